"""Smoke tests of the robosuite recipe on ToolHang and TwoArmTransport: a tiny robomimic file
(two short recorded episodes per task), a few training steps and a 2-seed evaluation."""

from __future__ import annotations

import math
import os
import sys
from pathlib import Path

import pytest
import torch
from recipe_loader import compose, load_recipe

from rfmp_rl.eval import read_table

pytest.importorskip("robosuite")

ROOT = Path(__file__).resolve().parents[2]
FOLDER = ROOT / "recipes" / "robosuite"
pytestmark = pytest.mark.slow
os.environ.setdefault("MUJOCO_GL", "egl")

TINY = [
    "data.val_episodes=1", "train.steps=2", "train.val_every=1", "train.val_batches=1",
    "train.batch_size=4", "train.log_every=1", "optim.warmup_steps=1", "eval.seeds=2",
    "eval.nfes=[1]", "eval.max_steps=10", "model.down_dims=[16,32]", "threads=1",
]


@pytest.fixture(scope="module")
def recipe():
    yield from load_recipe("robosuite")


def _record(task: str, action_space: str, path: Path, steps: int = 24) -> Path:
    """Two short episodes (seeds 0 and 1, the scripted expert's first ``steps`` steps) as a
    robomimic file (a stand-in for a user's own data set)."""
    if str(FOLDER) not in sys.path:
        sys.path.insert(0, str(FOLDER))
    import experts

    from rfmp_rl.data.robomimic import write_robomimic
    from rfmp_rl.envs.robosuite import RobosuiteEnv

    env = RobosuiteEnv(task, [1], action_space, max_steps=steps)
    policy = experts.make_expert(task, action_space)
    episodes = [experts._run_episode(env, policy, seed, images=False)[0] for seed in (0, 1)]
    env.close()
    write_robomimic(path, episodes, env_args={"env_name": task, "env_type": 1,
                                              "env_kwargs": {}, "action_space": action_space})
    return path


@pytest.mark.parametrize("task,algo,action_space", [
    ("TwoArmTransport", "srfmp", "delta"),
    ("TwoArmTransport", "rfmp", "abs_pose"),
    ("ToolHang", "ddim", "delta"),
])
def test_hard_task_trains_and_evaluates(recipe, tmp_path, task, algo, action_space):
    data = _record(task, action_space, tmp_path / f"{task}_{action_space}.hdf5")
    cfg = compose("robosuite", [f"task={task}", f"algo={algo}", f"action_space={action_space}",
                                f"out_dir={tmp_path / 'run'}", f"data.path={data}", *TINY])
    model_cfg = recipe["utils"].make_model_config(cfg)
    two_arms = task == "TwoArmTransport"
    assert model_cfg.obs_dim == (59 if two_arms else 53)
    assert [k for k, _ in model_cfg.obs_keys][-1] == "object"
    if action_space == "delta":
        assert model_cfg.action_manifold == ("R14" if two_arms else "R7")
    else:
        assert model_cfg.action_manifold == "R3 x S3 x R1 x R3 x S3 x R1"
    run = recipe["train"].train(cfg)
    (row,) = read_table(run / "eval" / "eval.csv")
    assert row["task"] == task and row["algo"] == algo and row["seeds"] == "100000-100001"
    assert 0.0 <= float(row["success"]) <= 1.0 and int(row["env_steps"]) > 0
    assert math.isfinite(float(row["jerk"]))
    if action_space == "abs_pose":
        assert float(row["quat_norm_err"]) <= 1e-5  # both arms' quaternions on S^3


def test_two_arm_pose_helpers(recipe):
    utils = recipe["utils"]
    cfg = compose("robosuite", ["task=TwoArmTransport", "action_space=abs_pose"])
    assert utils.quaternion_slices(cfg) == [slice(3, 7), slice(11, 15)]
    action = torch.arange(16.0).reshape(1, 16) + 1
    out = utils._normalise_quaternion(action)
    assert torch.allclose(out[0, 3:7].norm(), torch.tensor(1.0))
    assert torch.allclose(out[0, 11:15].norm(), torch.tensor(1.0))
    assert torch.equal(out[0, :3], action[0, :3]) and torch.equal(out[0, 7:11], action[0, 7:11])
    assert utils.cameras("TwoArmTransport") == (
        "shouldercamera0_image", "shouldercamera1_image", "robot0_eye_in_hand_image",
        "robot1_eye_in_hand_image")
    assert utils.cameras("Lift") == utils.CAMERAS
