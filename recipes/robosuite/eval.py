"""Evaluate a robosuite checkpoint: ``eval.seeds`` seeds from ``eval.seed_start`` (not the
demonstration seeds) for every NFE in ``eval.nfes``; success rate, jerk of the executed actions
and, for pose actions, how far the executed quaternions are from unit norm.

    python recipes/robosuite/eval.py checkpoint=runs/robosuite/<run>/best.pt
    python recipes/robosuite/eval.py checkpoint=... eval.seeds=10 eval.nfes=[1,3]

The task settings come from the checkpoint's stored config, the ``eval.*`` fields from the
command line. Writes eval.csv and eval.md to ``eval.out`` (default ``<checkpoint folder>/eval``).
"""

from __future__ import annotations

import sys

import hydra
from omegaconf import DictConfig
from utils import check_config, load_for_eval, sweep, write_tables  # noqa: I001


def evaluate_checkpoint(cfg: DictConfig) -> list[dict]:
    """Run the sweep on ``cfg.checkpoint``; returns the table rows."""
    model, task, extra, out = load_for_eval(cfg, check_config)

    def show(row):
        print(f"  NFE={row['nfe']:<2} T={row['t_end']:.1f}: success {row['success']:.2f}, "
              f"jerk {row['jerk']:.3g} ({row['seconds']:.0f} s)")

    rows = sweep(model, task, progress=show)
    title = (f"{task.task} {task.obs} {task.action_space}: {task.algo} ({task.preset}, step "
             f"{extra.get('step')}, {extra.get('train_minutes', float('nan')):.0f} min training)")
    command = "python recipes/robosuite/eval.py " + " ".join(sys.argv[1:])
    print(write_tables(rows, out, title, command).read_text())
    return rows


@hydra.main(config_path=".", config_name="config", version_base="1.3")
def main(cfg: DictConfig) -> None:
    evaluate_checkpoint(cfg)


if __name__ == "__main__":
    main()
