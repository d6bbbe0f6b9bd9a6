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

import hydra
import utils
from omegaconf import DictConfig

from recipes import common

TRAINING = common.RecipeTraining.from_utils(
    utils, recipe="kitchen", run_name=lambda cfg: str(cfg.algo),
    what=lambda cfg: f"{cfg.algo} on Franka Kitchen (R3 x S3 x R2, T_p {cfg.model.horizon})",
    prepare=utils.ensure_demos)  # the scripted expert writes the dataset once, on rank 0
train, run = TRAINING.train, TRAINING.run  # run: also the engine's FitResult


@hydra.main(config_path=".", config_name="config", version_base="1.3")
def main(cfg: DictConfig) -> None:
    TRAINING.main(cfg)


if __name__ == "__main__":
    common.run_cli(main)
