"""Evaluate a Franka Kitchen checkpoint: ``eval.seeds`` seeds from ``eval.seed_start`` (not the
demonstration seeds) for every NFE in ``eval.nfes``; success on all four subtasks, each
subtask's rate, the jerk of the executed positions and how far the executed quaternions are
from unit norm.

    python recipes/kitchen/eval.py checkpoint=runs/kitchen/<run>/best.pt
    python recipes/kitchen/eval.py checkpoint=... eval.seeds=10 eval.nfes=[1,3]

The task settings come from the checkpoint's stored config, the ``eval.*`` fields from the
command line. Writes eval.csv and eval.md to ``eval.out`` (default
``<checkpoint folder>/eval``).
"""

from __future__ import annotations

import hydra
import utils
from omegaconf import DictConfig

from recipes import common


def evaluate_checkpoint(cfg: DictConfig) -> list[dict]:
    """Run the sweep on ``cfg.checkpoint``; returns the table rows."""
    return common.evaluate_checkpoint(
        cfg, "kitchen", utils.check_config, lambda task_cfg, model: utils.eval_task(task_cfg),
        name=lambda task_cfg: "Franka Kitchen")


@hydra.main(config_path=".", config_name="config", version_base="1.3")
def main(cfg: DictConfig) -> None:
    evaluate_checkpoint(cfg)


if __name__ == "__main__":
    common.run_cli(main)
