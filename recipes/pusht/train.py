"""Train RFMP / SRFMP / Diffusion Policy (DDIM) on Push-T or Sphere Push-T from Diffusion
Policy's human demonstrations, then evaluate the best checkpoint.

    python recipes/pusht/train.py algo=srfmp obs=state space=euclidean train.max_minutes=60
    python recipes/pusht/train.py algo=rfmp space=sphere prior=wrapped

Writes to ``runs/pusht/<algo>_<obs>_<space>_<time>/``: ``best.pt`` (the EMA weights of the best
validation loss, or of the best rollout score on the selection seeds with
``train.select_by=rollout``), ``last.pt``, ``logs/`` (TorchRL CSV logger: train loss, lr,
validation loss and rollout score), and, with ``eval.final_eval=true``, ``eval/`` (eval.csv,
eval.md, eval.png) from `eval.py`'s sweep.
"""

from __future__ import annotations

from datetime import datetime
from pathlib import Path

import hydra
from omegaconf import DictConfig
from utils import (  # noqa: I001
    CONTROL_RATE_HZ,
    build_training,
    check_config,
    eval_model,
    exit_code,
    fit,
    make_loss_config,
    make_model,
    make_replay_buffer,
    make_stores,
    selection_score,
    start_run,
    sweep,
    write_tables,
)

from rfmp_rl import keys
from rfmp_rl.training import FitResult

#: Settings that define a run: a resumed run may not change them.
FIXED = ("algo", "obs", "space", "prior", "prior_scale", "prior_repeat", "preset", "down_dims",
         "horizon", "action_steps", "obs_horizon", "lambda_x", "lambda_tau", "time_max",
         "t0_fraction", "seed")


def train(cfg: DictConfig, overrides=None) -> Path:
    """Train, keep the best checkpoint, optionally evaluate it; returns the run folder.
    ``overrides``: the command line's explicit overrides (applied on top of a resumed run's
    configuration)."""
    return run(cfg, overrides)[0]


def run(cfg: DictConfig, overrides=None) -> tuple[Path, FitResult]:
    """`train`, also returning the engine's `FitResult` (steps, best score, interruption)."""
    check_config(cfg)
    stamp = datetime.now().strftime("%Y%m%d_%H%M%S")
    cfg, runtime, run_dir, last = start_run(cfg, "pusht", FIXED, overrides,
                                            f"{cfg.algo}_{cfg.obs}_{cfg.space}_{stamp}")
    check_config(cfg)
    model, rb, val_rb = build_training(cfg, runtime, make_stores, make_replay_buffer,
                                       make_model, f"{cfg.algo} on Push-T ({cfg.obs}, {cfg.space})")
    result = fit(model, rb, val_rb, cfg, run_dir, runtime, "pusht", last,
                 camera_keys={keys.PIXELS: keys.PIXELS} if cfg.obs == "image" else None,
                 rollout_score=selection_score(cfg), loss=make_loss_config(cfg),
                 control_rate_hz=CONTROL_RATE_HZ)
    if cfg.eval.final_eval and runtime.is_main and not result.interrupted:
        best_model, meta = eval_model(run_dir / "best.pt", cfg, runtime)

        def show(row):
            print(f"  NFE={row['nfe']:<2} T={row['t_end']:.1f}: score {row['score']:.3f}, "
                  f"success {row['success']:.2f}, jerk {row['jerk']:.3g} ({row['seconds']:.0f} s)")

        rows = sweep(best_model, cfg, progress=show)
        title = (f"Push-T {cfg.obs} {cfg.space}: {cfg.algo} ({cfg.preset}, best of "
                 f"{result.steps} steps at step {meta['extra'].get('step')}, "
                 f"{result.minutes:.0f} min)")
        command = f"python recipes/pusht/eval.py checkpoint={run_dir / 'best.pt'}"
        print(write_tables(rows, run_dir / "eval", title, command, cfg.eval.time_table).read_text())
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
