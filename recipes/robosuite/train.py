"""Train RFMP / SRFMP / Diffusion Policy (DDIM) / Consistency Policy on a robosuite task (Lift,
PickPlaceCan, NutAssemblySquare, TwoArmTransport, ToolHang, PickPlaceMug, MugFlip) from
scripted-expert demonstrations (robomimic HDF5), then evaluate the best checkpoint over 50
seeds at NFE {1, 2, 3, 5, 10}.

    python recipes/robosuite/train.py task=Lift algo=srfmp train.max_minutes=60
    python recipes/robosuite/train.py task=PickPlaceCan action_space=abs_pose   # R3 x S3 x R1
    python recipes/robosuite/train.py task=Lift action_space=abs_pose geometry=euclidean

The demonstrations default to ``data/robosuite/<task>_<action_space>.hdf5``, written by the
scripted expert on first use (``python recipes/robosuite/experts.py`` does it alone).
Writes ``runs/robosuite/<task>_<algo>_<obs>_<action_space>_<time>/``: ``best.pt``, ``last.pt``,
``logs/``, ``history.json`` and ``eval/`` (eval.csv, eval.md).
"""

from __future__ import annotations

import sys
from datetime import datetime
from pathlib import Path

import hydra
from omegaconf import DictConfig
from utils import (
    CONTROL_RATE_HZ,
    TASK_KEYS,
    check_config,
    ensure_demos,
    eval_task,
    make_model,
    make_replay_buffer,
    make_stores,
)

from recipes import common
from rfmp_rl.training import FitResult


def train(cfg: DictConfig, overrides=None) -> Path:
    """Train, keep the best checkpoint, optionally evaluate it; returns the run folder.
    ``overrides``: the command line's explicit overrides (applied on top of a resumed run's
    configuration)."""
    return run(cfg, overrides)[0]


def run(cfg: DictConfig, overrides=None) -> tuple[Path, FitResult]:
    """`train`, also returning the engine's `FitResult` (steps, best score, interruption)."""
    check_config(cfg)
    name = f"{cfg.task}_{cfg.algo}_{cfg.obs}_{cfg.action_space}_{datetime.now():%Y%m%d_%H%M%S}"
    fixed = common.fixed_settings(cfg, TASK_KEYS)
    cfg, runtime, run_dir, last = common.start_run(cfg, "robosuite", fixed, overrides, name)
    check_config(cfg)
    if runtime.is_main:
        ensure_demos(cfg)  # the scripted expert writes the file once, on rank 0
    runtime.barrier()
    what = f"{cfg.algo} on {cfg.task} ({cfg.obs}, {cfg.action_space})"
    model, rb, val_rb = common.build_training(cfg, runtime, make_stores, make_replay_buffer,
                                              make_model, what)
    result = common.fit(model, rb, val_rb, cfg, run_dir, runtime, "robosuite", last,
                        control_rate_hz=CONTROL_RATE_HZ)
    if cfg.eval.final_eval and runtime.is_main and not result.interrupted:
        best, meta = common.eval_model(run_dir / "best.pt", cfg, runtime)
        task = eval_task(cfg)
        rows = common.run_sweep(best, cfg, task, progress=common.show(task))
        title = (f"{what}: {cfg.model.unet_preset}, best of {result.steps} steps at step "
                 f"{meta['extra'].get('step')}, {result.minutes:.0f} min")
        command = f"python recipes/robosuite/eval.py checkpoint={run_dir / 'best.pt'}"
        print(common.report(rows, run_dir / "eval", cfg, task, title, command).read_text())
    if runtime.is_main:
        print(f"run folder: {run_dir}")
    runtime.shutdown()
    return run_dir, result


@hydra.main(config_path=".", config_name="config", version_base="1.3")
def main(cfg: DictConfig) -> None:
    from hydra.core.hydra_config import HydraConfig

    _, result = run(cfg, overrides=list(HydraConfig.get().overrides.task))
    raise SystemExit(common.exit_code(result))


if __name__ == "__main__":
    sys.argv = common.upgrade_argv(sys.argv)  # settings of earlier versions, renamed (printed)
    main()
