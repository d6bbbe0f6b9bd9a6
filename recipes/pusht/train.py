"""Train RFMP / SRFMP / Diffusion Policy (DDIM) on Push-T or Sphere Push-T from Diffusion
Policy's human demonstrations, then evaluate the best checkpoint.

    python recipes/pusht/train.py algo=srfmp obs=state space=euclidean train.max_minutes=60
    python recipes/pusht/train.py algo=rfmp space=sphere model.prior_sphere=wrapped

Writes to ``runs/pusht/<algo>_<obs>_<space>_<time>/``: ``best.pt`` (the EMA weights of the best
validation loss, or of the best rollout score on the selection seeds with
``train.select_by=rollout``), ``last.pt``, ``logs/`` (TorchRL CSV logger: train loss, lr,
validation loss and rollout score), and, with ``eval.final_eval=true``, ``eval/`` (eval.csv,
eval.md, eval.png) from `eval.py`'s sweep.
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
    eval_task,
    make_model,
    make_replay_buffer,
    make_stores,
    selection_score,
)

from recipes import common
from rfmp_rl import keys
from rfmp_rl.training import FitResult


def train(cfg: DictConfig, overrides=None) -> Path:
    """Train, keep the best checkpoint, optionally evaluate it; returns the run folder.
    ``overrides``: the command line's explicit overrides (applied on top of a resumed run's
    configuration)."""
    return run(cfg, overrides)[0]


def run(cfg: DictConfig, overrides=None) -> tuple[Path, FitResult]:
    """`train`, also returning the engine's `FitResult` (steps, best score, interruption)."""
    check_config(cfg)
    name = f"{cfg.algo}_{cfg.obs}_{cfg.space}_{datetime.now():%Y%m%d_%H%M%S}"
    fixed = common.fixed_settings(cfg, TASK_KEYS)
    cfg, runtime, run_dir, last = common.start_run(cfg, "pusht", fixed, overrides, name)
    check_config(cfg)
    what = f"{cfg.algo} on Push-T ({cfg.obs}, {cfg.space})"
    model, rb, val_rb = common.build_training(cfg, runtime, make_stores, make_replay_buffer,
                                              make_model, what)
    result = common.fit(model, rb, val_rb, cfg, run_dir, runtime, "pusht", last,
                        camera_keys={keys.PIXELS: keys.PIXELS} if cfg.obs == "image" else None,
                        rollout_score=selection_score(cfg), control_rate_hz=CONTROL_RATE_HZ)
    if cfg.eval.final_eval and runtime.is_main and not result.interrupted:
        best, meta = common.eval_model(run_dir / "best.pt", cfg, runtime)
        task = eval_task(cfg)
        rows = common.run_sweep(best, cfg, task, progress=common.show(task))
        title = (f"Push-T {cfg.obs} {cfg.space}: {cfg.algo} ({cfg.model.unet_preset}, best of "
                 f"{result.steps} steps at step {meta['extra'].get('step')}, "
                 f"{result.minutes:.0f} min)")
        command = f"python recipes/pusht/eval.py checkpoint={run_dir / 'best.pt'}"
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
