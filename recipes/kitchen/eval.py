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

import sys

import hydra
from omegaconf import DictConfig
from utils import check_config, eval_task

from recipes.common import load_for_eval, report, run_sweep, show, upgrade_argv


def evaluate_checkpoint(cfg: DictConfig) -> list[dict]:
    """Run the sweep on ``cfg.checkpoint``; returns the table rows."""
    model, task_cfg, extra, out = load_for_eval(cfg, check_config)
    task = eval_task(task_cfg)
    rows = run_sweep(model, task_cfg, task, progress=show(task))
    title = (f"Franka Kitchen: {task_cfg.algo} ({task_cfg.model.unet_preset}, step "
             f"{extra.get('step')}, {extra.get('train_minutes', float('nan')):.0f} min training)")
    command = "python recipes/kitchen/eval.py " + " ".join(sys.argv[1:])
    print(report(rows, out, task_cfg, task, title, command).read_text())
    return rows


@hydra.main(config_path=".", config_name="config", version_base="1.3")
def main(cfg: DictConfig) -> None:
    evaluate_checkpoint(cfg)


if __name__ == "__main__":
    sys.argv = upgrade_argv(sys.argv)  # settings of earlier versions, renamed (printed)
    main()
