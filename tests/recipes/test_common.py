"""recipes/common.py: the config groups map onto the library's dataclasses, and command lines,
configs and checkpoints of earlier versions (flat settings, ``algo=dp``) are read or refused by
name."""

from __future__ import annotations

import os

import pytest
from omegaconf import OmegaConf
from recipe_loader import ROOT, compose  # noqa: F401  (puts this checkout's recipes/ first)

from recipes import common
from rfmp_rl.eval import EvalConfig
from rfmp_rl.modules import ModelConfig
from rfmp_rl.training import OptimConfig, TrainConfig


def test_old_command_lines_are_renamed():
    argv = ["train.py", "horizon=8", "t0_fraction=0.3", "+prior=wrapped", "algo=dp",
            "optim.lr=1e-3", "preset=paper", "eval.seeds=3", "train.select_seeds=50"]
    assert common.upgrade_argv(argv) == [
        "train.py", "model.horizon=8", "loss.t0_fraction=0.3", "+model.prior_sphere=wrapped",
        "algo=ddim", "optim.lr=1e-3", "model.unet_preset=paper", "eval.seeds=3", "select.seeds=50"]


def test_old_configs_move_into_the_groups():
    old = {"algo": "dp", "horizon": 16, "obs_horizon": 2, "preset": "small", "prior": "uniform",
           "lambda_x": 2.5, "time_max": 2.0, "t0_fraction": 0.5, "logger": "csv",
           "optim": {"lr": 1e-3}, "train": {"steps": 5, "select_by": "rollout",
                                             "select_seeds": 50, "select_t_end": 1.0}}
    new = common.upgrade_config(old)
    assert new["algo"] == "ddim" and new["optim"] == {"lr": 1e-3}
    assert new["train"] == {"steps": 5, "select_by": "rollout"}
    assert new["select"] == {"seeds": 50, "t_end": 1.0}
    assert new["model"] == {"horizon": 16, "obs_horizon": 2, "unet_preset": "small",
                            "prior_sphere": "uniform"}
    assert new["loss"] == {"lambda_x": 2.5, "time_max": 2.0, "t0_fraction": 0.5}
    assert new["logger"] == {"backend": "csv"} and "horizon" in old  # the input is kept
    assert common.upgrade_config(new) == new


@pytest.mark.parametrize("recipe", ["pusht", "robosuite"])
def test_groups_map_one_to_one_onto_the_dataclasses(recipe):
    cfg = compose(recipe, ["algo=srfmp", "model.horizon=8", "model.action_steps=4",
                           "loss.time_max=2.0", "loss.t0_fraction=0.25"])
    names = {f for f in ModelConfig.__dataclass_fields__}
    assert set(cfg.model) <= names and not set(cfg.model) & set(common.TASK_MODEL_FIELDS)
    assert set(cfg.loss) == set(common.LOSS_FIELDS)
    assert set(cfg.eval) == set(EvalConfig.__dataclass_fields__)
    assert set(cfg.train) <= set(TrainConfig.__dataclass_fields__)
    assert set(cfg.optim) == set(OptimConfig.__dataclass_fields__)
    model = common.model_config(cfg, action_manifold="R2", obs_dim=3)
    assert (model.algorithm, model.horizon, model.action_steps) == ("srfmp", 8, 4)
    assert common.loss_config(cfg).time_max == 2.0 and common.eval_config(cfg).seeds == 50
    assert "model.horizon" in common.fixed_settings(cfg, ("obs",))
    assert "loss.t0_fraction" in common.fixed_settings(cfg, ("obs",))


def test_loss_options_of_other_algorithms_stay_neutral():
    cfg = compose("pusht", ["algo=rfmp", "loss.time_max=2.0", "loss.t0_fraction=0.3"])
    assert common.loss_config(cfg).time_max == 1.0  # SRFMP's option
    assert common.loss_config(cfg).t0_fraction == 0.3
    cfg = compose("pusht", ["algo=ddim", "loss.t0_fraction=0.3"])
    assert common.loss_config(cfg).t0_fraction == 0.0  # the flows' option


def test_bad_groups_and_algorithms_are_named():
    with pytest.raises(ValueError, match="algo=dp is now algo=ddim"):
        common.check_algo(OmegaConf.create({"algo": "dp"}))
    with pytest.raises(ValueError, match="algo must be one of"):
        common.check_algo(OmegaConf.create({"algo": "ddpm"}))
    cfg = compose("pusht", ["+model.obs_dim=3"])
    with pytest.raises(ValueError, match="model.obs_dim is not an architecture setting"):
        common.model_config(cfg, action_manifold="R2")
    cfg = compose("pusht", ["+loss.lr=3"])
    with pytest.raises(ValueError, match="loss.lr is not a loss setting"):
        common.loss_config(cfg)
    cfg = compose("pusht", ["+eval.seed=3"])
    with pytest.raises(ValueError, match="eval.seed is not an evaluation setting"):
        common.eval_config(cfg)


def test_a_script_takes_an_old_command_line(tmp_path):
    import os
    import subprocess
    import sys

    env = dict(os.environ, PYTHONPATH=str(ROOT), OMP_NUM_THREADS="1")
    done = subprocess.run(
        [sys.executable, str(ROOT / "recipes" / "pusht" / "train.py"), "algo=dp", "horizon=8",
         "t0_fraction=0.0", "optim.lr=1e-3", "--cfg", "job"],
        capture_output=True, text=True, env=env, timeout=120, cwd=tmp_path)
    assert done.returncode == 0, done.stderr[-2000:]
    cfg = OmegaConf.create(done.stdout)
    assert cfg.algo == "ddim" and cfg.model.horizon == 8 and cfg.optim.lr == 1e-3
    assert "note: horizon=8 is now model.horizon=8" in done.stderr


def test_tau_max_for_an_srfmp_checkpoint_without_one(make_tiny_model, tmp_path):
    import math

    from rfmp_rl.objectives import LossConfig

    model = make_tiny_model("srfmp")
    loss = LossConfig(time_max=2.0).to_dict()
    common.set_tau_max(model, "trained", loss, tmp_path / "best.pt")
    assert model.cfg.tau_max == pytest.approx(1 - math.exp(-5.0))  # tau at t = 2, rate 2.5
    common.set_tau_max(model, 0.9, loss, tmp_path / "best.pt")
    assert model.cfg.tau_max == 0.9
    with pytest.raises(SystemExit, match="tau_max=1.5: ModelConfig.tau_max must lie between"):
        common.set_tau_max(model, 1.5, loss, tmp_path / "best.pt")
    with pytest.raises(SystemExit, match="stores no loss settings"):
        common.set_tau_max(model, "trained", None, tmp_path / "best.pt")
    with pytest.raises(SystemExit, match="applies to SRFMP checkpoints.*holds rfmp"):
        common.set_tau_max(make_tiny_model("rfmp"), "trained", loss, tmp_path / "best.pt")


def test_command_line_is_runnable_from_the_repository_root(tmp_path):
    line = common.command_line(["recipes/pusht/train.py", "eval.nfes=[1,3]", "a=b c"],
                               {"OMP_NUM_THREADS": "1", "MUJOCO_GL": "egl", "HOME": "/x"},
                               cwd=ROOT)
    assert line == ("OMP_NUM_THREADS=1 MUJOCO_GL=egl python recipes/pusht/train.py "
                    "'eval.nfes=[1,3]' 'a=b c'")
    # an absolute script inside the checkout is shown from the root
    assert common.command_line([str(ROOT / "recipes/pusht/train.py")], {}, cwd=ROOT) == (
        "python recipes/pusht/train.py")
    # launched elsewhere, the line goes there first (relative out_dir= stays right)
    assert common.command_line(["train.py", "out_dir=runs/x"], {}, cwd=tmp_path) == (
        f"cd {tmp_path} && python {tmp_path / 'train.py'} out_dir=runs/x")
    # torchrun: one node is --standalone; several give their count (torchrun's node count)
    one = {"LOCAL_WORLD_SIZE": "2", "WORLD_SIZE": "2", "GROUP_WORLD_SIZE": "1"}
    assert common.command_line(["recipes/pusht/train.py"], one, cwd=ROOT) == (
        "torchrun --standalone --nproc_per_node=2 recipes/pusht/train.py")
    uneven = {"LOCAL_WORLD_SIZE": "2", "WORLD_SIZE": "3"}
    assert common.command_line(["t.py"], uneven, cwd=ROOT).startswith(
        "torchrun --nnodes=2 --nproc_per_node=2 ")
    # this process: the interpreter as launched (a virtual environment's stays in its bin)
    import sys
    mine = common.command_line().split()
    assert {os.path.relpath(sys.executable, ROOT), sys.executable} & set(mine), mine
