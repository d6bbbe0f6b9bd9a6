"""Check training on a CUDA machine: Push-T state and image with the paper's UNet in fp32, bf16
and compiled fp32 on one GPU, the Push-T recipe under DDP over every visible GPU, and ONNX
parity of every trained policy.

    python recipes/benchmarks/gpu_check.py [--steps 300] [--out results/gpu_check.md]

Without CUDA it prints one line and exits 0 (nothing can be checked). With CUDA:

1. one GPU, per task (state: batch 256, image: batch 64) and setting (fp32, bf16, compiled fp32):
   ``Trainer.fit`` for ``--steps`` steps in a temporary run folder (logger none, validation
   only at the end); samples/s over the steps after ``--warmup`` (compilation and autotuning
   happen there), the peak of ``torch.cuda.max_memory_allocated`` (reset per setting), the
   final training loss (the engine's running mean) and validation loss;
2. ``torchrun --standalone --nproc_per_node=<GPUs> recipes/pusht/train.py`` with
   ``device=cuda precision=bf16 preset=paper obs=state`` (batch 256 per GPU; skipped with a
   note on a single GPU): samples/s from the run's own clock (warm-up included);
3. every trained policy (EMA weights of its ``best.pt``) exported with
   `rfmp_rl.onnx_export.export_onnx` at NFE 1 and compared with PyTorch: max |onnxruntime -
   torch| <= 1e-4 in normalised action units, sphere components within 1e-5 of unit norm.
   ``export_onnx`` runs onnxruntime's CPUExecutionProvider only (it has no provider argument),
   so parity is checked on the CPU.

Real Push-T batches when the recipe's zarr exists, else synthetic ones (the DDP check needs the
zarr: it runs the recipe). Prints a table (setting, samples/s, peak GPU memory, losses, parity)
and exits non-zero when any setting fails: an exception, a non-finite loss, parity over a limit.

Every part that does not need CUDA runs on the CPU too: `build_settings`, `run_setting` (any
device) and `run_ddp` (``device=cpu`` trains over gloo) are what tests/benchmarks exercises.
"""

from __future__ import annotations

import argparse
import json
import math
import shlex
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import torch
from training_throughput import (
    ROOT,
    TITLES,
    TaskData,
    default_zarr,
    load_task_data,
    make_policy,
)

from rfmp_rl.checkpoint import load_checkpoint
from rfmp_rl.onnx_export import export_onnx
from rfmp_rl.training import (
    LoggerConfig,
    OptimConfig,
    TrainConfig,
    Trainer,
    setup_runtime,
)

TASKS = ("pusht_state", "pusht_image")
#: ONNX parity limits (what `export_onnx` enforces by default)
PARITY_LIMIT, SPHERE_LIMIT = 1e-4, 1e-5
#: (label, precision, compile) of the one-GPU settings
PRECISIONS = (("fp32", "fp32", False), ("bf16", "bf16", False),
              ("compiled fp32", "fp32", True))


@dataclass
class Setting:
    """One training check."""

    name: str
    task: str  # pusht_state | pusht_image
    precision: str  # fp32 | bf16
    compile: bool
    batch: int  # per process
    steps: int
    processes: int = 1  # > 1: the recipe under torchrun (DDP)


@dataclass
class Outcome:
    """What one setting measured (``error`` set when it failed).

    Example:
        >>> s = Setting("Push-T state fp32", "pusht_state", "fp32", False, 256, 300)
        >>> o = Outcome(s, 900.0, 1.2, 0.05, 0.07, parity=3e-4, sphere_error=0.0)
        >>> o.check(); o.ok, o.error
        (False, 'ONNX parity 0.0003 > 0.0001')
    """

    setting: Setting
    samples_per_s: float = math.nan  # all processes together
    peak_memory_gb: float | None = None  # None: not measured (CPU, or another process)
    final_loss: float = math.nan  # running training loss at the last step
    val_loss: float = math.nan
    parity: float = math.nan  # max |onnxruntime - torch|, normalised action units
    sphere_error: float = math.nan
    note: str = ""
    error: str | None = None

    def check(self) -> None:
        """Set ``error`` for a non-finite figure or parity over its limit."""
        if self.error:
            return
        for name in ("samples_per_s", "final_loss", "val_loss"):
            if not math.isfinite(getattr(self, name)):
                self.error = f"non-finite {name}: {getattr(self, name)}"
                return
        if not self.parity <= PARITY_LIMIT:
            self.error = f"ONNX parity {self.parity:.3g} > {PARITY_LIMIT:g}"
        elif not self.sphere_error <= SPHERE_LIMIT:
            self.error = f"ONNX sphere error {self.sphere_error:.3g} > {SPHERE_LIMIT:g}"

    @property
    def ok(self) -> bool:
        return self.error is None


def build_settings(steps: int, gpus: int, tasks=TASKS, state_batch: int = 256,
                   image_batch: int = 64, ddp: bool = True) -> tuple[list[Setting], list[str]]:
    """The checks for ``gpus`` visible GPUs: every task x (fp32, bf16, compiled fp32) on one
    GPU, then Push-T state under DDP over all of them (``gpus >= 2``); and the notes on what
    was skipped."""
    settings, notes = [], []
    for task in tasks:
        batch = state_batch if task == "pusht_state" else image_batch
        for label, precision, compiled in PRECISIONS:
            settings.append(Setting(f"{TITLES[task].split(' (')[0]} {label}", task, precision,
                                    compiled, batch, steps))
    if not ddp:
        notes.append("DDP skipped (--no-ddp)")
    elif gpus < 2:
        notes.append(f"DDP skipped: {gpus} GPU visible (needs 2 or more)")
    else:
        settings.append(Setting(f"Push-T state DDP x{gpus} bf16", "pusht_state", "bf16", False,
                                state_batch, steps, processes=gpus))
    return settings, notes


class _Clocked:
    """The training batches, noting the time at the start of step ``start`` and of step
    ``stop`` (``sample()`` is the first thing a step does; the device is synchronised there so
    the time covers the steps' GPU work)."""

    def __init__(self, data, device: torch.device, start: int, stop: int) -> None:
        self.data, self.device = data, device
        self.start, self.stop = start, stop
        self.calls, self.times = 0, {}

    @property
    def sampler(self):  # the engine saves / restores its generator
        return getattr(self.data, "sampler", None)

    def sample(self):
        self.calls += 1
        if self.calls in (self.start, self.stop):
            if self.device.type == "cuda":
                torch.cuda.synchronize(self.device)
            self.times[self.calls] = time.perf_counter()
        return self.data.sample()

    @property
    def seconds_per_step(self) -> float:
        return (self.times[self.stop] - self.times[self.start]) / (self.stop - self.start)


def check_parity(checkpoint: Path, out: Path, nfe: int = 1) -> tuple[float, float]:
    """Export the EMA policy of ``checkpoint`` at ``nfe`` (CPU, fp32); ``(max |onnxruntime -
    torch| in normalised action units, max sphere error)``, whatever their size."""
    model, payload = load_checkpoint(checkpoint, use_ema=True)
    report = export_onnx(model, out, nfe, atol=math.inf, sphere_tol=math.inf, latency_runs=2,
                         control_rate_hz=payload["control_rate_hz"])
    return report.max_abs_diff, report.max_sphere_error


def run_setting(setting: Setting, device: str, data: TaskData, workdir: Path,
                preset: str = "paper", down_dims: list[int] | None = None,
                warmup: int = 20) -> Outcome:
    """Train one single-process setting on ``device`` with `Trainer.fit`, then check the ONNX
    parity of its EMA policy; the run folder is removed afterwards."""
    runtime = setup_runtime(device, setting.precision, setting.compile, distributed=False)
    cuda = runtime.device.type == "cuda"
    run_dir = workdir / setting.name.replace(" ", "_")
    if setting.steps < 2:
        raise ValueError(f"{setting.name}: steps must be >= 2, got {setting.steps}")
    start = 1 + min(warmup, setting.steps - 2)  # timed: steps start .. steps - 1
    batches = _Clocked(data.train, runtime.device, start, setting.steps)
    if cuda:
        torch.cuda.empty_cache()
        torch.cuda.reset_peak_memory_stats(runtime.device)
    model = make_policy(setting.task, data, preset, down_dims=down_dims)
    trainer = Trainer(
        model, batches, data.val, runtime=runtime, run_dir=run_dir, recipe="gpu_check",
        optim=OptimConfig(warmup_steps=max(1, setting.steps // 10)),
        train=TrainConfig(steps=setting.steps, batch_size=setting.batch,
                          val_every=10 * setting.steps, val_batches=1,
                          log_every=10 * setting.steps, checkpoint_every=10 * setting.steps),
        logger=LoggerConfig(backend="none"), camera_keys=data.camera_keys, progress=False,
        control_rate_hz=10.0)  # Push-T's rate, for the exported metadata
    try:
        result = trainer.fit()
        peak = torch.cuda.max_memory_allocated(runtime.device) / 1e9 if cuda else None
        del trainer, model
        last = result.history[-1]
        parity, sphere = check_parity(run_dir / "best.pt", run_dir / "policy_nfe1.onnx")
    finally:
        shutil.rmtree(run_dir, ignore_errors=True)
    outcome = Outcome(setting, setting.batch / batches.seconds_per_step, peak,
                      float(last["train"]), float(last["val"]), parity, sphere,
                      note=f"steps {start}-{setting.steps - 1} timed")
    outcome.check()
    return outcome


def ddp_overrides(setting: Setting, device: str, out_dir: Path, zarr: Path, preset: str,
                  max_minutes: float, extra: list[str] = ()) -> list[str]:
    """The hydra overrides of recipes/pusht/train.py for a DDP setting."""
    steps = setting.steps
    return ["algo=srfmp", "obs=state", "space=euclidean", f"device={device}",
            f"precision={setting.precision}", f"compile={str(setting.compile).lower()}",
            f"model.unet_preset={preset}", f"train.steps={steps}",
            f"train.max_minutes={max_minutes}", f"train.batch_size={setting.batch}",
            f"train.val_every={steps}",
            # log_every beyond the run: with logger.backend=none, Trainer.fit's periodic
            # train-loss log calls log_scalar on a None logger
            "train.val_batches=1", f"train.log_every={10 * steps}",
            f"train.checkpoint_every={steps}",
            f"optim.warmup_steps={max(1, steps // 10)}", "eval.final_eval=false",
            "logger.backend=none", f"out_dir={out_dir}", f"data.path={zarr}", *extra]


def run_ddp(setting: Setting, device: str, workdir: Path, zarr: Path, preset: str = "paper",
            max_minutes: float = 30.0, extra: list[str] = (), timeout: float = 3600) -> Outcome:
    """``torchrun --standalone --nproc_per_node=<processes> recipes/pusht/train.py`` for
    ``setting``, then the ONNX parity of the run's ``best.pt``. samples/s: the global batch
    over the run's clock at its last step (warm-up included)."""
    out_dir = workdir / setting.name.replace(" ", "_")
    torchrun = Path(sys.executable).parent / "torchrun"
    command = [str(torchrun), "--standalone", f"--nproc_per_node={setting.processes}",
               str(ROOT / "recipes" / "pusht" / "train.py"),
               *ddp_overrides(setting, device, out_dir, zarr, preset, max_minutes, extra)]
    print(f"  {shlex.join(command)}", flush=True)
    proc = subprocess.run(command, capture_output=True, text=True, cwd=ROOT, timeout=timeout)
    try:
        if proc.returncode != 0:
            raise RuntimeError(f"torchrun exited with {proc.returncode}: "
                               f"{proc.stderr[-2000:] or proc.stdout[-2000:]}")
        history = json.loads((out_dir / "history.json").read_text())
        last = history[-1]
        seconds = float(last["minutes"]) * 60  # the clock at the start of the last step
        rate = (int(last["step"]) - 1) * setting.batch * setting.processes / seconds
        parity, sphere = check_parity(out_dir / "best.pt", out_dir / "policy_nfe1.onnx")
    finally:
        shutil.rmtree(out_dir, ignore_errors=True)
    outcome = Outcome(setting, rate, None, float(last["train"]), float(last["val"]), parity,
                      sphere, note=f"{setting.batch} per process, run clock incl. warm-up; "
                      "memory in the ranks")
    outcome.check()
    return outcome


def table(outcomes: list[Outcome]) -> list[str]:
    lines = ["| setting | batch | steps | samples/s | peak GPU memory (GB) | final train loss | "
             "val loss | ONNX parity (NFE 1) | sphere error | status | note |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for o in outcomes:
        s = o.setting
        memory = "-" if o.peak_memory_gb is None else f"{o.peak_memory_gb:.2f}"
        status = "ok" if o.ok else f"FAIL: {o.error}".replace("|", "/").replace("\n", " ")[:300]
        lines.append(f"| {s.name} | {s.batch} x {s.processes} | {s.steps} | "
                     f"{o.samples_per_s:,.1f} | {memory} | {o.final_loss:.4f} | {o.val_loss:.4f} | "
                     f"{o.parity:.2e} | {o.sphere_error:.1e} | {status} | {o.note} |")
    return lines


def parse_args(argv: list[str] | None = None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=300, help="training steps per setting")
    parser.add_argument("--warmup", type=int, default=20, help="steps excluded from samples/s")
    parser.add_argument("--tasks", nargs="+", default=list(TASKS), choices=TASKS)
    parser.add_argument("--batch", type=int, default=256, help="Push-T state batch (per GPU)")
    parser.add_argument("--image-batch", type=int, default=64, help="Push-T image batch")
    parser.add_argument("--preset", default="paper", help="UNet preset")
    parser.add_argument("--max-minutes", type=float, default=30.0, help="DDP run's time cap")
    parser.add_argument("--no-ddp", action="store_true", help="skip the torchrun check")
    parser.add_argument("--data", default=None, help="Push-T zarr (default: the recipe's)")
    parser.add_argument("--synthetic", action="store_true", help="synthetic batches, no zarr")
    parser.add_argument("--out", default=None, help="also write the table to this markdown file")
    args = parser.parse_args(argv)
    if args.steps < 2:
        parser.error("--steps must be >= 2")
    return args


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    if not torch.cuda.is_available():
        print(f"gpu_check: no CUDA device visible (torch {torch.__version__}); nothing to check")
        return 0
    gpus = torch.cuda.device_count()
    names = ", ".join(torch.cuda.get_device_name(i) for i in range(gpus))
    settings, notes = build_settings(args.steps, gpus, args.tasks, args.batch, args.image_batch,
                                     ddp=not args.no_ddp)
    import onnxruntime

    notes.append("ONNX parity runs on onnxruntime's CPUExecutionProvider (export_onnx has no "
                 f"provider argument; onnxruntime offers {onnxruntime.get_available_providers()})")
    data: dict[str, TaskData] = {}
    outcomes = []
    with tempfile.TemporaryDirectory() as tmp:
        for setting in settings:
            print(f"{setting.name}: {setting.steps} steps ...", flush=True)
            try:
                if setting.processes > 1:
                    zarr = Path(args.data) if args.data else default_zarr()
                    if args.synthetic or not zarr.exists():
                        raise RuntimeError(f"the DDP check runs the recipe, which needs the "
                                           f"Push-T zarr ({zarr} not found or --synthetic)")
                    outcome = run_ddp(setting, "cuda", Path(tmp), zarr, args.preset,
                                      args.max_minutes)
                else:
                    if setting.task not in data:
                        data[setting.task] = load_task_data(setting.task, setting.batch,
                                                            args.data, 0, args.synthetic)
                        notes.append(f"{setting.task}: {data[setting.task].source}")
                    outcome = run_setting(setting, "cuda", data[setting.task], Path(tmp),
                                          args.preset, warmup=args.warmup)
            except Exception as err:  # every failure is reported in the table
                outcome = Outcome(setting, error=f"{type(err).__name__}: {err}")
            outcomes.append(outcome)
            print("\n".join(table([outcome])[2:]), flush=True)
    lines = [f"# GPU check: {gpus} x {names}, torch {torch.__version__}, preset {args.preset}",
             "", f"Command: `{shlex.join(['python', *sys.argv])}`", "",
             *table(outcomes), "", *[f"- {n}" for n in notes]]
    failed = [o for o in outcomes if not o.ok]
    lines.append(f"- {len(outcomes) - len(failed)} of {len(outcomes)} settings pass")
    print("\n".join(lines))
    if args.out:
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.out).write_text("\n".join(lines) + "\n")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
