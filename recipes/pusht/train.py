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


def _fit_options(cfg: DictConfig) -> dict:
    return {"camera_keys": {keys.PIXELS: keys.PIXELS} if cfg.obs == "image" else None,
            "rollout_score": selection_score(cfg), "control_rate_hz": CONTROL_RATE_HZ}


TRAINING = common.RecipeTraining(
    recipe="pusht", task_keys=TASK_KEYS, check=check_config,
    run_name=lambda cfg: f"{cfg.algo}_{cfg.obs}_{cfg.space}",
    what=lambda cfg: f"{cfg.algo} on Push-T ({cfg.obs}, {cfg.space})",
    make_stores=make_stores, make_replay_buffer=make_replay_buffer, make_model=make_model,
    eval_task=eval_task, fit_options=_fit_options,
    heading=lambda cfg, what, result, step: (
        f"Push-T {cfg.obs} {cfg.space}: {cfg.algo} ({cfg.model.unet_preset}, best of "
        f"{result.steps} steps at step {step}, {result.minutes:.0f} min)"))


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
