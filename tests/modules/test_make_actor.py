"""`make_actor`: the receding-horizon actor and its primer in plain, unbatched, serial and parallel
envs; the README's "Acting in any TorchRL env" section run as written."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
import torch
from tensordict import TensorDict
from torch import nn

from rfmp_rl import keys
from rfmp_rl.envs import make_lasa_sphere_env, window_transforms
from rfmp_rl.modules import FlowPolicy, RecedingHorizonActor, make_actor

ROOT = Path(__file__).resolve().parents[2]
EAST = torch.tensor([1.0, 0.0, 0.0])


def readme_section(title: str) -> str:
    """The python code block of the README section ``## title``."""
    text = (ROOT / "README.md").read_text()
    assert f"\n## {title}\n" in text, f"README.md has no section '## {title}'"
    section = text.split(f"\n## {title}\n", 1)[1].split("\n## ", 1)[0]
    blocks = re.findall(r"```python\n(.*?)```", section, flags=re.S)
    assert len(blocks) == 1, f"'## {title}' holds {len(blocks)} python blocks, expected 1"
    return blocks[0]


def counting(model) -> list[torch.Tensor]:
    """Record every chunk ``model.sample`` returns."""
    calls, original = [], model.sample

    def sample(*args, **kw):
        out = original(*args, **kw)
        calls.append(out.clone())
        return out

    model.sample = sample
    return calls


def test_readme_acting_section_trains_and_acts_in_plain_serial_and_parallel_envs():
    gym = pytest.importorskip("gymnasium")
    del gym
    code = readme_section("Acting in any TorchRL env")
    assert "MountainCarContinuous-v0" in code and "make_actor(" in code
    assert "MountainCar" not in "".join(
        p.read_text() for p in (ROOT / "tests").rglob("*.py") if p.name != "test_make_actor.py"
    ), "the README example must use an env the rest of the suite does not"
    torch.manual_seed(0)
    namespace = {"__name__": "__main__"}
    try:
        exec(compile(code, "README.md", "exec"), namespace)
    finally:  # worker processes end even when the code fails
        for env in namespace.get("envs", []):
            if not env.is_closed:
                env.close()
    assert all(env.is_closed for env in namespace["envs"])
    plain, serial, parallel = namespace["rollouts"]
    assert plain["action"].shape == (300, 1)
    assert serial["action"].shape == parallel["action"].shape == (2, 300, 1)
    for rollout in (plain.unsqueeze(0), serial, parallel):
        # the policy imitates the expert: every env reaches the goal (terminated) in 300 steps
        assert rollout["next", "terminated"].any(dim=-2).all(), rollout["next", "reward"].sum(-2)
        # the window the policy read: [previous observation, current observation]
        obs, window = rollout["observation"], rollout["obs_window"]
        torch.testing.assert_close(window[:, :, 1], obs)
        fresh = ~rollout["is_init"][:, 1:, 0]  # (N, 299): steps that continue an episode
        torch.testing.assert_close(window[:, 1:, 0][fresh], obs[:, :-1][fresh])
        # receding horizon: re-plans every T_a = 4 steps and after every reset
        counter = rollout["counter"][..., 0]
        assert counter.max() == 4 and (counter[rollout["is_init"][..., 0]] == 1).all()
        assert (counter[:, :4] == torch.arange(1, 5)).all()


@pytest.fixture
def lasa_model(make_tiny_model):
    return make_tiny_model("srfmp", "S2", obs_dim=3, horizon=4)  # T_p = 4, T_a = 2


def test_make_actor_executes_t_a_of_each_chunk_in_an_unbatched_env(make_tiny_model):
    pytest.importorskip("gymnasium")
    from torchrl.envs import GymEnv, TransformedEnv

    model = make_tiny_model("srfmp", "R1", obs_dim=2, horizon=4)
    actor, primer = make_actor(model, observation_key=keys.OBS_WINDOW, nfe=1)
    assert isinstance(actor, RecedingHorizonActor) and actor.replan_interval == 2
    env = TransformedEnv(GymEnv("MountainCarContinuous-v0"), window_transforms(actor))
    env = env.append_transform(primer)
    env.set_seed(0)
    assert env.batch_size == ()
    calls = counting(model)
    rollout = env.rollout(10, actor, break_when_any_done=False)
    assert rollout["action"].shape == (10, 1) and rollout[keys.OBS_WINDOW].shape == (10, 2, 2)
    assert len(calls) == 5  # one chunk every T_a = 2 steps
    executed = rollout["action"].reshape(5, 2, 1)
    torch.testing.assert_close(executed, torch.stack([c[0, :2] for c in calls]))
    assert rollout["counter"][:, 0].tolist() == [1, 2] * 5


def test_primer_declares_the_actor_state_with_the_env_batch(lasa_model):
    actor, primer = make_actor(FlowPolicy(lasa_model, observation_key=keys.OBS_WINDOW))
    env = make_lasa_sphere_env(EAST, [3], seed=0).append_transform(primer)
    spec = env.observation_spec
    assert spec["action_orig"].shape == (3, 4, 3) and spec["counter"].shape == (3, 1)
    assert spec["counter"].dtype == torch.int32
    rollout = env.rollout(6, actor)
    assert rollout["counter"][0, :, 0].tolist() == [1, 2, 1, 2, 1, 2]
    # the chunk the actor keeps is the one it executes from
    torch.testing.assert_close(rollout["action"][:, 1], rollout["action_orig"][:, 1, 1])


def test_serial_env_of_windowed_envs_carries_the_chunk(lasa_model):
    from torchrl.envs import SerialEnv

    policy = FlowPolicy(lasa_model, observation_key=keys.OBS_WINDOW)
    actor, primer = make_actor(policy)

    def make_env():
        return make_lasa_sphere_env(EAST, [2], seed=0).append_transform(primer.clone())

    calls = counting(lasa_model)
    rollout = SerialEnv(2, make_env).rollout(4, actor)
    assert rollout["action"].shape == (2, 2, 4, 3)
    assert len(calls) == 2 and calls[0].shape == (4, 4, 3)  # 4 envs at once, every T_a = 2
    torch.testing.assert_close(rollout["action"][:, :, 1], calls[0][:, 1].reshape(2, 2, 3))


def test_make_actor_names_what_it_takes(lasa_model):
    with pytest.raises(TypeError, match="FlowPolicy or a policy model"):
        make_actor(nn.Linear(2, 2))
    with pytest.raises(TypeError, match="built already"):
        make_actor(FlowPolicy(lasa_model), nfe=2)
    actor, _ = make_actor(lasa_model, action_steps=3)
    assert actor.replan_interval == 3 and actor.n_steps == 4
    with pytest.raises(ValueError, match="replan_interval"):
        make_actor(lasa_model, action_steps=5)


def test_unbatched_input_is_written_back(lasa_model):
    actor, _ = make_actor(lasa_model, nfe=1)
    td = TensorDict({keys.OBSERVATION: torch.randn(2, 3),
                     "is_init": torch.ones(1, dtype=torch.bool)}, [])
    out = actor(td)
    assert out is td and td["action"].shape == (3,) and td["action_orig"].shape == (4, 3)
    torch.testing.assert_close(td["action"], td["action_orig"][0])
    td["is_init"] = torch.zeros(1, dtype=torch.bool)
    actor(td)
    torch.testing.assert_close(td["action"], td["action_orig"][1])
    assert td["counter"].tolist() == [2]


def test_torchrl_finds_the_primer_on_the_actor(lasa_model):
    from torchrl.collectors import Collector
    from torchrl.envs import TensorDictPrimer
    from torchrl.modules.utils import get_primers_from_module

    actor, primer = make_actor(lasa_model, observation_key=keys.OBS_WINDOW)
    found = get_primers_from_module(actor)
    assert isinstance(found, TensorDictPrimer)
    assert set(found.primers.keys()) == set(primer.primers.keys()) == {"action_orig", "counter"}
    # a Collector that registers the policy's transforms appends it to the env by itself
    collector = Collector(make_lasa_sphere_env(EAST, [2], seed=0), actor, frames_per_batch=8,
                          total_frames=8, auto_register_policy_transforms=True)
    (batch,) = list(collector)
    collector.shutdown()
    assert batch["counter"][..., 0].tolist() == [[1, 2, 1, 2]] * 2
    assert batch["action_orig"].shape == (2, 4, 4, 3)
