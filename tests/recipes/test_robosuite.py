"""Smoke tests of the robosuite recipes: tiny expert data sets, a few training steps and a
2-seed evaluation per variant (tasks, algorithms, action spaces, Euclidean pose baseline,
images); eval.py re-evaluates a checkpoint."""

from __future__ import annotations

import math
import os
from pathlib import Path

import pytest
from recipe_loader import compose, load_recipe

from rfmp_rl.eval import read_table

ROOT = Path(__file__).resolve().parents[2]
RECIPE = ROOT / "recipes" / "robosuite"

pytestmark = pytest.mark.slow
os.environ.setdefault("MUJOCO_GL", "egl")


@pytest.fixture(scope="module")
def recipe():
    yield from load_recipe("robosuite")


@pytest.fixture(scope="module")
def data_dir(tmp_path_factory):
    return tmp_path_factory.mktemp("robosuite_demos")


def _cfg(overrides):
    return compose("robosuite", overrides)


TINY = [
    "data.demos=3", "data.val_episodes=1", "train.steps=2", "train.val_every=1",
    "train.val_batches=1", "train.batch_size=4", "train.log_every=1", "optim.warmup_steps=1",
    "eval.seeds=2", "eval.nfes=[1]", "eval.max_steps=12", "model.down_dims=[16,32]", "threads=1",
]

VARIANTS = [
    ("Lift", "srfmp", "state", "delta", "riemannian"),
    ("Lift", "rfmp", "state", "abs_pose", "riemannian"),
    ("Lift", "ddim", "state", "abs_pose", "riemannian"),
    ("Lift", "srfmp", "state", "abs_pose", "euclidean"),
    ("PickPlaceCan", "srfmp", "state", "delta", "riemannian"),
    ("NutAssemblySquare", "rfmp", "state", "abs_pose", "riemannian"),
    ("Lift", "srfmp", "image", "delta", "riemannian"),
]


@pytest.mark.parametrize("task,algo,obs,action_space,geometry", VARIANTS)
def test_variant_trains_and_evaluates(recipe, data_dir, tmp_path, task, algo, obs, action_space,
                                      geometry):
    suffix = "_images" if obs == "image" else ""
    cfg = _cfg([f"task={task}", f"algo={algo}", f"obs={obs}", f"action_space={action_space}",
                f"geometry={geometry}", f"out_dir={tmp_path}",
                f"data.path={data_dir / f'{task}_{action_space}{suffix}.hdf5'}", *TINY])
    run = recipe["train"].train(cfg)
    for name in ("best.pt", "last.pt", "config.yaml", "history.json", "eval/eval.csv",
                 "eval/eval.md"):
        assert (run / name).is_file() and (run / name).stat().st_size > 0, name
    (row,) = read_table(run / "eval" / "eval.csv")
    assert row["task"] == task and row["algo"] == algo and row["seeds"] == "100000-100001"
    assert 0.0 <= float(row["success"]) <= 1.0 and int(row["env_steps"]) > 0
    assert math.isfinite(float(row["jerk"]))
    if action_space == "abs_pose" and geometry == "riemannian":
        assert float(row["quat_norm_err"]) <= 1e-5  # every executed quaternion on S^3
    if action_space == "abs_pose" and geometry == "euclidean":
        assert math.isfinite(float(row["quat_norm_err"]))  # the raw R^8 output, before fixing
    model_cfg = recipe["utils"].make_model_config(cfg)
    names = [k for k, _ in model_cfg.obs_keys]
    if obs == "image":  # robomimic's image setting: proprioception + cameras, no object state
        assert names == ["robot0_eef_pos", "robot0_eef_quat", "robot0_gripper_qpos"]
        assert model_cfg.obs_dim == 9 and set(model_cfg.cameras) == set(recipe["utils"].CAMERAS)
    else:
        assert names[-1] == "object" and not model_cfg.cameras


def test_eval_script_uses_its_own_seeds(recipe, data_dir, tmp_path):
    cfg = _cfg(["task=Lift", f"out_dir={tmp_path / 'run'}", "eval.final_eval=false",
                f"data.path={data_dir / 'Lift_delta.hdf5'}", *TINY])
    run = recipe["train"].train(cfg)
    rows = recipe["eval"].evaluate_checkpoint(_cfg([
        f"checkpoint={run / 'best.pt'}", "eval.seeds=3", "eval.seed_start=500", "eval.nfes=[1,2]",
        "eval.max_steps=8", f"eval.out={tmp_path / 'ev'}", "threads=1"]))
    assert [r["nfe"] for r in rows] == [1, 2] and all(r["seeds"] == "500-502" for r in rows)
    assert (tmp_path / "ev" / "eval.md").is_file()
    # The same seeds stepped two envs at a time (chunks 500-501, 502): one row per setting over
    # all three seeds; with the prior's mode the episodes do not depend on the batching.
    common = [f"checkpoint={run / 'best.pt'}", "eval.seeds=3", "eval.seed_start=500",
              "eval.nfes=[1]", "eval.max_steps=8", "eval.sampling=deterministic", "threads=1"]
    whole = recipe["eval"].evaluate_checkpoint(_cfg([*common, f"eval.out={tmp_path / 'e1'}"]))
    split = recipe["eval"].evaluate_checkpoint(_cfg([*common, "eval.num_envs=2",
                                                     f"eval.out={tmp_path / 'e2'}"]))
    (a,), (b,) = whole, split
    assert b["seeds"] == "500-502" and b["per_seed"]["seed"] == [500, 501, 502]
    assert b["per_seed"]["success"] == a["per_seed"]["success"] and b["success"] == a["success"]
    assert b["env_steps"] == a["env_steps"]
    assert len(b["per_seed"]["jerk"]) == 3 and math.isclose(b["jerk"], a["jerk"], rel_tol=1e-4)
    with pytest.raises(ValueError, match="eval.num_envs"):
        recipe["eval"].evaluate_checkpoint(_cfg([*common, "eval.num_envs=0"]))


def test_parallel_evaluation_gives_the_serial_per_seed_results(recipe, data_dir, tmp_path):
    # eval.workers=2 steps the seeds in two TorchRL ParallelEnv workers (3 seeds: one padding
    # seed on the second worker, dropped); each episode's prior noise comes from its own seed,
    # so random sampling gives the same episodes as the serial evaluation.
    cfg = _cfg(["task=Lift", f"out_dir={tmp_path / 'run'}", "eval.final_eval=false",
                f"data.path={data_dir / 'Lift_delta.hdf5'}", *TINY])
    run = recipe["train"].train(cfg)
    common = [f"checkpoint={run / 'best.pt'}", "eval.seeds=3", "eval.seed_start=700",
              "eval.nfes=[1]", "eval.max_steps=10", "threads=1"]
    serial = recipe["eval"].evaluate_checkpoint(_cfg([*common, f"eval.out={tmp_path / 's'}"]))
    parallel = recipe["eval"].evaluate_checkpoint(_cfg([*common, "eval.workers=2",
                                                        f"eval.out={tmp_path / 'p'}"]))
    (a,), (b,) = serial, parallel
    assert b["seeds"] == a["seeds"] == "700-702"
    assert b["per_seed"]["success"] == a["per_seed"]["success"]
    assert b["env_steps"] == a["env_steps"]
    assert len(b["per_seed"]["jerk"]) == 3
    for x, y in zip(a["per_seed"]["jerk"], b["per_seed"]["jerk"], strict=True):
        assert math.isclose(x, y, rel_tol=1e-4), (a["per_seed"]["jerk"], b["per_seed"]["jerk"])
    with pytest.raises(ValueError, match="eval.workers"):
        recipe["eval"].evaluate_checkpoint(_cfg([*common, "eval.workers=0"]))


def test_missing_data_without_generation_names_the_file(recipe, tmp_path):
    cfg = _cfg(["task=Lift", f"data.path={tmp_path / 'none.hdf5'}", "data.generate=false",
                f"out_dir={tmp_path / 'run'}", *TINY])
    with pytest.raises(FileNotFoundError, match="none.hdf5"):
        recipe["train"].train(cfg)


def test_cp_distils_a_ddim_teacher_on_lift_pose_actions(recipe, data_dir, tmp_path):
    # algo=cp teacher=<ddim best.pt>: the student keeps the teacher's R3 x S3 x R1 actions and
    # evaluates at NFE 1 with every quaternion on S^3
    data = f"data.path={data_dir / 'Lift_abs_pose.hdf5'}"
    common = ["task=Lift", "action_space=abs_pose", "geometry=riemannian", data, *TINY]
    teacher = recipe["train"].train(_cfg(["algo=ddim", f"out_dir={tmp_path / 'ddim'}",
                                          "eval.final_eval=false", *common]))
    run = recipe["train"].train(_cfg(["algo=cp", f"teacher={teacher / 'best.pt'}",
                                      f"out_dir={tmp_path / 'cp'}", *common]))
    (row,) = read_table(run / "eval" / "eval.csv")
    assert row["algo"] == "cp" and row["nfe"] == "1" and 0.0 <= float(row["success"]) <= 1.0
    assert float(row["quat_norm_err"]) <= 1e-5
