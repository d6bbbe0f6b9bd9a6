"""Evaluate a robosuite checkpoint: ``eval.seeds`` seeds from ``eval.seed_start`` (not the
demonstration seeds) for every NFE in ``eval.nfes``; success rate, jerk of the executed actions
and, for pose actions, how far the executed quaternions are from unit norm.

    python recipes/robosuite/eval.py checkpoint=runs/robosuite/<run>/best.pt
    python recipes/robosuite/eval.py checkpoint=... eval.seeds=10 eval.nfes=[1,3]

The task settings come from the checkpoint's stored config (that of an earlier version is
upgraded), the ``eval.*`` fields from the command line. Writes eval.csv and eval.md to
``eval.out`` (default ``<checkpoint folder>/eval``).
"""

from __future__ import annotations

import hydra
import utils
from omegaconf import DictConfig

from recipes import common


def evaluate_checkpoint(cfg: DictConfig) -> list[dict]:
    """Run the sweep on ``cfg.checkpoint``; returns the table rows."""
    return common.evaluate_checkpoint(
        cfg, "robosuite", utils.check_config, utils.eval_task,  # the env follows the model
        name=lambda task_cfg: f"{task_cfg.task} {task_cfg.obs} {task_cfg.action_space}")


@hydra.main(config_path=".", config_name="config", version_base="1.3")
def main(cfg: DictConfig) -> None:
    evaluate_checkpoint(cfg)


if __name__ == "__main__":
    common.run_cli(main)
