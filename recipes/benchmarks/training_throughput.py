"""Training throughput on this machine's CPU: eager fp32, torch.compile and bf16 autocast side by
side, DDP with 1 and 2 processes, and the data pipeline's share of a step (Push-T state and
image, small UNet, SRFMP).

    OMP_NUM_THREADS=1 .venv/bin/python recipes/benchmarks/training_throughput.py \
        --out results/training_throughput.md
    # tiny (the smoke test): --tasks pusht_state --steps 2 --warmup 1 --batch 8 --down-dims 16 32

Every figure is one `rfmp_rl.training.Trainer.update` (forward under the model's autocast,
backward, fused AdamW, EMA) on batches drawn from the Push-T recipe's replay buffer
(``recipes/pusht/utils.py``; synthetic batches when the zarr is absent, and the output says so):

1. one process, ``--threads`` threads (default 1): eager fp32, compiled fp32 and eager bf16, each
   its own model from the same initialisation, warmed up first (``--warmup`` steps, excluded;
   compilation happens there and is reported on its own, from an empty inductor cache unless
   ``--warm-compile-cache``), then ``--steps`` timed steps interleaved: one step of each
   variant in turn, the order rotating every round, so machine noise hits every variant alike;
2. ``torchrun --standalone --nproc_per_node=N`` of this script (``--ddp-worker``), N = 1 and 2,
   one thread per process, per-rank batch = global batch / N; rank 0 writes its times to a JSON
   file this process reads; ``--ddp-repeats`` launches per N, alternating N = 1 and 2, pooled;
3. the data share: ``rb.sample()`` + moving to the device over the whole step (sample + update),
   per variant (target <= 10%).

samples/s = samples per step / median update time (global samples under DDP: rank 0's update
includes the gradient all-reduce, which waits for the slower rank). Every figure carries its
ratio to eager fp32 measured in the same run.
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib.util
import json
import math
import os
import shlex
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import torch
from configs import task_config
from tensordict import TensorDict

from rfmp_rl import keys
from rfmp_rl.modules import build_model
from rfmp_rl.training import (
    LoggerConfig,
    OptimConfig,
    TrainConfig,
    Trainer,
    rank_seed,
    setup_runtime,
)

ROOT = Path(__file__).resolve().parents[2]
TASKS = ("pusht_state", "pusht_image")
TITLES = {"pusht_state": "Push-T state", "pusht_image": "Push-T image, 96x96 camera"}
#: Push-T's actions and low-dim observations are pixel coordinates of the 512 x 512 board.
PUSHT_RANGE = (0.0, 512.0)
#: the task config names the Push-T camera ``image``; the recipe's batches hold it as ``pixels``
CAMERA_KEYS = {"pusht_state": None, "pusht_image": {"image": keys.PIXELS}}
#: (label, precision, compile) of the single-process variants; the first is the baseline
VARIANTS = (("eager fp32", "fp32", False), ("compiled fp32", "fp32", True),
            ("bf16 autocast (eager)", "bf16", False))
LR = 1.0e-4
DATA_TARGET = 0.10


# ----- data ------------------------------------------------------------------------------------
def pusht_utils():
    """recipes/pusht/utils.py, imported under its own name (it is `utils` to the recipe)."""
    name = "pusht_recipe_utils"
    if name not in sys.modules:
        spec = importlib.util.spec_from_file_location(name, ROOT / "recipes/pusht/utils.py")
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module
        spec.loader.exec_module(module)
    return sys.modules[name]


def recipe_config(obs: str, overrides: list[str] = ()):
    """The Push-T recipe's hydra config (recipes/pusht/config.yaml) with ``overrides``."""
    from hydra import compose, initialize_config_dir

    with initialize_config_dir(config_dir=str(ROOT / "recipes" / "pusht"), version_base="1.3"):
        return compose("config", overrides=[f"obs={obs}", *overrides])


def default_zarr() -> Path:
    """Where the Push-T recipe reads its demonstrations (``data.path`` of its config; relative
    paths from the repository root, as the recipe resolves them)."""
    path = Path(recipe_config("state").data.path)
    return path if path.is_absolute() else (ROOT / path).resolve()


class SyntheticBatches:
    """``sample()``: random batches shaped like the Push-T replay buffer's (used when the zarr is
    absent): pixel-range actions and observations, random ``uint8`` images.

    Example:
        >>> SyntheticBatches("pusht_image", batch=4, seed=0).sample()["pixels"].shape
        torch.Size([4, 2, 3, 96, 96])
    """

    def __init__(self, task: str, batch: int, seed: int, horizon: int = 16) -> None:
        cfg = task_config(task, "srfmp", "small")
        self.obs_dim, self.cameras = cfg.obs_dim, dict(cfg.cameras)
        self.batch, self.horizon = batch, horizon
        self.generator = torch.Generator().manual_seed(seed)

    def sample(self) -> TensorDict:
        b, g = self.batch, self.generator
        lo, hi = PUSHT_RANGE
        data = {keys.ACTION: lo + (hi - lo) * torch.rand(b, self.horizon, 2, generator=g),
                keys.ACTION_IS_PAD: torch.zeros(b, self.horizon, dtype=torch.bool),
                keys.OBSERVATION: lo + (hi - lo) * torch.rand(b, 2, self.obs_dim, generator=g)}
        for shape in self.cameras.values():
            data[keys.PIXELS] = torch.randint(0, 256, (b, 2, *shape), generator=g,
                                              dtype=torch.uint8)
        return TensorDict(data, [b])


@dataclass
class TaskData:
    """Training and validation batches of one task and the statistics of the normalisers."""

    task: str
    train: object  # sample() -> TensorDict
    val: object
    action_stats: tuple
    obs_stats: tuple
    source: str  # what the batches are, for the reports
    real: bool

    @property
    def camera_keys(self) -> dict | None:
        return CAMERA_KEYS[self.task]


def load_task_data(task: str, batch: int, zarr: str | Path | None = None, seed: int = 0,
                   synthetic: bool = False) -> TaskData:
    """The Push-T recipe's replay buffers (train and validation, ``batch`` samples per draw,
    sampler seeded with ``seed``) when the zarr exists, else `SyntheticBatches`."""
    if task not in TASKS:
        raise ValueError(f"task must be one of {TASKS}, got {task!r}")
    zarr = Path(zarr) if zarr else default_zarr()
    if synthetic or not zarr.exists():
        why = "--synthetic" if synthetic else f"no Push-T zarr at {zarr}"
        lo, hi = PUSHT_RANGE
        cfg = task_config(task, "srfmp", "small")
        return TaskData(task, SyntheticBatches(task, batch, seed),
                        SyntheticBatches(task, batch, seed + 1),
                        (torch.full((2,), lo), torch.full((2,), hi)),
                        (torch.full((cfg.obs_dim,), lo), torch.full((cfg.obs_dim,), hi)),
                        f"synthetic batches ({why})", False)
    utils = pusht_utils()
    cfg = recipe_config(task.removeprefix("pusht_"),
                        [f"train.batch_size={batch}", f"data.path={zarr}"])
    train_store, val_store = utils.make_stores(cfg)
    return TaskData(task, utils.make_replay_buffer(train_store, cfg, seed),
                    utils.make_replay_buffer(val_store, cfg, seed + 1),
                    train_store.stats(keys.ACTION), train_store.stats(keys.OBSERVATION),
                    f"Push-T replay buffer ({zarr}, {len(train_store)} steps in "
                    f"{train_store.num_episodes} episodes)", True)


def make_policy(task: str, data: TaskData, preset: str = "small", algorithm: str = "srfmp",
                down_dims: list[int] | None = None, seed: int = 0):
    """`configs.task_config` (optionally with ``down_dims``), normalisers set from ``data``."""
    cfg = task_config(task, algorithm, preset)
    if down_dims:
        cfg = dataclasses.replace(cfg, down_dims=list(down_dims))
    torch.manual_seed(seed)
    model = build_model(cfg)
    model.action_normalizer.set_stats(*data.action_stats)
    model.obs_normalizer.set_stats(*data.obs_stats)
    return model


def make_trainer(model, data: TaskData, runtime, run_dir: Path, batch: int) -> Trainer:
    return Trainer(model, data.train, data.val, runtime=runtime, run_dir=run_dir,
                   recipe="training_throughput", optim=OptimConfig(lr=LR, warmup_steps=1),
                   train=TrainConfig(batch_size=batch), logger=LoggerConfig(backend="none"),
                   camera_keys=data.camera_keys, progress=False)


# ----- timing ----------------------------------------------------------------------------------
@dataclass
class Timing:
    """Per-step times of one setting (seconds).

    Example:
        >>> t = Timing("eager fp32", batch=256, sample=[0.01, 0.01], update=[0.09, 0.11])
        >>> round(t.samples_per_s), f"{t.data_share:.0%}"
        (2560, '9%')
    """

    label: str
    batch: int  # samples per step, all processes together
    processes: int = 1
    threads: int = 1
    warmup: list[float] = field(default_factory=list)  # sample + update of the warm-up steps
    sample: list[float] = field(default_factory=list)  # rb.sample() + to device
    update: list[float] = field(default_factory=list)  # Trainer.update
    note: str = ""

    @property
    def step_ms(self) -> float:
        return statistics.median(self.update) * 1e3

    @property
    def samples_per_s(self) -> float:
        return self.batch / statistics.median(self.update)

    @property
    def data_share(self) -> float:
        data = statistics.median(self.sample)
        return data / (data + statistics.median(self.update))


def timed_step(trainer: Trainer, data) -> tuple[float, float, float]:
    """``(sample + to device seconds, update seconds, loss)`` of one training step."""
    start = time.perf_counter()
    batch = trainer.runtime.to_device(data.sample())
    sampled = time.perf_counter()
    loss = float(trainer.update(batch, LR))  # float(): the step has finished
    return sampled - start, time.perf_counter() - sampled, loss


def measure_variants(data: TaskData, batch: int, args, run_dir: Path) -> list[Timing]:
    """Eager fp32, compiled fp32 and bf16 in this process: warm-up each, then ``args.steps``
    rounds of one step per variant (the order rotates every round)."""
    chosen = [v for v in VARIANTS if not (v[2] and args.no_compile)]
    trainers, timings = [], []
    for label, precision, compiled in chosen:
        runtime = setup_runtime("cpu", precision, compiled, distributed=False)
        model = make_policy(data.task, data, down_dims=args.down_dims, algorithm=args.algo)
        trainers.append(make_trainer(model, data, runtime, run_dir, batch))
        timing = Timing(label, batch, 1, torch.get_num_threads())
        for _ in range(args.warmup):
            sample_s, update_s, loss = timed_step(trainers[-1], data.train)
            timing.warmup.append(sample_s + update_s)
            if not math.isfinite(loss):
                raise RuntimeError(f"{data.task} {label}: non-finite loss {loss} in warm-up")
        timings.append(timing)
        print(f"  {label}: warm-up {sum(timing.warmup):.1f} s ({args.warmup} step(s))", flush=True)
    for step in range(args.steps):
        shift = step % len(trainers)
        for i in [*range(shift, len(trainers)), *range(shift)]:
            sample_s, update_s, loss = timed_step(trainers[i], data.train)
            if not math.isfinite(loss):
                raise RuntimeError(f"{data.task} {timings[i].label}: non-finite loss {loss}")
            timings[i].sample.append(sample_s)
            timings[i].update.append(update_s)
    return timings


# ----- DDP -------------------------------------------------------------------------------------
def worker_args(args, task: str, batch: int, out: Path) -> list[str]:
    """The command-line flags of a `ddp_worker` for ``task`` at global batch ``batch``."""
    flags = ["--ddp-worker", "--tasks", task, "--batch", str(batch), "--steps", str(args.steps),
             "--warmup", str(args.warmup), "--algo", args.algo, "--json", str(out)]
    if args.down_dims:
        flags += ["--down-dims", *map(str, args.down_dims)]
    if args.data:
        flags += ["--data", str(args.data)]
    if args.synthetic:
        flags.append("--synthetic")
    return flags


def run_ddp(args, task: str, batch: int, nproc: int, workdir: Path) -> Timing:
    """``torchrun --standalone --nproc_per_node=nproc`` of this script's worker mode."""
    out = workdir / f"ddp_{task}_{nproc}.json"
    torchrun = Path(sys.executable).parent / "torchrun"
    command = [str(torchrun), "--standalone", f"--nproc_per_node={nproc}", str(Path(__file__)),
               *worker_args(args, task, batch, out)]
    env = dict(os.environ, OMP_NUM_THREADS="1")
    proc = subprocess.run(command, capture_output=True, text=True, env=env, cwd=ROOT,
                          timeout=args.ddp_timeout)
    if proc.returncode != 0 or not out.exists():
        raise RuntimeError(f"{shlex.join(command)} exited with {proc.returncode}:\n"
                           f"{proc.stdout[-2000:]}\n{proc.stderr[-3000:]}")
    result = json.loads(out.read_text())
    label = f"DDP {nproc} process{'es' if nproc > 1 else ''} (eager fp32)"
    note = f"{result['per_rank_batch']} per rank"
    if nproc == 1:
        note += "; world size 1: no DDP wrapper"
    return Timing(label, result["global_batch"], nproc, result["threads"], result["warmup"],
                  result["sample"], result["update"], note)


def pooled(runs: list[Timing]) -> Timing:
    """One row from repeated launches of the same setting (their steps pooled)."""
    first = runs[0]
    note = first.note + (f"; {len(runs)} launches pooled" if len(runs) > 1 else "")
    return Timing(first.label, first.batch, first.processes, first.threads, first.warmup,
                  [t for r in runs for t in r.sample],
                  [t for r in runs for t in r.update], note)


def ddp_worker(args) -> int:
    """One rank: the eager fp32 step at per-rank batch = global / world size; rank 0 writes its
    times to ``--json``."""
    torch.set_num_threads(1)
    runtime = setup_runtime("cpu", "fp32", False)
    task = args.tasks[0]
    if args.batch % runtime.world_size:
        raise SystemExit(f"--batch {args.batch} is not divisible by {runtime.world_size} ranks")
    per_rank = args.batch // runtime.world_size
    data = load_task_data(task, per_rank, args.data, rank_seed(0, runtime.rank), args.synthetic)
    model = make_policy(task, data, down_dims=args.down_dims, algorithm=args.algo)
    with tempfile.TemporaryDirectory() as tmp:
        trainer = make_trainer(model, data, runtime, Path(tmp), per_rank)
        warmup = [sum(timed_step(trainer, data.train)[:2]) for _ in range(args.warmup)]
        runtime.barrier()
        sample, update = [], []
        for _ in range(args.steps):
            sample_s, update_s, loss = timed_step(trainer, data.train)
            if not math.isfinite(loss):
                raise RuntimeError(f"rank {runtime.rank}: non-finite loss {loss}")
            sample.append(sample_s)
            update.append(update_s)
        runtime.barrier()
    if runtime.is_main:
        Path(args.json).write_text(json.dumps({
            "world_size": runtime.world_size, "global_batch": args.batch,
            "per_rank_batch": per_rank, "threads": torch.get_num_threads(), "warmup": warmup,
            "sample": sample, "update": update, "data": data.source}))
    runtime.shutdown()
    return 0


# ----- report ----------------------------------------------------------------------------------
def cpu_name() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    import platform

    return platform.processor() or platform.machine()


def bf16_flags() -> str:
    """The CPU's native bf16 instructions as /proc/cpuinfo lists them."""
    try:
        flags = set(Path("/proc/cpuinfo").read_text().split())
    except OSError:
        return "unknown (no /proc/cpuinfo)"
    found = [f for f in ("avx512_bf16", "amx_bf16", "amx_tile") if f in flags]
    return ", ".join(found) if found else "none (no avx512_bf16 / amx_bf16)"


def cache_note(warm_cache: bool) -> str:
    """What the compile time includes (a first compile, or whatever the on-disk cache held)."""
    if warm_cache:
        return (" (--warm-compile-cache: torch's on-disk inductor cache was used, so a rerun of "
                "the same model compiles faster than a first run)")
    return " (a first compile: this run used an empty inductor cache)"


def section(task: str, source: str, timings: list[Timing], params: int, warm_cache: bool
            ) -> list[str]:
    """The markdown table and the summary lines of one task."""
    base = timings[0].samples_per_s
    lines = [f"## {TITLES[task]} (batch {timings[0].batch})", "",
             f"Data: {source}. Model: {params / 1e6:.2f}M parameters.", "",
             "| setting | processes x threads | step ms (median) | samples/s | vs eager fp32 | "
             "data share | warm-up s (excluded) | note |",
             "|---|---|---|---|---|---|---|---|"]
    for t in timings:
        share = t.data_share
        flag = "" if share <= DATA_TARGET else " (MISS)"
        lines.append(f"| {t.label} | {t.processes} x {t.threads} | {t.step_ms:.1f} | "
                     f"{t.samples_per_s:,.1f} | {t.samples_per_s / base:.2f}x | "
                     f"{share:.1%}{flag} | {sum(t.warmup):.1f} | {t.note} |")
    lines.append("")
    by_label = {t.label.split(" (")[0]: t for t in timings}
    for t in timings[1:]:
        lines.append(f"- {t.label}: {t.samples_per_s / base:.2f}x eager fp32")
    compiled = by_label.get("compiled fp32")
    if compiled is not None:
        lines.append(f"- torch.compile: first step {compiled.warmup[0]:.1f} s, "
                     f"{len(compiled.warmup)} warm-up step(s) {sum(compiled.warmup):.1f} s "
                     f"(eager fp32: {sum(timings[0].warmup):.1f} s); excluded from samples/s"
                     f"{cache_note(warm_cache)}")
    one, two = by_label.get("DDP 1 process"), by_label.get("DDP 2 processes")
    if one is not None and two is not None:
        lines.append(f"- DDP scaling at global batch {two.batch}: 2 processes / 1 process = "
                     f"{two.samples_per_s / one.samples_per_s:.2f}x (ideal 2.00x)")
    eager = timings[0]
    verdict = "met" if eager.data_share <= DATA_TARGET else "MISSED"
    lines.append(f"- Data pipeline (eager fp32): rb.sample() + to device "
                 f"{statistics.median(eager.sample) * 1e3:.1f} ms of a "
                 f"{(statistics.median(eager.sample) + statistics.median(eager.update)) * 1e3:.1f}"
                 f" ms step = {eager.data_share:.1%}; target <= {DATA_TARGET:.0%}: {verdict}")
    return lines


def header(args, command: str, sources: list[str], load: float) -> list[str]:
    threads = os.environ.get("OMP_NUM_THREADS", "unset")
    unet = f"UNet down dims {args.down_dims}" if args.down_dims else "small UNet"
    gpu = ": the machine has no GPU" if not torch.cuda.is_available() else " (the GPU is not used)"
    return [
        f"# Training throughput on the CPU (Push-T, {args.algo.upper()}, {unet})", "",
        "Regenerate with:", "", "```", command, "```", "",
        f"Machine: {cpu_name()}, {os.cpu_count()} cores, torch {torch.__version__}, "
        f"{torch.get_num_threads()} torch thread(s) in the single-process rows "
        f"(OMP_NUM_THREADS={threads}), 1 thread per process under torchrun. Native bf16 "
        f"instructions: {bf16_flags()}. 1-minute load average before the run: {load:.2f} "
        "(each busy core adds about 1; it decays over minutes).", "",
        f"**These are CPU figures{gpu}.** They compare settings on this CPU only and say "
        "nothing about GPU speed-ups (`recipes/benchmarks/gpu_check.py` measures "
        "those on a CUDA machine). bf16 autocast on a CPU without native bf16 support may be "
        "slower than fp32; what was measured is reported as measured, and a target missed is "
        "marked MISS.", "",
        f"Method: `Trainer.update` (forward, backward, fused AdamW, EMA) at lr {LR:g}; "
        f"{args.warmup} warm-up step(s) per setting (excluded; torch.compile compiles there), then "
        f"{args.steps} timed steps. The single-process settings are interleaved (one step of "
        "each in turn, order rotating). samples/s = samples per step / median update time; "
        "under DDP the global batch is kept and split over the processes (rank 0's update "
        f"includes the all-reduce); each process count is launched {args.ddp_repeats} time(s), "
        "alternating 1 and 2 processes, and the timed steps of its launches are pooled "
        "(warm-up column: the first launch). Data share = median rb.sample() + to-device "
        f"time / (that + median update time), target <= {DATA_TARGET:.0%}. Batches: "
        + "; ".join(sources) + ".", "",
    ]


def _relative(path: Path) -> str:
    """``path`` relative to the working directory when under it (the command as typed)."""
    path = path.absolute()
    return str(path.relative_to(Path.cwd())) if path.is_relative_to(Path.cwd()) else str(path)


def regenerate_command() -> str:
    """This run's command line (with its OMP_NUM_THREADS)."""
    env = os.environ.get("OMP_NUM_THREADS")
    words = [_relative(Path(sys.executable)), _relative(Path(sys.argv[0])), *sys.argv[1:]]
    return (f"OMP_NUM_THREADS={env} " if env else "") + shlex.join(words)


def parse_args(argv: list[str] | None = None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tasks", nargs="+", default=list(TASKS), choices=TASKS)
    parser.add_argument("--batch", type=int, default=256, help="Push-T state batch (global)")
    parser.add_argument("--image-batch", type=int, default=32, help="Push-T image batch (global)")
    parser.add_argument("--steps", type=int, default=10, help="timed steps per setting")
    parser.add_argument("--warmup", type=int, default=3, help="warm-up steps per setting")
    parser.add_argument("--threads", type=int, default=1, help="torch threads, single process")
    parser.add_argument("--algo", default="srfmp", choices=("rfmp", "srfmp", "ddim"))
    parser.add_argument("--down-dims", type=int, nargs="+", default=None,
                        help="UNet widths instead of the small preset's (tiny smoke runs)")
    parser.add_argument("--no-compile", action="store_true", help="skip the torch.compile row")
    parser.add_argument("--no-ddp", action="store_true", help="skip the torchrun rows")
    parser.add_argument("--ddp-repeats", type=int, default=2,
                        help="torchrun launches per process count (alternating 1, 2, 1, 2)")
    parser.add_argument("--warm-compile-cache", action="store_true",
                        help="use torch's on-disk inductor cache (default: an empty one, so the "
                             "compile time is a first compile's)")
    parser.add_argument("--data", default=None, help="Push-T zarr (default: the recipe's)")
    parser.add_argument("--synthetic", action="store_true", help="synthetic batches, no zarr")
    parser.add_argument("--ddp-timeout", type=float, default=900, help="seconds per torchrun")
    parser.add_argument("--out", default=None, help="also write the markdown report to this file")
    parser.add_argument("--ddp-worker", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--json", default=None, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.steps < 1 or args.warmup < 1 or args.ddp_repeats < 1:
        parser.error("--steps, --warmup and --ddp-repeats must be >= 1")
    return args


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    if args.ddp_worker:
        return ddp_worker(args)
    torch.set_num_threads(args.threads)
    command = regenerate_command()
    load = os.getloadavg()[0]  # before this run's own processes
    body, sources, failures = [], [], []
    with tempfile.TemporaryDirectory() as tmp:
        if not args.warm_compile_cache:  # compile from scratch: the cost of a first run
            os.environ["TORCHINDUCTOR_CACHE_DIR"] = str(Path(tmp) / "inductor_cache")
        for task in args.tasks:
            batch = args.batch if task == "pusht_state" else args.image_batch
            print(f"{task}: batch {batch}", flush=True)
            data = load_task_data(task, batch, args.data, 0, args.synthetic)
            sources.append(f"{task}: {data.source}")
            print(f"  data: {data.source}", flush=True)
            timings = measure_variants(data, batch, args, Path(tmp))
            params = sum(p.numel() for p in make_policy(
                task, data, down_dims=args.down_dims, algorithm=args.algo).parameters())
            del data
            ddp: dict[int, list[Timing]] = {1: [], 2: []}
            for _ in range(0 if args.no_ddp else args.ddp_repeats):
                for nproc in ddp:  # alternating, so machine noise hits both alike
                    try:
                        ddp[nproc].append(run_ddp(args, task, batch, nproc, Path(tmp)))
                    except (RuntimeError, subprocess.TimeoutExpired) as err:
                        failures.append(f"{task} DDP {nproc}: {err}")
                        print(f"  FAILED: DDP {nproc}: {err}", flush=True)
            timings += [pooled(runs) for runs in ddp.values() if runs]
            body += section(task, sources[-1].split(": ", 1)[1], timings, params,
                            args.warm_compile_cache) + [""]
    report = "\n".join(header(args, command, sources, load) + body)
    if failures:
        report += "\n## Failures\n\n" + "\n".join(f"- {f}" for f in failures) + "\n"
    print(report)
    if args.out:
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.out).write_text(report)
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
