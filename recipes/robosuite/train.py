"""Train RFMP / SRFMP / Diffusion Policy (DDIM) on robosuite Lift, PickPlaceCan or
NutAssemblySquare from scripted-expert demonstrations (robomimic HDF5), then evaluate the best
checkpoint over 50 seeds at NFE {1, 2, 3, 5, 10}.

    python recipes/robosuite/train.py task=Lift algo=srfmp train.max_minutes=60
    python recipes/robosuite/train.py task=PickPlaceCan action_space=abs_pose   # R3 x S3 x R1
    python recipes/robosuite/train.py task=Lift action_space=abs_pose geometry=euclidean

The demonstrations default to ``data/robosuite/<task>_<action_space>.hdf5``, written by the
scripted expert on first use (``python recipes/robosuite/experts.py`` does it alone).
Writes ``runs/robosuite/<task>_<algo>_<obs>_<action_space>_<time>/``: ``best.pt``, ``last.pt``,
``logs/``, ``history.json`` and ``eval/`` (eval.csv, eval.md).
"""

from __future__ import annotations

from datetime import datetime
from pathlib import Path

import hydra
from omegaconf import DictConfig
from utils import (  # noqa: I001
    build_training,
    check_config,
    ensure_demos,
    eval_model,
    exit_code,
    fit,
    make_model,
    make_replay_buffer,
    make_stores,
    start_run,
    sweep,
    write_tables,
)

from rfmp_rl.training import FitResult


def show(row: dict) -> None:
    print(f"  NFE={row['nfe']:<2} T={row['t_end']:.1f}: success {row['success']:.2f}, "
          f"jerk {row['jerk']:.3g} ({row['seconds']:.0f} s)")


#: Settings that define a run: a resumed run may not change them.
FIXED = ("task", "algo", "obs", "action_space", "geometry", "prior", "prior_scale",
         "prior_repeat", "preset", "down_dims", "horizon", "action_steps", "obs_horizon",
         "lambda_x", "lambda_tau", "time_max", "t0_fraction", "seed")


def train(cfg: DictConfig, overrides=None) -> Path:
    """Train, keep the best checkpoint, optionally evaluate it; returns the run folder.
    ``overrides``: the command line's explicit overrides (applied on top of a resumed run's
    configuration)."""
    return run(cfg, overrides)[0]


def run(cfg: DictConfig, overrides=None) -> tuple[Path, FitResult]:
    """`train`, also returning the engine's `FitResult` (steps, best score, interruption)."""
    check_config(cfg)
    stamp = datetime.now().strftime("%Y%m%d_%H%M%S")
    cfg, runtime, run_dir, last = start_run(
        cfg, "robosuite", FIXED, overrides,
        f"{cfg.task}_{cfg.algo}_{cfg.obs}_{cfg.action_space}_{stamp}")
    check_config(cfg)
    if runtime.is_main:
        ensure_demos(cfg)  # the scripted expert writes the file once, on rank 0
    runtime.barrier()
    what = f"{cfg.algo} on {cfg.task} ({cfg.obs}, {cfg.action_space})"
    model, rb, val_rb = build_training(cfg, runtime, make_stores, make_replay_buffer,
                                       make_model, what)
    result = fit(model, rb, val_rb, cfg, run_dir, runtime, "robosuite", last)
    if cfg.eval.final_eval and runtime.is_main and not result.interrupted:
        best_model, meta = eval_model(run_dir / "best.pt", cfg, runtime)
        rows = sweep(best_model, cfg, progress=show)
        title = (f"{cfg.task} {cfg.obs} {cfg.action_space}: {cfg.algo} ({cfg.preset}, best of "
                 f"{result.steps} steps at step {meta['extra'].get('step')}, "
                 f"{result.minutes:.0f} min)")
        command = f"python recipes/robosuite/eval.py checkpoint={run_dir / 'best.pt'}"
        print(write_tables(rows, run_dir / "eval", title, command).read_text())
    if runtime.is_main:
        print(f"run folder: {run_dir}")
    runtime.shutdown()
    return run_dir, result


@hydra.main(config_path=".", config_name="config", version_base="1.3")
def main(cfg: DictConfig) -> None:
    from hydra.core.hydra_config import HydraConfig

    _, result = run(cfg, overrides=list(HydraConfig.get().overrides.task))
    raise SystemExit(exit_code(result))


if __name__ == "__main__":
    main()
