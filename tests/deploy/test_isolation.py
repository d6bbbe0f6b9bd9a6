"""The robot-side package imports neither torch nor rfmp_rl: a fresh interpreter where both are
unimportable loads a model, steps the controller (with a camera), completes a closed-loop
Gymnasium episode and runs ``--check``."""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

from toy_policy import example_spec

DEPLOY = Path(__file__).resolve().parents[2] / "deploy"

SCRIPT = textwrap.dedent("""
    import importlib.abc
    import runpy
    import sys

    BLOCKED = ("torch", "torchvision", "torchrl", "tensordict", "rfmp_rl")
    attempts = []

    class Block(importlib.abc.MetaPathFinder):
        def find_spec(self, name, path=None, target=None):
            if name.split(".")[0] in BLOCKED:
                attempts.append(name)
                raise ImportError(f"{name} is blocked on the robot PC")
            return None

    sys.meta_path.insert(0, Block())
    sys.path.insert(0, sys.argv[1])
    model = sys.argv[2]

    import numpy as np
    from rfmp_deploy import Controller

    controller = Controller(model, seed=0)
    observation = {"eef_pos": np.array([0.1, 0.0, 0.3]), "eef_quat": np.array([0, 0, 0, 1.0]),
                   "gripper": np.array([0.04]), "wrist": np.zeros((480, 640, 3), np.uint8)}
    actions = [controller.step(observation) for _ in range(3)]
    assert all(a.shape == (8,) and np.isfinite(a).all() for a in actions)
    held = controller.step({"eef_pos": np.array([np.nan, 0, 0])})
    assert np.array_equal(held, actions[-1]) and controller.events[-1].kind == "rejected"

    # A whole closed-loop episode in a Gymnasium simulation (gymnasium imports numpy only).
    import gymnasium as gym
    from rfmp_deploy import GymnasiumRobot, run

    class Arm(gym.Env):
        observation_space = gym.spaces.Box(-np.inf, np.inf, (8,), np.float64)
        action_space = gym.spaces.Box(-1.0, 1.0, (8,), np.float64)

        def reset(self, seed=None, options=None):
            super().reset(seed=seed)
            self.state, self.t = np.array([0.1, 0, 0.3, 0, 0, 0, 1, 0.04]), 0
            return self.state.copy(), {}

        def step(self, action):
            self.state = 0.5 * self.state + 0.5 * np.asarray(action, np.float64)
            self.state[3:7] /= np.linalg.norm(self.state[3:7])
            self.t += 1
            return self.state.copy(), -float(np.abs(self.state[:3]).sum()), False, self.t >= 40, {}

    robot = GymnasiumRobot(Arm(), seed=0, observation_fn=lambda o: {
        "eef_pos": o[:3], "eef_quat": o[3:7], "gripper": o[7:8],
        "wrist": np.full((60, 80, 3), 128, np.uint8)})
    controller.reset()
    stats = run(controller, robot, rate_hz=1000.0, stop=lambda: robot.done)
    assert robot.truncated and stats.steps == 40 and len(robot.rewards) == 40, stats
    assert np.isfinite(robot.episode_return)
    print("EPISODE OK", stats.steps, round(robot.episode_return, 3))

    sys.argv = ["rfmp_deploy", "--model", model, "--check", "--runs", "3"]
    try:
        runpy.run_module("rfmp_deploy.cli", run_name="__main__")
    except SystemExit as e:
        assert e.code == 0, e.code

    loaded = sorted(m for m in sys.modules if m.split(".")[0] in BLOCKED)
    assert not loaded, loaded
    assert "cv2" in sys.modules  # the camera path really ran
    print("ISOLATED OK; blocked import attempts:", attempts)
""")


def test_deploy_runs_without_torch_or_rfmp_rl(make_model, tmp_path):
    model = make_model(example_spec())
    result = subprocess.run(
        [sys.executable, "-c", SCRIPT, str(DEPLOY), str(model)],
        cwd=tmp_path, capture_output=True, text=True, timeout=120,
        env={"PATH": "/usr/bin:/bin", "OMP_NUM_THREADS": "1"},
    )
    assert result.returncode == 0, result.stderr[-3000:]
    assert "ISOLATED OK; blocked import attempts: []" in result.stdout, result.stdout
    assert "latency:" in result.stdout
    assert "EPISODE OK 40" in result.stdout
