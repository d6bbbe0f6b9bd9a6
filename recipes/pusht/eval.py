"""Evaluate a Push-T checkpoint: ``eval.seeds`` seeds (from ``eval.seed_start``) for every NFE in
``eval.nfes`` and end time T in ``eval.t_ends`` (DDIM: T = 1), in one batched env per setting.

    python recipes/pusht/eval.py checkpoint=runs/pusht/<run>/best.pt
    python recipes/pusht/eval.py checkpoint=... eval.seeds=10 eval.nfes=[1] eval.t_ends=[1.0,1.6]

The task settings (algo, obs, space, horizons) come from the checkpoint's stored config; the
``eval.*`` fields from the command line. Writes eval.csv, eval.md and eval.png to ``eval.out``
(default: ``<checkpoint folder>/eval``) and prints the table. Scores are the paper's: maximum
coverage over the episode (early stop at 95%), mean over seeds; jerk of the executed actions.
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
        print(f"  NFE={row['nfe']:<2} T={row['t_end']:.1f}: score {row['score']:.3f}, "
              f"success {row['success']:.2f}, jerk {row['jerk']:.3g} ({row['seconds']:.0f} s)")

    rows = sweep(model, task, progress=show)
    title = (f"Push-T {task.obs} {task.space}: {task.algo} ({task.preset}, step "
             f"{extra.get('step')}, {extra.get('train_minutes', float('nan')):.0f} min training)")
    command = "python recipes/pusht/eval.py " + " ".join(sys.argv[1:])
    print(write_tables(rows, out, title, command, task.eval.time_table).read_text())
    return rows


@hydra.main(config_path=".", config_name="config", version_base="1.3")
def main(cfg: DictConfig) -> None:
    evaluate_checkpoint(cfg)


if __name__ == "__main__":
    main()
