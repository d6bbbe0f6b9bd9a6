"""`GymnasiumRobot` (closed loop in simulation) and `BagReplay` (open loop against a recording)."""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest
from rfmp_deploy import BagReplay, Controller, GymnasiumRobot, run
from toy_policy import ToySpec, make_observation


class PointEnv(gym.Env):
    """A point in the plane; the action is a displacement. Success: within 0.04 of the origin."""

    def __init__(self, dict_obs: bool = True, max_steps: int = 50) -> None:
        self.dict_obs, self.max_steps = dict_obs, max_steps
        box = gym.spaces.Box(-10, 10, (2,), np.float64)
        self.observation_space = gym.spaces.Dict({"pos": box}) if dict_obs else box
        self.action_space = gym.spaces.Box(-1, 1, (2,), np.float32)

    def _obs(self):
        return {"pos": self.pos.copy()} if self.dict_obs else self.pos.copy()

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.pos, self.t = np.array([0.6, -0.8]), 0
        self.received = []
        return self._obs(), {}

    def step(self, action):
        self.received.append(action)
        self.pos = self.pos + action
        self.t += 1
        distance = float(np.linalg.norm(self.pos))
        return self._obs(), -distance, distance < 0.04, self.t >= self.max_steps, {"d": distance}


# action = -0.25 * latest position (the same for every step of the chunk): with T_a = 2 each
# chunk takes the distance d to 0.75 d, then 0.5 d; from 1, 0.03125 < 0.04 after 5 chunks.
W = np.zeros((2 * 2 + 2, 2))
W[2:4] = -0.25 * np.eye(2)
POINT = ToySpec(obs_keys=[("pos", 2)], manifold={"type": "euclidean", "dim": 2}, horizon=4,
                action_steps=2, noise_dim=2, weight=W, bias=np.zeros(2), offsets=np.zeros((4, 2)))


def test_closed_loop_in_gymnasium(make_policy):
    env = PointEnv()
    robot = GymnasiumRobot(env, seed=0)
    controller = Controller(make_policy(POINT), deterministic=True)
    stats = run(controller, robot, rate_hz=1000, stop=lambda: robot.done)
    assert robot.terminated and not robot.truncated and robot.done
    assert stats.steps == 10 and len(robot.rewards) == 10
    assert robot.info["d"] == pytest.approx(1 / 32)
    expected = [-(0.5 ** ((k - 1) // 2)) * (0.75 if k % 2 else 0.5) for k in range(1, 11)]
    np.testing.assert_allclose(robot.rewards, expected, rtol=1e-5)
    assert robot.episode_return == pytest.approx(sum(expected), rel=1e-5)
    assert all(a.dtype == np.float32 and a.shape == (2,) for a in env.received)
    with pytest.raises(RuntimeError, match="call reset"):
        robot.send_action(np.zeros(2, np.float32))
    robot.reset()
    controller.reset()
    assert not robot.done and robot.rewards == [] and robot.episodes == 2


def test_observation_fn_for_array_observations(make_policy):
    env = PointEnv(dict_obs=False, max_steps=3)
    with pytest.raises(TypeError, match="observation_fn"):
        GymnasiumRobot(env).read_observation()
    robot = GymnasiumRobot(env, observation_fn=lambda o: {"pos": o})
    controller = Controller(make_policy(POINT), deterministic=True)
    stats = run(controller, robot, rate_hz=1000, stop=lambda: robot.done)
    assert robot.truncated and not robot.terminated and stats.steps == 3


SPEC = ToySpec(horizon=4, action_steps=2)  # R3 x S3 x R1


def _recording(controller, n=6):
    observations = [make_observation(SPEC, 0.2 * k) for k in range(n)]
    controller.reset()
    actions = np.stack([controller.step(o) for o in observations])
    return observations, actions


def test_bag_replay_errors_have_known_values(make_policy):
    controller = Controller(make_policy(SPEC), deterministic=True)
    observations, actions = _recording(controller)
    recorded = actions.astype(np.float64)
    recorded[:, 0] += 0.03  # 3-4-12-13: Euclidean error 0.13 (gripper included)
    recorded[:, 1] -= 0.04
    recorded[:, 7] += 0.12
    # Rotate each quaternion by `angle` along a direction orthogonal to it on S^3.
    angle = np.deg2rad(np.array([0, 5, 10, 15, 20, 25]))
    q = recorded[:, 3:7]
    v = np.roll(q, 1, axis=1) * [1, -1, 1, -1]
    v -= np.sum(v * q, axis=1, keepdims=True) * q
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    recorded[:, 3:7] = np.cos(angle)[:, None] * q + np.sin(angle)[:, None] * v
    report = BagReplay(observations, recorded).replay(controller)
    np.testing.assert_allclose(report.euclidean_error, 0.13, rtol=1e-5)
    assert report.mean_euclidean_error == pytest.approx(0.13, rel=1e-5)
    assert report.max_euclidean_error == pytest.approx(0.13, rel=1e-5)
    np.testing.assert_allclose(report.geodesic_error[:, 0], angle, atol=1e-6)
    np.testing.assert_allclose(report.mean_geodesic_error, [np.deg2rad(12.5)], atol=1e-6)
    np.testing.assert_allclose(report.max_geodesic_error, [np.deg2rad(25)], atol=1e-6)
    np.testing.assert_allclose(report.actions, actions)  # replay reproduces the controller
    assert "angle mean 12.5 deg, max 25 deg" in report.summary()


def test_bag_replay_under_the_run_loop(make_policy):
    controller = Controller(make_policy(SPEC), deterministic=True)
    observations, actions = _recording(controller, n=5)
    bag = BagReplay(observations, actions)
    controller.reset()
    stats = run(controller, bag, rate_hz=1000, stop=lambda: bag.done)
    assert stats.steps == len(bag) == 5 and bag.done
    report = bag.report(controller)
    assert report.max_euclidean_error < 1e-6
    assert math.isclose(float(report.max_geodesic_error[0]), 0.0, abs_tol=1e-3)
    with pytest.raises(IndexError):
        bag.read_observation()
    bag.rewind()
    assert not bag.done and bag.sent == []


def test_bag_replay_checks_its_inputs(make_policy):
    with pytest.raises(ValueError, match="expected \\(N, D\\) actions for N=2"):
        BagReplay([{}, {}], np.zeros((3, 8)))
    bag = BagReplay([{}], np.zeros((1, 5)))
    bag.send_action(np.zeros(8))
    with pytest.raises(ValueError, match="5 coordinates"):
        bag.report(Controller(make_policy(SPEC)))
