"""Train-step throughput and sampling latency of RFMP, SRFMP and DDIM, side by side.

    bash recipes/venv.sh python recipes/benchmarks/throughput.py [--presets small paper]
        [--task pusht_state] [--steps 3] [--out results/policy_core_benchmark.md]

Training: samples/s of one AdamW step (forward, backward, update) at batch 256, T_p = 16.
Sampling: median latency of one action chunk at batch 1 for each NFE (DDIM: NFE = DDIM steps).
Everything runs in one process on the same threads, so the ratios are comparable.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import sys
import time
from pathlib import Path

import torch
from configs import task_config
from tensordict import TensorDict

from rfmp_rl import keys
from rfmp_rl.modules import build_model
from rfmp_rl.objectives import make_loss

NFES = (1, 2, 3, 5, 10)


def fake_batch(model, batch: int) -> TensorDict:
    data = {keys.ACTION: model.chunk.unflatten(model.chunk.random_base(batch))}
    if model.cfg.obs_dim:
        data[keys.OBSERVATION] = torch.randn(batch, 2, model.cfg.obs_dim)
    for name, shape in model.cfg.cameras.items():
        data[name] = torch.randint(0, 255, (batch, 2, *shape), dtype=torch.uint8)
    return TensorDict(data, [batch])


def train_throughput(model, batch: int, steps: int) -> float:
    loss = make_loss(model)
    opt = torch.optim.AdamW(model.parameters(), lr=1e-4, weight_decay=1e-3, fused=True)
    td = fake_batch(model, batch)
    times = []
    for i in range(steps + 1):
        start = time.perf_counter()
        out = loss(td)
        value = sum(v for k, v in out.items() if k.startswith("loss_"))
        opt.zero_grad()
        value.backward()
        opt.step()
        if i:  # the first step pays for allocation
            times.append(time.perf_counter() - start)
    return batch / statistics.median(times)


@torch.no_grad()
def sampling_latency(model, nfe: int, repeats: int) -> float:
    model.eval()
    td = fake_batch(model, 1)
    obs = td.get(keys.OBSERVATION, None)
    images = {n: td[n] for n in model.cameras} or None
    times = []
    for i in range(repeats + 1):
        start = time.perf_counter()
        model.sample(model.encode(obs, images), nfe=nfe)
        if i:
            times.append(time.perf_counter() - start)
    model.train()
    return statistics.median(times) * 1e3


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--presets", nargs="+", default=["small", "paper"])
    parser.add_argument("--task", default="pusht_state")
    parser.add_argument("--batch", type=int, default=256)
    parser.add_argument("--steps", type=int, default=3, help="timed training steps per model")
    parser.add_argument("--repeats", type=int, default=10, help="timed samples per NFE")
    parser.add_argument("--out", default=None, help="also write the tables to this markdown file")
    args = parser.parse_args()
    torch.manual_seed(0)
    lines = [
        f"Task `{args.task}`, batch {args.batch} for training, batch 1 for sampling; "
        f"torch {torch.__version__}, {torch.get_num_threads()} threads, "
        f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores.",
        "",
        "| preset | algorithm | params | train samples/s | "
        + " | ".join(f"NFE {n} (ms)" for n in NFES)
        + " |",
        "|---|---|---|---|" + "---|" * len(NFES),
    ]
    print("\n".join(lines), flush=True)
    for preset in args.presets:
        for algorithm in ("rfmp", "srfmp", "ddim"):
            model = build_model(task_config(args.task, algorithm, preset))
            params = sum(p.numel() for p in model.parameters())
            rate = train_throughput(model, args.batch, args.steps)
            lat = [sampling_latency(model, n, args.repeats) for n in NFES]
            row = (
                f"| {preset} | {algorithm} | {params / 1e6:.1f}M | {rate:,.0f} | "
                + " | ".join(f"{v:.1f}" for v in lat)
                + " |"
            )
            lines.append(row)
            print(row, flush=True)
    if args.out:
        command = "bash recipes/venv.sh python recipes/benchmarks/throughput.py " + " ".join(
            sys.argv[1:]
        )
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.out).write_text(
            "# Policy core: training throughput and sampling latency\n\n"
            f"Regenerate with:\n\n```\n{command}\n```\n\n" + "\n".join(lines) + "\n"
        )


if __name__ == "__main__":
    main()
