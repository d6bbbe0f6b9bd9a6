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

import hydra
import utils
from omegaconf import DictConfig

from recipes import common

TRAINING = common.RecipeTraining.from_utils(
    utils, recipe="robosuite",
    run_name=lambda cfg: f"{cfg.task}_{cfg.algo}_{cfg.obs}_{cfg.action_space}",
    what=lambda cfg: f"{cfg.algo} on {cfg.task} ({cfg.obs}, {cfg.action_space})",
    prepare=utils.ensure_demos)  # the scripted expert writes the file once, on rank 0
train, run = TRAINING.train, TRAINING.run  # run: also the engine's FitResult


@hydra.main(config_path=".", config_name="config", version_base="1.3")
def main(cfg: DictConfig) -> None:
    TRAINING.main(cfg)


if __name__ == "__main__":
    common.run_cli(main)
