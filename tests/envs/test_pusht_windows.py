"""Push-T with T_o > 2 in PyTorch: the env emits the window and gap the store's sampler trains on;
a state policy with ``obs_horizon=4`` trains a few steps on scripted Push-T demonstrations and
rolls out through `make_actor`."""

from __future__ import annotations

import pytest
import torch
from tensordict import TensorDict
from torchrl.envs.utils import ExplorationType, check_env_specs, set_exploration_type

from rfmp_rl import keys
from rfmp_rl.data import DemonstrationStore
from rfmp_rl.modules import FlowPolicy, ModelConfig, build_model, make_actor
from rfmp_rl.objectives import make_loss

pytest.importorskip("gym_pusht")

from rfmp_rl.envs.pusht import PushTEnv, make_pusht_env  # noqa: E402

T_O, T_P, T_A = 4, 8, 4


def push_toward_block(td: TensorDict) -> TensorDict:
    """Scripted demonstrator: command the disc to the centre of the block's keypoints."""
    points = td[keys.OBSERVATION][..., :18].reshape(*td.batch_size, 9, 2)
    return td.set(keys.ACTION, points.mean(-2))


def scripted_episodes(steps: int = 30) -> list[TensorDict]:
    env = PushTEnv([2], seeds=[7, 8], max_steps=steps)
    rollout = env.rollout(steps, push_toward_block, break_when_any_done=False)
    return [TensorDict({keys.OBSERVATION: rollout[i][keys.OBSERVATION],
                        keys.ACTION: rollout[i][keys.ACTION]}, [steps]) for i in range(2)]


def assert_oldest_and_latest(window: torch.Tensor, obs: torch.Tensor, obs_horizon: int) -> None:
    """``window (N, L, 2, ...)`` == ``[o_{max(t - T_o + 1, 0)}, o_t]`` of one episode per env."""
    for t in range(obs.shape[1]):
        torch.testing.assert_close(window[:, t, 0], obs[:, max(t - obs_horizon + 1, 0)])
        torch.testing.assert_close(window[:, t, 1], obs[:, t])


def test_pusht_state_with_obs_horizon_4_trains_and_rolls_out_through_make_actor():
    torch.manual_seed(0)
    store = DemonstrationStore.from_episodes(scripted_episodes())
    rb = store.replay_buffer(T_P, [keys.OBSERVATION], obs_horizon=T_O, batch_size=32,
                             generator=torch.Generator().manual_seed(0))
    model = build_model(ModelConfig("srfmp", "R2", obs_dim=20, horizon=T_P, action_steps=T_A,
                                    obs_horizon=T_O, down_dims=[16, 32], time_embed_dim=32,
                                    tau_hidden_dim=32))
    model.action_normalizer.set_stats(*store.stats(keys.ACTION))
    model.obs_normalizer.set_stats(*store.stats(keys.OBSERVATION))
    loss_fn = make_loss(model)
    optim = torch.optim.Adam(model.parameters(), lr=1e-3)
    before = [p.detach().clone() for p in model.parameters()]
    gaps = set()
    for _ in range(4):
        batch = rb.sample()
        assert batch[keys.OBSERVATION].shape == (32, 2, 20)
        gaps |= set(batch[keys.OBS_GAP].tolist())
        losses = loss_fn(batch)
        loss = sum(v for k, v in losses.items() if k.startswith("loss_"))
        assert torch.isfinite(loss)
        optim.zero_grad()
        loss.backward()
        optim.step()
    assert gaps == {2.0, 3.0, 4.0}  # the sampler's context range [s - T_o, s - 2]
    assert any(not torch.equal(a, b) for a, b in zip(before, model.parameters(), strict=True))

    policy = FlowPolicy(model.eval(), observation_key=keys.OBS_WINDOW, nfe=1)
    actor, primer = make_actor(policy)
    env = make_pusht_env([2], obs_horizon=T_O, seeds=[100, 101]).append_transform(primer)
    check_env_specs(env)
    calls, sample = [], model.sample
    model.sample = lambda *a, **kw: calls.append(1) or sample(*a, **kw)
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        rollout = env.rollout(12, actor, break_when_any_done=False)
    assert rollout[keys.ACTION].shape == (2, 12, 2) and torch.isfinite(rollout[keys.ACTION]).all()
    assert len(calls) == 12 // T_A
    assert (rollout[keys.OBS_GAP] == T_O).all()  # the constant gap: c = s - T_o
    assert_oldest_and_latest(rollout[keys.OBS_WINDOW], rollout[keys.OBSERVATION], T_O)
    # the disc was driven: it moved between the first and the last step
    moved = (rollout["next", "agent_pos"][:, -1] - rollout["agent_pos"][:, 0]).norm(dim=-1)
    assert (moved > 1.0).all()


def test_pusht_image_env_emits_camera_windows_for_t_o_3():
    env = make_pusht_env([1], obs_type="image", obs_horizon=3, seeds=[5])
    check_env_specs(env)
    rollout = env.rollout(4, break_when_any_done=False)
    assert rollout[keys.PIXELS_WINDOW].shape == (1, 4, 2, 3, 96, 96)
    assert rollout[keys.PIXELS_WINDOW].dtype == torch.uint8
    assert_oldest_and_latest(rollout[keys.PIXELS_WINDOW], rollout[keys.PIXELS], 3)
    assert_oldest_and_latest(rollout[keys.OBS_WINDOW], rollout[keys.OBSERVATION], 3)
    assert (rollout[keys.OBS_GAP] == 3).all()
