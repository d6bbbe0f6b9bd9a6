"""Train RFMP / SRFMP / Diffusion Policy (DDIM) on Franka Kitchen (microwave, kettle, light
switch, slide cabinet) with end-effector pose actions on R3 x S3 x R2, then evaluate the best
checkpoint over 50 seeds at NFE {1, 2, 3, 5, 10}: success on all four subtasks and each
subtask's rate.

    python recipes/kitchen/train.py algo=srfmp train.max_minutes=60
    python recipes/kitchen/train.py algo=ddim model.unet_preset=paper     # GPU
    python recipes/kitchen/train.py data.source=D4RL/kitchen/complete-v2  # a local Minari copy

The demonstrations default to ``data/kitchen/kitchen-expert-v0`` (Minari's layout), written by
the scripted expert on first use (``python recipes/kitchen/experts.py`` does it alone).
Writes ``runs/kitchen/<algo>_<time>/``: ``best.pt``, ``last.pt``, ``logs/``,
``history.json`` and ``eval/`` (eval.csv, eval.md).
"""

from __future__ import annotations

import sys
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


TRAINING = common.RecipeTraining(
    recipe="kitchen", task_keys=TASK_KEYS, check=check_config,
    run_name=lambda cfg: str(cfg.algo),
    what=lambda cfg: f"{cfg.algo} on Franka Kitchen (R3 x S3 x R2, T_p {cfg.model.horizon})",
    make_stores=make_stores, make_replay_buffer=make_replay_buffer, make_model=make_model,
    eval_task=eval_task, fit_options=lambda cfg: {"control_rate_hz": CONTROL_RATE_HZ},
    prepare=ensure_demos)  # the scripted expert writes the dataset once, on rank 0


def run(cfg: DictConfig, overrides=None) -> tuple[Path, FitResult]:
    """`train`, also returning the engine's `FitResult` (steps, best score, interruption)."""
    return common.train_run(cfg, TRAINING, overrides)

@hydra.main(config_path=".", config_name="config", version_base="1.3")
def main(cfg: DictConfig) -> None:
    from hydra.core.hydra_config import HydraConfig

    _, result = run(cfg, overrides=list(HydraConfig.get().overrides.task))
    raise SystemExit(common.exit_code(result))


if __name__ == "__main__":
    sys.argv = common.upgrade_argv(sys.argv)  # settings of earlier versions, renamed (printed)
    main()
