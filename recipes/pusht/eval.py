"""Evaluate a Push-T checkpoint: ``eval.seeds`` seeds (from ``eval.seed_start``) for every NFE in
``eval.nfes`` and end time T in ``eval.t_ends`` (DDIM: T = 1), in one batched env per setting.

    python recipes/pusht/eval.py checkpoint=runs/pusht/<run>/best.pt
    python recipes/pusht/eval.py checkpoint=... eval.seeds=10 eval.nfes=[1] eval.t_ends=[1.0,1.6]

The task settings (algo, obs, space, model) come from the checkpoint's stored config (that of an
earlier version is upgraded); the ``eval.*`` fields from the command line. Writes eval.csv,
eval.md and eval.png to ``eval.out`` (default: ``<checkpoint folder>/eval``) and prints the
table. Scores are the paper's: maximum coverage over the episode (early stop at 95%), mean over
seeds, beside the paper's Push-T figures (Sphere Push-T: its row of the run's prior;
`utils.paper_figures`); jerk of the executed actions.
"""

from __future__ import annotations

import hydra
import utils
from omegaconf import DictConfig

from recipes import common


def evaluate_checkpoint(cfg: DictConfig) -> list[dict]:
    """Run the sweep on ``cfg.checkpoint``; returns the table rows."""
    return common.evaluate_checkpoint(
        cfg, "pusht", utils.check_config, lambda task_cfg, model: utils.eval_task(task_cfg),
        name=lambda task_cfg: f"Push-T {task_cfg.obs} {task_cfg.space}")


@hydra.main(config_path=".", config_name="config", version_base="1.3")
def main(cfg: DictConfig) -> None:
    evaluate_checkpoint(cfg)


if __name__ == "__main__":
    common.run_cli(main)
