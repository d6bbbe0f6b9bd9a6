"""`observation_windows` / `window_transforms`: the window ``[o^{s-T_o}, o^{s-1}]`` and the gap T_o
an env emits, for any T_o, and `FlowPolicy` reading exactly those."""

from __future__ import annotations

import pytest
import torch
from tensordict import TensorDict
from torchrl.envs import Compose, StepCounter, TransformedEnv
from torchrl.envs.utils import ExplorationType, check_env_specs, set_exploration_type

from rfmp_rl import keys
from rfmp_rl.envs import (
    ContextWindow,
    LasaSphereEnv,
    make_lasa_sphere_env,
    observation_windows,
    window_transforms,
)
from rfmp_rl.envs.transforms import step_key
from rfmp_rl.modules import FlowPolicy, ModelConfig, build_model

EAST = torch.tensor([1.0, 0.0, 0.0])


def expected_windows(obs: torch.Tensor, is_init: torch.Tensor, obs_horizon: int) -> torch.Tensor:
    """``(N, L, 2, D)`` = ``[o_{max(t - T_o + 1, start)}, o_t]`` from a rollout's observations."""
    n, length = obs.shape[:2]
    out = torch.empty(n, length, 2, obs.shape[-1])
    for i in range(n):
        start = 0
        for t in range(length):
            if is_init[i, t]:
                start = t
            out[i, t, 0] = obs[i, max(t - obs_horizon + 1, start)]
            out[i, t, 1] = obs[i, t]
    return out


@pytest.mark.parametrize("obs_horizon", [2, 3, 4])
def test_lasa_env_emits_the_oldest_and_latest_of_the_last_t_o(obs_horizon):
    # max_steps=5 ends (and resets) episodes inside the rollout: the window restarts there
    env = make_lasa_sphere_env(EAST, [2], seed=0, obs_horizon=obs_horizon, max_steps=5,
                               start_noise=0.3)
    check_env_specs(env)
    torch.manual_seed(0)
    rollout = env.rollout(12, break_when_any_done=False)
    window = rollout[keys.OBS_WINDOW]
    assert window.shape == (2, 12, 2, 3)
    is_init = rollout["is_init"][..., 0]
    assert is_init[:, 5].all()  # an episode restarted after 5 steps
    torch.testing.assert_close(window, expected_windows(rollout[keys.OBSERVATION], is_init,
                                                       obs_horizon))
    if obs_horizon == 2:
        assert keys.OBS_GAP not in rollout
    else:
        assert rollout[keys.OBS_GAP].shape == (2, 12)
        assert (rollout[keys.OBS_GAP] == obs_horizon).all()
        assert env.observation_spec[keys.OBS_GAP].shape == (2,)
    assert env.observation_spec[keys.OBS_WINDOW].shape == (2, 2, 3)


def test_windows_in_a_compose_of_their_own_and_in_an_unbatched_env():
    base = LasaSphereEnv(EAST, [], seed=0)
    env = TransformedEnv(base, Compose(StepCounter(), observation_windows(3)))
    check_env_specs(env)
    td = env.rollout(4)
    assert td[keys.OBS_WINDOW].shape == (4, 2, 3) and td[keys.OBS_GAP].tolist() == [3.0] * 4
    torch.testing.assert_close(td[keys.OBS_WINDOW][3, 0], td[keys.OBSERVATION][1])


def test_camera_windows_stack_along_their_own_dim():
    t = Compose(
        ContextWindow(3, [keys.OBS_WINDOW, keys.PIXELS_WINDOW], [1, 3]),
    )
    pixels = torch.arange(3 * 3 * 2 * 2, dtype=torch.uint8).reshape(1, 3, 3, 2, 2)
    td = t(TensorDict({keys.OBS_WINDOW: torch.arange(6.0).reshape(1, 3, 2),
                       keys.PIXELS_WINDOW: pixels}, [1]))
    assert td[keys.PIXELS_WINDOW].shape == (1, 2, 3, 2, 2)
    torch.testing.assert_close(td[keys.PIXELS_WINDOW], pixels[:, [0, 2]])
    assert td[keys.OBS_WINDOW].tolist() == [[[0.0, 1.0], [4.0, 5.0]]]


def test_bad_windows_are_named():
    with pytest.raises(ValueError, match="obs_horizon"):
        observation_windows(1)
    with pytest.raises(ValueError, match="'observation' needs its own key"):
        observation_windows(2, {keys.OBSERVATION: keys.OBSERVATION})
    with pytest.raises(ValueError, match="must be > 2"):
        ContextWindow(2, [keys.OBS_WINDOW], [1])
    with pytest.raises(ValueError, match="stacks 3 frames .* expected T_o = 4"):
        ContextWindow(4, [keys.OBS_WINDOW], [1])(
            TensorDict({keys.OBS_WINDOW: torch.zeros(1, 3, 2)}, [1]))
    assert step_key(keys.OBS_WINDOW) == keys.OBS_STEP
    assert step_key(keys.PIXELS_WINDOW) == keys.PIXELS_STEP
    assert step_key("agentview_image_window") == "agentview_image_step"


def _model(obs_horizon: int, cameras=None):
    torch.manual_seed(0)
    return build_model(ModelConfig("srfmp", "S2", obs_dim=3, horizon=4, obs_horizon=obs_horizon,
                                   cameras=cameras or {}, down_dims=[16, 32], time_embed_dim=32,
                                   tau_hidden_dim=32, vision_out_dim=8))


def test_window_transforms_take_the_keys_from_the_policy():
    model = _model(4, cameras={"agentview": [3, 8, 8]})
    policy = FlowPolicy(model, observation_key=("obs", "window"),
                        camera_keys={"agentview": "agentview_window"}, gap_key="gap")
    t = window_transforms(policy, sources={"agentview_window": "agentview_image"})
    unsqueeze_obs, cat_obs, unsqueeze_cam, cat_cam, context, tracker = list(t)
    assert (unsqueeze_obs.in_keys, cat_obs.out_keys) == ([keys.OBSERVATION], [("obs", "window")])
    assert (unsqueeze_cam.in_keys, cat_cam.out_keys) == (["agentview_image"],
                                                          ["agentview_window"])
    assert (cat_obs.N, cat_cam.N, cat_cam.dim) == (4, 4, -4)
    assert context.gap_key == "gap" and context.obs_horizon == 4
    assert tracker.init_key == "is_init"
    with pytest.raises(ValueError, match="name no window the policy reads"):
        window_transforms(policy, sources={"pixels_window": "pixels"})
    with pytest.raises(TypeError, match="FlowPolicy or a wrapper"):
        window_transforms(model)


def test_flow_policy_reads_the_window_and_gap_the_env_emits():
    model = _model(4)
    policy = FlowPolicy(model, observation_key=keys.OBS_WINDOW, nfe=2)
    assert policy.in_keys == [keys.OBS_WINDOW, keys.OBS_GAP]
    env = TransformedEnv(LasaSphereEnv(EAST, [3], seed=0, start_noise=0.3),
                         window_transforms(policy))
    torch.manual_seed(1)
    td = env.rollout(5, break_when_any_done=False)[:, -1]  # a window of two distinct steps
    assert not torch.equal(td[keys.OBS_WINDOW][:, 0], td[keys.OBS_WINDOW][:, 1])
    assert td[keys.OBS_GAP].tolist() == [4.0, 4.0, 4.0]
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        action = policy(td.clone())[keys.ACTION]
        other = td.clone().set(keys.OBS_GAP, torch.full((3,), 2.0))
        action_gap2 = policy(other)[keys.ACTION]
    cond = model.encode(td[keys.OBS_WINDOW], gap=td[keys.OBS_GAP])
    expected = model.sample(cond, nfe=2, deterministic=True)
    torch.testing.assert_close(action, expected)
    assert (action - action_gap2).abs().max() > 1e-4  # the gap reaches the network
