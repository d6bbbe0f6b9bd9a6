"""Soak test of the deploy controller: a fixed-rate loop against a fake robot, for minutes.

    .venv/bin/python recipes/benchmarks/soak.py [--minutes 10] [--rate 50] [--preset small]
        [--model policy.onnx] [--threads 2] [--modes sync async] [--out results/soak.md]

Exports an SRFMP NFE=1 Push-T state policy of the given UNet preset (random weights; in a child
process, so that this one stays torch-free like the robot PC) or loads ``--model``, then drives
an `rfmp_deploy.Controller` (T_a from the model: one inference every T_a steps) with
`rfmp_deploy.run` at ``--rate`` Hz against a fake robot that returns random valid observations
(standard normal, like `Policy.random_inputs`) and drops the actions. Each mode in ``--modes``
runs for ``--minutes``, one after the other in the same process: ``sync`` plans inside the step
that needs the chunk, ``async`` (``Controller(asynchronous=True)``) plans in a background thread
while the queued actions are sent.

Recorded: per-step latency (read + step + send, the work `run` measures against the period) at
p50, p99 and max; every inference's latency (`Controller.inference_times`); overruns and missed
ticks (`RunStats`); the controller's events; the process RSS (VmRSS) every 10 s. Targets: no
overrun, and an RSS growth below 5 MB (10^6 bytes) between the first minute and the end of each
mode. Results are printed; ``--out`` also writes them, under the command that produced them.
"""

from __future__ import annotations

import argparse
import multiprocessing
import os
import shlex
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]

import numpy as np  # noqa: E402
import onnxruntime as ort  # noqa: E402
from rfmp_deploy import Controller, Policy, run  # noqa: E402

COMMAND = ".venv/bin/python recipes/benchmarks/soak.py"
RSS_EVERY = 10.0  # seconds between RSS samples


def rss_bytes() -> int:
    """Resident set size of this process (VmRSS in /proc/self/status)."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) * 1024  # reported in kB
    raise RuntimeError("no VmRSS in /proc/self/status")


def _export(preset: str, path: str) -> None:
    """Child process: torch, rfmp_rl and the export live and die here."""
    from latency import export_policy

    export_policy(preset, path)


def export_in_child(preset: str, path: Path) -> None:
    child = multiprocessing.get_context("spawn").Process(target=_export, args=(preset, str(path)))
    child.start()
    child.join()
    if child.exitcode != 0:
        raise SystemExit(f"export of the {preset} policy failed (exit code {child.exitcode})")


class FakeRobot:
    """Random valid observations; times each step from reading to sending.

    Timings go into arrays allocated (and touched) up front, so recording them does not grow
    the process while it is being measured.
    """

    def __init__(self, controller: Controller, capacity: int, seed: int = 0) -> None:
        meta = controller.meta
        self.controller = controller
        self.rng = np.random.default_rng(seed)
        self.fields = [(f.key, f.dim) for f in meta.observation_keys]
        self.frames = {s.name: (s.shape[2], s.shape[3], s.shape[1]) for s in meta.image_inputs}
        self.step_times = np.full(capacity, np.nan)  # seconds, read -> send
        self.inference_times = np.full(capacity, np.nan)  # seconds, every inference
        self.steps = self.inferences = 0
        self._plans = controller.plan_count
        self._begin = 0.0

    def read_observation(self) -> dict[str, np.ndarray]:
        self._begin = time.perf_counter()
        obs = {key: self.rng.standard_normal(dim, dtype=np.float32) for key, dim in self.fields}
        for name, shape in self.frames.items():  # H x W x C uint8
            obs[name] = self.rng.integers(0, 256, shape, dtype=np.uint8)
        return obs

    def send_action(self, action: np.ndarray) -> None:
        elapsed = time.perf_counter() - self._begin
        if self.steps < len(self.step_times):
            self.step_times[self.steps] = elapsed
        self.steps += 1
        if self.controller.plan_count != self._plans:  # this step ran an inference
            self._plans = self.controller.plan_count
            if self.inferences < len(self.inference_times):
                self.inference_times[self.inferences] = self.controller.last_inference_time
            self.inferences += 1


class Monitor:
    """The loop's ``stop``: samples RSS every `RSS_EVERY` s and ends the run after ``seconds``."""

    def __init__(self, seconds: float, robot: FakeRobot) -> None:
        self.robot = robot
        self.start = time.monotonic()
        self.end = self.start + seconds
        self.next_sample = self.start
        self.samples: list[tuple[float, int]] = []  # (seconds since start, RSS bytes)

    def sample(self) -> None:
        now = time.monotonic() - self.start
        self.samples.append((now, rss_bytes()))
        if len(self.samples) % 6 == 1:  # once a minute
            rss = self.samples[-1][1] / 1e6
            print(f"t = {now:5.0f} s: {self.robot.steps} steps, RSS {rss:.2f} MB", flush=True)

    def __call__(self) -> bool:
        now = time.monotonic()
        if now >= self.next_sample:
            self.sample()
            self.next_sample += RSS_EVERY
        return now >= self.end


def events_bytes(controller: Controller) -> int:
    """Approximate memory held by the controller's retained `Event` list."""
    total = sys.getsizeof(controller.events)
    for e in controller.events:
        total += sys.getsizeof(e) + sys.getsizeof(e.__dict__) + sys.getsizeof(e.message)
        total += sys.getsizeof(e.time)
    return total


def percentiles_ms(values: np.ndarray) -> str:
    ms = values[np.isfinite(values)] * 1e3
    return f"{np.median(ms):.2f} / {np.percentile(ms, 99):.2f} / {ms.max():.2f}"


def report(args, mode: str, model: str, controller: Controller, robot: FakeRobot, stats,
           monitor) -> list[str]:
    meta = controller.meta
    samples = monitor.samples
    t, rss = np.array([s[0] for s in samples]), np.array([s[1] for s in samples], dtype=float)
    at_minute = rss[np.searchsorted(t, 60.0)] if t[-1] >= 60.0 else rss[0]
    growth = rss[-1] - at_minute
    peak = rss[t >= min(60.0, t[-1])].max() - at_minute
    half = rss[np.searchsorted(t, t[-1] / 2)]  # bounded buffers (events) may still be filling
    period = 1e3 / args.rate
    expected = int(args.minutes * 60 * args.rate)
    counts = ", ".join(f"{k} {v}" for k, v in sorted(controller.event_counts.items())) or "none"
    kind = ("Asynchronous `Controller(asynchronous=True)`" if mode == "async"
            else "Synchronous `Controller`")
    lines = [
        f"## {mode}",
        "",
        f"Model: {model} ({meta.algorithm}, NFE {meta.nfe}, T_p {meta.horizon}, "
        f"T_a {meta.action_steps}, D_obs {meta.obs_dim}, actions {meta.action_space}). "
        f"{kind} driven by `rfmp_deploy.run` at {args.rate:g} Hz "
        f"(period {period:.1f} ms) for {args.minutes:g} min; onnxruntime {ort.__version__}, "
        f"intra-op {args.threads} threads; {os.cpu_count()} logical CPUs, process nice "
        f"{os.nice(0)}, load average "
        f"(1, 5, 15 min) at end {', '.join(f'{v:.2f}' for v in os.getloadavg())}. "
        f"The policy ran 3 untimed warm-up inferences before the loop.",
        "",
        "| figure | measured | target |",
        "|---|---|---|",
        f"| steps | {stats.steps} in {stats.duration:.1f} s (grid: {expected}) | |",
        f"| step latency p50 / p99 / max (ms) | {percentiles_ms(robot.step_times)} "
        f"| below the {period:.1f} ms period |",
        f"| inference latency p50 / p99 / max (ms), {robot.inferences} inferences | "
        f"{percentiles_ms(robot.inference_times)} | |",
        f"| overruns / missed ticks (`RunStats`) | {stats.overruns} / {stats.missed_ticks} | "
        f"0: **{'met' if stats.overruns == 0 else 'missed'}** |",
        f"| controller events | {counts} | |",
        f"| events retained at end | {len(controller.events)} "
        f"(~{events_bytes(controller) / 1e6:.2f} MB, capped at {controller.max_events}) | |",
        f"| RSS at start / 1 min / end / max (MB) | {rss[0] / 1e6:.2f} / {at_minute / 1e6:.2f} / "
        f"{rss[-1] / 1e6:.2f} / {rss.max() / 1e6:.2f} | |",
        f"| **RSS growth, 1 min to end** | **{growth / 1e6:+.2f} MB** (peak after 1 min "
        f"{peak / 1e6:+.2f} MB) | < 5 MB: **{'met' if growth < 5e6 else 'missed'}** |",
        f"| RSS growth over the second half ({t[-1] / 120:.1f} min to end) | "
        f"{(rss[-1] - half) / 1e6:+.2f} MB | |",
        "",
        "Missed ticks without an overrun are steps that started late (the process woke late "
        "from its sleep) and so ended past the next tick; the step's own work fit the period.",
        "",
        f"RSS (MB) every {RSS_EVERY:g} s, one row per minute:",
        "",
        "| minute | " + " | ".join(f"+{k * RSS_EVERY:g} s" for k in range(6)) + " |",
        "|---|" + "---|" * 6,
    ]
    for row in range(0, len(samples), 6):
        cells = [f"{v / 1e6:.2f}" for v in rss[row : row + 6]]
        cells += [""] * (6 - len(cells))
        lines.append(f"| {row // 6} | " + " | ".join(cells) + " |")
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, default=10.0, help="length of the loop")
    parser.add_argument("--rate", type=float, default=50.0, help="control rate in Hz")
    parser.add_argument("--preset", default="small", help="UNet preset of the exported policy")
    parser.add_argument("--model", default=None, help="soak this .onnx instead of exporting")
    parser.add_argument("--threads", type=int, default=2, help="onnxruntime intra-op threads")
    parser.add_argument("--seed", type=int, default=0, help="noise and observation seed")
    parser.add_argument("--modes", nargs="+", default=["sync", "async"],
                        choices=["sync", "async"], help="controller modes, run one after another")
    parser.add_argument("--out", default=None, help="also write the report to this markdown file")
    args = parser.parse_args()

    with tempfile.TemporaryDirectory(prefix="rfmp_soak_") as tmp:
        if args.model is None:
            path = Path(tmp) / f"pusht_state_srfmp_{args.preset}_nfe1.onnx"
            export_in_child(args.preset, path)
            model = f"exported SRFMP Push-T state, `{args.preset}` preset, random weights"
        else:
            path = Path(args.model)
            model = f"`{args.model}`"
        policy = Policy(path, intra_op_threads=args.threads)
    rng = np.random.default_rng(args.seed)
    for _ in range(3):  # warm-up: the first calls allocate
        policy(**policy.random_inputs(1, rng))

    lines = []
    for mode in args.modes:
        controller = Controller(policy, seed=args.seed, control_rate_hz=args.rate,
                                asynchronous=mode == "async")
        capacity = int(args.minutes * 60 * args.rate) + 1000
        robot = FakeRobot(controller, capacity, seed=args.seed)
        monitor = Monitor(args.minutes * 60, robot)
        print(f"soaking {path.name} ({mode}) at {args.rate:g} Hz for {args.minutes:g} min",
              flush=True)
        stats = run(controller, robot, rate_hz=args.rate, stop=monitor)
        monitor.sample()  # the end
        controller.close()
        print(stats.summary(), flush=True)
        lines += report(args, mode, model, controller, robot, stats, monitor) + [""]
    print("\n" + "\n".join(lines), flush=True)
    if args.out:
        command = shlex.join([*COMMAND.split(), *sys.argv[1:]])
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.out).write_text(
            f"{command}\n\n# Controller soak test\n\n" + "\n".join(lines)
        )


if __name__ == "__main__":
    main()
