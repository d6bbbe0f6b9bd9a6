"""How robust the quickstart's SRFMP integration-time figure is across training seeds.

    bash recipes/venv.sh python recipes/benchmarks/quickstart_seeds.py [--seeds 1 2 3]
        [--out results/quickstart_seeds.md] [key=value ...]

For each seed, trains SRFMP as `recipes/quickstart.py` does (its config file, plus any
``key=value`` overrides such as ``steps=1200``; SRFMP alone, in one process with ``threads``
threads where the quickstart gives its SRFMP worker half of them) and rolls it out closed loop
from the quickstart's 42 start points, at NFE 1, 5 and 10 and end times T = 1.0 and 1.6. Prints
the mean DTW to the nearest demonstration and the ratio DTW(T = 1.6) / DTW(T = 1.0) per NFE, the
figure the quickstart checks against 1.10 (RFMP is not trained here: its growth past
t = 1 is not in doubt).
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import torch
from omegaconf import OmegaConf

from recipes import quickstart as qs
from rfmp_rl.eval.tables import setting_label
from rfmp_rl.solvers import SolverConfig

ROOT = Path(__file__).resolve().parents[2]


NFES, T_ENDS = (1, 5, 10), (1.0, 1.6)


def run_seed(cfg, seed: int) -> dict:
    cfg = OmegaConf.merge(cfg, {"seed": seed})
    torch.manual_seed(seed)
    demos = qs.load_shapes(cfg)
    store = qs.make_store(cfg)
    runtime = qs.setup_runtime(cfg.device, cfg.precision, cfg.compile, distributed=False)
    with tempfile.TemporaryDirectory() as run_dir:  # the engine's checkpoints, not kept
        _, ema, seconds = qs.train("srfmp", store, cfg, runtime, Path(run_dir))
    model = ema.module.eval()
    rows, _ = qs.sweep("srfmp", model, demos, cfg, nfes=NFES, t_ends=T_ENDS)  # the quickstart's
    dtw = {(row["nfe"], row["t_end"]): row["dtw"] for row in rows}  # start points and metrics
    return {"seconds": seconds, "dtw": dtw}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3])
    parser.add_argument("--out", default=None)
    args, overrides = parser.parse_known_args()
    cfg = OmegaConf.load(ROOT / "recipes" / "quickstart.yaml")
    for key in ("defaults", "hydra"):
        cfg.pop(key, None)
    cfg = OmegaConf.merge(cfg, OmegaConf.from_dotlist(overrides))
    torch.set_num_threads(int(cfg.threads))
    def reached(nfe: int, t_end: float) -> float:  # SRFMP's schedule stops short at low NFE
        return SolverConfig(nfe=nfe, t_end=t_end).resolve("srfmp").reached(cfg.lambda_x)

    head = " | ".join("DTW " + setting_label({"nfe": n, "t_end": t, "t_reached": reached(n, t)})
                      for n in NFES for t in T_ENDS)
    ratios = " | ".join(f"ratio NFE {n} (T {reached(n, max(T_ENDS)):.2f} / "
                        f"{reached(n, min(T_ENDS)):.2f})" for n in NFES if n > 1)
    lines = [
        f"| seed | train (s) | {head} | {ratios} | within 10% |",
        "|---" * (3 + len(NFES) * len(T_ENDS) + len(NFES) - 1) + "|",
    ]
    print("\n".join(lines), flush=True)
    start = time.perf_counter()
    for seed in args.seeds:
        r = run_seed(cfg, seed)
        d = r["dtw"]
        ratio = [d[(n, 1.6)] / d[(n, 1.0)] for n in NFES if n > 1]
        row = (
            f"| {seed} | {r['seconds']:.0f} | "
            + " | ".join(f"{d[(n, t)]:.4f}" for n in NFES for t in T_ENDS)
            + " | "
            + " | ".join(f"{x:.3f}" for x in ratio)
            + f" | {'yes' if max(ratio) <= 1.10 else 'no'} |"
        )
        lines.append(row)
        print(row, flush=True)
    if args.out:
        cmd = "bash recipes/venv.sh python recipes/benchmarks/quickstart_seeds.py " + " ".join(
            sys.argv[1:]
        )
        Path(args.out).write_text(
            "# Quickstart: SRFMP's DTW at T = 1.6 vs T = 1.0 across training seeds\n\n"
            + f"Command ({time.perf_counter() - start:.0f} s on a {os.cpu_count()}-core CPU "
            + f"machine): `{cmd}`\n\n"
            + __doc__.split("\n\n", 2)[2].strip()
            + "\n\nConfig: `recipes/quickstart.yaml`"
            + (f" with {' '.join(overrides)}" if overrides else "")
            + f" (steps {cfg.steps}, batch {cfg.batch_size}, {cfg.threads} threads).\n\n"
            + "\n".join(lines)
            + "\n"
        )


if __name__ == "__main__":
    main()
