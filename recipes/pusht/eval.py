"""Evaluate a Push-T checkpoint: ``eval.seeds`` seeds (from ``eval.seed_start``) for every NFE in
``eval.nfes`` and end time T in ``eval.t_ends`` (DDIM: T = 1), in one batched env per setting.

    python recipes/pusht/eval.py checkpoint=runs/pusht/<run>/best.pt
    python recipes/pusht/eval.py checkpoint=... eval.seeds=10 eval.nfes=[1] eval.t_ends=[1.0,1.6]

The task settings (algo, obs, space, model) come from the checkpoint's stored config (that of an
earlier version is upgraded); the ``eval.*`` fields from the command line. Writes eval.csv,
eval.md and eval.png to ``eval.out`` (default: ``<checkpoint folder>/eval``) and prints the
table. Scores are the paper's: maximum coverage over the episode (early stop at 95%), mean over
seeds, beside the paper's Euclidean Push-T figures; jerk of the executed actions.
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
    title = (f"Push-T {task_cfg.obs} {task_cfg.space}: {task_cfg.algo} "
             f"({task_cfg.model.unet_preset}, step {extra.get('step')}, "
             f"{extra.get('train_minutes', float('nan')):.0f} min training)")
    command = "python recipes/pusht/eval.py " + " ".join(sys.argv[1:])
    print(report(rows, out, task_cfg, task, title, command).read_text())
    return rows


@hydra.main(config_path=".", config_name="config", version_base="1.3")
def main(cfg: DictConfig) -> None:
    evaluate_checkpoint(cfg)


if __name__ == "__main__":
    sys.argv = upgrade_argv(sys.argv)  # settings of earlier versions, renamed (printed)
    main()
