"""Training time per epoch of RFMP, SRFMP, DDIM (Diffusion Policy) and CP (Consistency Policy,
its teacher included) on Push-T state, measured side by side in one run.

    OMP_NUM_THREADS=1 .venv/bin/python recipes/benchmarks/epoch_time.py --out results/epoch_time.md
    # the defaults: 4 x (3 + 5 x 10) steps of 0.5-0.9 s on one CPU thread, about 3 minutes
    # tiny (the smoke test): --steps 2 --rounds 1 --warmup 1 --batch-size 8 --max-episodes 3
    #                        --down-dims 16 32

Every algorithm is built as the Push-T recipe builds it (``recipes/pusht/config.yaml`` defaults:
small UNet, T_p 16, T_o 2, batch 256, AdamW at the recipe's lr and weight decay, EMA 0.999):
``make_model`` with its normalisers fitted to the training store and the loss of
``make_loss(model, loss_config(cfg))``. CP's student is ``ConsistencyModel.from_teacher`` of a
DDIM model of the same config and its loss ``ConsistencyDistillationLoss(student,
teacher=<that DDIM model>)`` (frozen teacher, one teacher DDIM step per sample).

One timed step = loss forward + backward + fused AdamW step + EMA update on a batch from the
recipe's replay buffer (``recipes/pusht/utils.py``; drawing the batch and moving it to the device
are timed apart, and are the same for every algorithm). After ``--warmup`` untimed steps each,
the algorithms take turns: ``--rounds`` rounds of ``--steps`` consecutive steps per algorithm,
the order rotating every round, so machine noise falls on all alike. On CUDA the device is
synchronised before every clock reading.

    steps per epoch = ceil(training windows / global batch), one window per stored step (every
    step of every training episode is a reference step of the sampler);
    seconds per epoch = steps per epoch x median seconds per step.

Ratios are to DDIM measured in the same run. CP's step includes the frozen teacher's forward
pass; "CP including its teacher" adds one DDIM epoch to one CP epoch: the per-epoch cost of a
Consistency Policy whose teacher trained as many epochs as the student (a CP run's total is
E_teacher x DDIM epoch + E_student x CP epoch).
"""

from __future__ import annotations

import argparse
import math
import os
import statistics
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import torch
from training_throughput import (
    cpu_name,
    default_zarr,
    pusht_utils,
    recipe_config,
    regenerate_command,
)

from recipes.common import loss_config
from rfmp_rl.modules import ConsistencyModel
from rfmp_rl.modules.ema import EMA
from rfmp_rl.objectives import ConsistencyDistillationLoss, make_loss

ALGOS = ("rfmp", "srfmp", "ddim", "cp")
TITLES = {"rfmp": "RFMP", "srfmp": "SRFMP", "ddim": "DDIM (Diffusion Policy)",
          "cp": "CP (Consistency Policy, step includes the frozen teacher's forward)"}
BASE = "ddim"


@dataclass
class Algo:
    """One algorithm's model, loss, optimiser and EMA, and its timed steps (seconds)."""

    name: str
    model: torch.nn.Module
    loss_fn: torch.nn.Module
    optimizer: torch.optim.Optimizer
    ema: EMA
    params: int
    warmup: list[float] = field(default_factory=list)
    steps: list[float] = field(default_factory=list)
    sample: list[float] = field(default_factory=list)
    rounds: list[float] = field(default_factory=list)  # median step of each round

    @property
    def step_s(self) -> float:
        return statistics.median(self.steps)


def recipe_cfg(algo: str, args):
    """The Push-T state recipe config of ``algo`` with this run's overrides."""
    overrides = [f"algo={algo}", f"model.unet_preset={args.preset}",
                 f"train.batch_size={args.batch_size}", f"data.path={args.data}",
                 f"seed={args.seed}"]
    if args.down_dims:
        overrides.append("model.down_dims=[" + ",".join(map(str, args.down_dims)) + "]")
    if args.max_episodes:
        overrides.append(f"data.max_episodes={args.max_episodes}")
    return recipe_config("state", overrides)


def build(algo: str, args, store, device: torch.device) -> Algo:
    """The recipe's model and loss of ``algo`` on ``device``, AdamW and EMA as the trainer's."""
    utils = pusht_utils()
    cfg = recipe_cfg("ddim" if algo == "cp" else algo, args)
    torch.manual_seed(args.seed)
    model = utils.make_model(cfg, store).to(device)
    if algo == "cp":  # the student starts from the teacher's weights, as Consistency Policy does
        teacher = model
        model = ConsistencyModel.from_teacher(teacher)
        loss_fn = ConsistencyDistillationLoss(model, loss_config(cfg), teacher=teacher)
    else:
        loss_fn = make_loss(model, loss_config(cfg))
    model.train()
    loss_fn.train()
    optimizer = torch.optim.AdamW(model.parameters(), lr=float(cfg.optim.lr),
                                  weight_decay=float(cfg.optim.weight_decay),
                                  fused=device.type in ("cpu", "cuda"))
    ema = EMA(model, decay=float(cfg.optim.ema_decay))
    return Algo(algo, model, loss_fn, optimizer, ema, sum(p.numel() for p in model.parameters()))


def sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def timed_step(algo: Algo, rb, device: torch.device) -> tuple[float, float]:
    """``(sample + to device seconds, optimiser step seconds)`` of one training step."""
    sync(device)
    start = time.perf_counter()
    batch = rb.sample().to(device)
    sync(device)
    sampled = time.perf_counter()
    out = algo.loss_fn(batch)
    loss = sum(v for k, v in out.items() if k.startswith("loss_"))
    algo.optimizer.zero_grad(set_to_none=True)
    loss.backward()
    algo.optimizer.step()
    algo.ema.update(algo.model)
    sync(device)
    done = time.perf_counter()
    value = loss.detach().item()
    if not math.isfinite(value):
        raise RuntimeError(f"{algo.name}: non-finite loss {value}")
    return sampled - start, done - sampled


def measure(algos: list[Algo], rb, args, device: torch.device) -> None:
    """Warm-up, then ``args.rounds`` rounds of ``args.steps`` steps per algorithm in turn."""
    for algo in algos:
        for _ in range(args.warmup):
            algo.warmup.append(sum(timed_step(algo, rb, device)))
        print(f"  {algo.name}: warm-up {sum(algo.warmup):.1f} s ({args.warmup} step(s))",
              flush=True)
    for r in range(args.rounds):
        shift = r % len(algos)
        for algo in algos[shift:] + algos[:shift]:
            times = []
            for _ in range(args.steps):
                sample_s, step_s = timed_step(algo, rb, device)
                algo.sample.append(sample_s)
                times.append(step_s)
            algo.steps += times
            algo.rounds.append(statistics.median(times))
        print(f"  round {r + 1}/{args.rounds}: " + ", ".join(
            f"{a.name} {a.rounds[-1]:.3f} s/step" for a in algos), flush=True)


# ----- report ----------------------------------------------------------------------------------
def report(algos: list[Algo], args, command: str, source: str, windows: int, load: float,
           device: torch.device) -> str:
    by_name = {a.name: a for a in algos}
    steps_per_epoch = math.ceil(windows / args.batch_size)
    base = by_name.get(BASE, algos[0])
    base_epoch = steps_per_epoch * base.step_s
    unet = f"UNet down dims {args.down_dims}" if args.down_dims else f"{args.preset} UNet"
    where = (f"{cpu_name()}, {os.cpu_count()} cores, {torch.get_num_threads()} torch thread(s) "
             f"(OMP_NUM_THREADS={os.environ.get('OMP_NUM_THREADS', 'unset')})")
    if device.type == "cuda":
        where = f"{torch.cuda.get_device_name(device)} (CUDA); host {where}"
    lines = [
        f"# Training time per epoch: RFMP, SRFMP, DDIM and CP (Push-T state, {unet})", "",
        "Regenerate with:", "", "```", command, "```", "",
        f"Device: {where}; torch {torch.__version__}; fp32. 1-minute load average before the "
        f"run: {load:.2f}.", "",
        f"Data: {source}: {windows} training windows (one per stored step); global batch "
        f"{args.batch_size}, so {steps_per_epoch} steps per epoch (ceil(windows / batch)).", "",
        "Method: one step = loss forward + backward + fused AdamW step + EMA update, built as "
        "the Push-T recipe builds each algorithm (T_p 16, T_o 2). "
        f"{args.warmup} warm-up step(s) per algorithm (excluded), then {args.rounds} round(s) "
        f"of {args.steps} consecutive steps per algorithm, taking turns with the order rotating "
        "every round. s/step is the median over all timed steps; the spread column gives the "
        "lowest and highest round median. Drawing a batch and moving it to the device is "
        "timed apart (the same for every algorithm) and not in s/step. "
        f"s/epoch = steps per epoch x s/step. Ratios are to {base.name.upper()} in this run.", "",
        "| algorithm | parameters | s/step (median) | round medians (min-max) | steps/epoch | "
        f"s/epoch | vs {base.name.upper()} |",
        "|---|---|---|---|---|---|---|",
    ]
    for a in algos:
        epoch = steps_per_epoch * a.step_s
        lines.append(f"| {a.name} | {a.params / 1e6:.2f}M | {a.step_s:.4f} | "
                     f"{min(a.rounds):.4f}-{max(a.rounds):.4f} | {steps_per_epoch} | "
                     f"{epoch:.2f} | {epoch / base_epoch:.2f}x |")
    cp, ddim = by_name.get("cp"), by_name.get("ddim")
    if cp is not None and ddim is not None:
        total = steps_per_epoch * (cp.step_s + ddim.step_s)
        lines.append(f"| cp+teacher | {cp.params / 1e6:.2f}M + {ddim.params / 1e6:.2f}M | "
                     f"{cp.step_s + ddim.step_s:.4f} | - | {steps_per_epoch} | {total:.2f} | "
                     f"{total / base_epoch:.2f}x |")
    lines += ["", "Rows:", ""]
    lines += [f"- {a.name}: {TITLES[a.name]}." for a in algos]
    if cp is not None and ddim is not None:
        lines.append(
            "- cp+teacher: CP including its teacher, as the Consistency Policy paper counts it: "
            "one CP epoch plus one DDIM epoch (the teacher's training). A CP run's total "
            "training time is E_teacher x (DDIM s/epoch) + E_student x (CP s/epoch); with "
            "as many teacher as student epochs it is E x (cp+teacher s/epoch). CP's own row "
            "already includes the frozen teacher's forward pass in every step.")
    sample = statistics.median(t for a in algos for t in a.sample)
    lines += ["", f"Batch draw + to device (not in s/step): median {sample * 1e3:.1f} ms per "
              f"step, {steps_per_epoch * sample:.1f} s per epoch.", ""]
    return "\n".join(lines)


def parse_args(argv: list[str] | None = None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--algos", nargs="+", default=list(ALGOS), choices=ALGOS,
                        help="algorithms to time (cp adds ddim: its teacher's epoch)")
    parser.add_argument("--steps", type=int, default=10, help="timed steps per algorithm per round")
    parser.add_argument("--rounds", type=int, default=5, help="rounds of turns")
    parser.add_argument("--warmup", type=int, default=3, help="untimed steps per algorithm first")
    parser.add_argument("--batch-size", type=int, default=256, help="global batch (recipe: 256)")
    parser.add_argument("--threads", type=int, default=1, help="torch threads")
    parser.add_argument("--device", default="cpu", help="cpu | cuda | cuda:N")
    parser.add_argument("--preset", default="small", choices=("small", "paper"),
                        help="UNet preset (recipe default: small)")
    parser.add_argument("--down-dims", type=int, nargs="+", default=None,
                        help="UNet widths instead of the preset's (tiny smoke runs)")
    parser.add_argument("--max-episodes", type=int, default=None,
                        help="use only the first N training episodes (data.max_episodes)")
    parser.add_argument("--data", default=None, help="Push-T zarr (default: the recipe's)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", default=None, help="also write the markdown report to this file")
    args = parser.parse_args(argv)
    if min(args.steps, args.rounds, args.warmup, args.batch_size, args.threads) < 1:
        parser.error("--steps, --rounds, --warmup, --batch-size and --threads must be >= 1")
    if args.max_episodes is not None and args.max_episodes < 1:
        parser.error("--max-episodes must be >= 1")
    if args.device.startswith("cuda") and not torch.cuda.is_available():
        parser.error(f"--device {args.device}: no CUDA device is visible")
    args.algos = list(dict.fromkeys(args.algos))
    if "cp" in args.algos and "ddim" not in args.algos:
        args.algos.insert(args.algos.index("cp"), "ddim")
    return args


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    torch.set_num_threads(args.threads)
    command = regenerate_command()
    load = os.getloadavg()[0]  # before this run's own work
    args.data = str(Path(args.data).resolve()) if args.data else str(default_zarr())
    if not Path(args.data).exists():
        raise SystemExit(f"epoch_time.py: no Push-T zarr at {args.data} (give --data)")
    device = torch.device(args.device)
    utils = pusht_utils()
    cfg = recipe_cfg("ddim", args)
    store, _ = utils.make_stores(cfg)
    rb = utils.make_replay_buffer(store, cfg, args.seed)
    source = (f"Push-T replay buffer ({args.data}, {len(store)} steps in "
              f"{store.num_episodes} training episodes)")
    print(f"data: {source}", flush=True)
    algos = [build(name, args, store, device) for name in args.algos]
    measure(algos, rb, args, device)
    text = report(algos, args, command, source, len(store), load, device)
    print(text)
    if args.out:
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.out).write_text(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
