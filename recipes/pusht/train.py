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

import hydra
import utils
from omegaconf import DictConfig

from recipes import common
from rfmp_rl import keys


def _fit_options(cfg: DictConfig) -> dict:
    return {"camera_keys": {keys.PIXELS: keys.PIXELS} if cfg.obs == "image" else None,
            "rollout_score": utils.selection_score(cfg),
            "control_rate_hz": utils.CONTROL_RATE_HZ}


TRAINING = common.RecipeTraining.from_utils(
    utils, recipe="pusht", run_name=lambda cfg: f"{cfg.algo}_{cfg.obs}_{cfg.space}",
    what=lambda cfg: f"{cfg.algo} on Push-T ({cfg.obs}, {cfg.space})", fit_options=_fit_options,
    heading=lambda cfg, what, result, step: (
        f"Push-T {cfg.obs} {cfg.space}: {cfg.algo} ({cfg.model.unet_preset}, best of "
        f"{result.steps} steps at step {step}, {result.minutes:.0f} min)"))
train, run = TRAINING.train, TRAINING.run  # run: also the engine's FitResult


@hydra.main(config_path=".", config_name="config", version_base="1.3")
def main(cfg: DictConfig) -> None:
    TRAINING.main(cfg)


if __name__ == "__main__":
    common.run_cli(main)
