"""Success rate at every evaluated NFE, one row per training run, from the runs' own files.

    python recipes/robosuite/summary.py runs/robosuite/lift_srfmp_s13 runs/robosuite/can_dp_s16 \
        --out results/robosuite_summary.md

Each run folder needs ``config.yaml`` and ``history.json`` (written by ``train.py``) and
``eval/eval.csv`` (its final evaluation, or ``eval.py``'s); the training column is read from
them: steps, minutes, learning rate and ``loss.t0_fraction`` (the flat
configs of earlier versions are read too). Where the paper reports the setting (state
observations: `recipes.paper.ROBOMIMIC_STATE`), a cell is ours / the paper's.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import yaml

from recipes import paper
from recipes.common import upgrade_config
from rfmp_rl.eval import read_table

ALGO_NAMES = {"srfmp": "SRFMP", "rfmp": "RFMP", "ddim": "DDIM"}


def _read(run: Path) -> tuple[dict, list[dict], list[dict]]:
    files = {name: run / name for name in ("config.yaml", "history.json", "eval/eval.csv")}
    missing = [str(p) for p in files.values() if not p.is_file()]
    if missing:
        raise FileNotFoundError(f"run {run}: missing {', '.join(missing)}")
    cfg = upgrade_config(yaml.safe_load(files["config.yaml"].read_text()))
    history = json.loads(files["history.json"].read_text())
    rows = read_table(files["eval/eval.csv"])
    if not history or not rows:
        raise ValueError(f"run {run}: empty history.json or eval/eval.csv")
    return cfg, history, rows


def summary(runs: list[Path]) -> str:
    nfes = sorted({int(r["nfe"]) for run in runs for r in _read(run)[2]})
    head = ["task", "algo", "obs", "actions", *(f"NFE {n}, T=1 asked" for n in nfes), "training",
            "run"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for run in runs:
        cfg, history, rows = _read(run)
        success = {int(r["nfe"]): float(r["success"]) for r in rows if float(r["t_end"]) == 1.0}
        reached = {int(r["nfe"]): float(r["t_reached"]) for r in rows
                   if float(r["t_end"]) == 1.0 and r.get("t_reached") not in (None, "")}
        last = history[-1]
        training = f"{last['step']} steps, {last['minutes']:.0f} min, lr {cfg['optim']['lr']:g}"
        if cfg.get("loss", {}).get("t0_fraction"):
            training += f", t0_fraction {cfg['loss']['t0_fraction']:g}"
        actions = cfg["action_space"]
        if actions == "abs_pose":
            actions += f"/{cfg['geometry']}"
        theirs = paper.robomimic_state(cfg["task"], cfg["algo"]) if cfg["obs"] == "state" else {}
        cells = [f"{success[n]:.2f}"
                 + (f" / {theirs[(n, 1.0)]:.3f}" if (n, 1.0) in theirs else "")
                 + (f" (T {reached[n]:.2f} reached)"
                    if abs(reached.get(n, 1.0) - 1.0) > 1e-6 else "")
                 if n in success else "-" for n in nfes]
        lines.append("| " + " | ".join([cfg["task"], ALGO_NAMES.get(cfg["algo"], cfg["algo"]),
                                        cfg["obs"], actions, *cells, training, f"`{run}`"]) + " |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="+", type=Path, help="training run folders")
    parser.add_argument("--out", type=Path, default=None, help="write the table here as well")
    args = parser.parse_args(argv)
    table = summary(args.runs)
    command = "python recipes/robosuite/summary.py " + " ".join(str(r) for r in args.runs)
    text = (f"Success over 50 seeds (end time T = 1 asked; a cell whose solver stopped at another "
            f"T names the T it reached) of each run's evaluated checkpoint; where the paper "
            f"reports the setting, ours / the paper's (table \"{paper.ROBOMIMIC_STATE.caption}\", "
            f"state observations, robomimic's human demonstrations, mean over its seeds).\n\n"
            f"Command: `{command}`\n\n{table}")
    sys.stdout.write(text)
    if args.out:
        args.out.write_text(text)


if __name__ == "__main__":
    main()
