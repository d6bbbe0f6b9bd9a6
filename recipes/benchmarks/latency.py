"""Batch-1 latency of the exported NFE=1 SRFMP policy against its bare network and eager PyTorch.

    .venv/bin/python recipes/benchmarks/latency.py [--presets paper small] [--runs 300]
        [--threads 2 1] [--out results/latency.md]

For the Push-T state configuration (20-D observations, R^2 actions, T_p = 16) and each UNet
preset, four ways of producing one action chunk are timed in one process, at batch 1, with the
same thread count for torch and onnxruntime:

    (a) policy   the whole exported graph, `export_onnx(model, path, nfe=1)`, in onnxruntime
    (b) network  `model.network` (UNet + tau head) alone, exported the same way (dynamo, opset
                 18, dynamic batch) and called once on (x (1, T_p, D), tau (1,), cond (1, C))
    (c) eager    `model.sample(model.encode(obs), noise, nfe=1)` under `torch.no_grad()`
    (d) deploy   the torch-free `rfmp_deploy.Controller` on the file of (a), its
                 `inference_times` (run with T_a = 1 so that every step plans)

Targets, at 2 threads: (a)/(b) <= 1.15 (the graph around the network costs little) and
(c)/(a) >= 2. Ratios are of medians. Everything is repeated at 1 thread as a control: on a
loaded 2-core machine a 2-thread eager call can stall on a busy core (see the notes in the output).

Reduced-precision exports of (a) (``--precisions``, default fp16 and int8: `export_onnx(...,
precision=...)`, the networks in float16 or int8, everything around them float32) take the same
turns; their table gives the latency ratio to the float32 graph (a) (fp32 median / variant median,
so > 1 is faster), the file size and the largest difference to float32 PyTorch. With random
weights, int8 calibrates on observations drawn uniformly in the normaliser's range.
The paths take turns in blocks (a few discarded calls, then timed calls) so that load from other
processes on a shared machine falls on all four alike. Weights are random and the normalisers
fitted on random data: latency does not depend on their values.
Results are printed; ``--out`` also writes them, under the command that produced them.
"""

from __future__ import annotations

import argparse
import functools
import os
import platform
import shlex
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]

import numpy as np  # noqa: E402
import onnxruntime as ort  # noqa: E402
import torch  # noqa: E402
from configs import task_config  # noqa: E402
from rfmp_deploy import Controller, Policy  # noqa: E402
from torch import nn  # noqa: E402

from rfmp_rl import keys  # noqa: E402
from rfmp_rl.modules import FlowModel, build_model  # noqa: E402
from rfmp_rl.onnx_export import export_onnx  # noqa: E402

PATHS = ("policy", "network", "eager", "deploy")
RATE_HZ = 10.0  # Push-T's control rate, written into the exported metadata
COMMAND = ".venv/bin/python recipes/benchmarks/latency.py"


def make_policy(preset: str, seed: int = 0) -> FlowModel:
    """The Push-T state SRFMP policy with random weights and normalisers fitted on random data."""
    torch.manual_seed(seed)
    model = build_model(task_config("pusht_state", "srfmp", preset)).eval()
    # Unit-range actions: in Push-T's pixel units (0..512) float32 rounding alone exceeds the
    # exporter's absolute parity limit of 1e-4.
    model.action_normalizer.fit(torch.rand(1000, model.action_dim))
    model.obs_normalizer.fit(torch.randn(1000, model.cfg.obs_dim))
    return model


def export_policy(preset: str, path: str | Path) -> None:
    """Export `make_policy(preset)` at NFE 1 to ``path`` (parity-checked by `export_onnx`)."""
    torch.set_num_threads(2)
    print(export_onnx(make_policy(preset), path, nfe=1, control_rate_hz=RATE_HZ).summary(),
          flush=True)


class BareNetwork(nn.Module):
    """``model.network`` alone: ``(x (B, T_p, D), tau (B,), cond (B, C)) -> (v_x, v_tau)``."""

    def __init__(self, network: nn.Module) -> None:
        super().__init__()
        self.network = network

    def forward(self, x: torch.Tensor, tau: torch.Tensor, cond: torch.Tensor):
        return self.network(x, tau, cond)


@torch.no_grad()
def export_network(model: FlowModel, path: Path) -> None:
    """Export ``model.network`` alone to ``path``, with a dynamic batch like the policy graph."""
    example = (
        torch.randn(2, model.horizon, model.action_dim),  # x (B, T_p, D)
        torch.zeros(2),  # tau (B,)
        model.encode(torch.randn(2, 2, model.cfg.obs_dim)),  # cond (B, C)
    )
    batch = torch.export.Dim("batch", min=1, max=4096)
    program = torch.onnx.export(
        BareNetwork(model.network).eval(),
        example,
        dynamo=True,
        opset_version=18,
        input_names=["x", "tau", "cond"],
        output_names=["v_x", "v_tau"],
        dynamic_shapes=({0: batch}, {0: batch}, {0: batch}),  # same dynamic batch as (a)
        verbose=False,
    )
    program.save(str(path))


def session(path: Path, threads: int) -> ort.InferenceSession:
    """An onnxruntime session set up like `rfmp_deploy.Policy(path, intra_op_threads=threads)`."""
    options = ort.SessionOptions()
    options.intra_op_num_threads = threads
    options.inter_op_num_threads = 1
    return ort.InferenceSession(str(path), sess_options=options, providers=["CPUExecutionProvider"])


def timed(call, runs: int, discard: int) -> list[float]:
    """Seconds per call over ``runs`` calls, after ``discard`` untimed ones."""
    for _ in range(discard):
        call()
    times = []
    for _ in range(runs):
        start = time.perf_counter()
        call()
        times.append(time.perf_counter() - start)
    return times


def export_all(
    preset: str, workdir: Path, precisions: list[str]
) -> tuple[FlowModel, Path, Path, float, dict[str, tuple[Path, float]]]:
    """Export the policy graph (a), the bare network (b) and (a) at each reduced precision;
    returns them with (a)'s parity and ``{precision: (path, parity)}``."""
    model = make_policy(preset)
    policy_path = workdir / f"pusht_state_srfmp_{preset}_nfe1.onnx"
    network_path = workdir / f"pusht_state_srfmp_{preset}_network.onnx"
    start = time.perf_counter()
    report = export_onnx(model, policy_path, nfe=1, control_rate_hz=RATE_HZ)
    export_network(model, network_path)
    variants = {}
    for precision in precisions:
        path = workdir / f"pusht_state_srfmp_{preset}_nfe1_{precision}.onnx"
        variants[precision] = (path, export_onnx(model, path, nfe=1, precision=precision,
                                                 control_rate_hz=RATE_HZ).max_abs_diff)
    print(
        f"[{preset}] exported {2 + len(precisions)} graphs in "
        f"{time.perf_counter() - start:.0f} s; parity max |ort - torch| = "
        f"{report.max_abs_diff:.2g}",
        flush=True,
    )
    return model, policy_path, network_path, report.max_abs_diff, variants


def measure(
    model: FlowModel, policy_path: Path, network_path: Path, threads: int, args: argparse.Namespace,
    variants: dict[str, tuple[Path, float]],
) -> dict[str, list[float]]:
    """Seconds per call of the four paths and the precision variants of (a) (as
    ``policy_<precision>``), all at ``threads`` threads, taking turns in blocks."""
    torch.set_num_threads(threads)
    rng = np.random.default_rng(0)
    obs = rng.standard_normal((1, 2, model.cfg.obs_dim), dtype=np.float32)  # (1, T_o, D_obs)
    noise = rng.standard_normal((1, model.noise_dim), dtype=np.float32)
    with torch.no_grad():
        cond = model.encode(torch.from_numpy(obs)).numpy()  # (1, C)
    x = rng.standard_normal((1, model.horizon, model.action_dim), dtype=np.float32)
    tau = np.zeros(1, np.float32)

    policy = session(policy_path, threads)
    network = session(network_path, threads)
    policy_feed = {keys.OBSERVATION: obs, keys.PRIOR_NOISE: noise}
    network_feed = {"x": x, "tau": tau, "cond": cond}
    obs_t, noise_t = torch.from_numpy(obs), torch.from_numpy(noise)
    controller = Controller(Policy(policy_path, intra_op_threads=threads), seed=0, action_steps=1)
    step_obs = {keys.OBSERVATION: obs[0, 1]}

    @torch.no_grad()
    def eager() -> None:
        model.sample(model.encode(obs_t), noise_t, nfe=1)

    calls = {
        "policy": lambda: policy.run([keys.ACTION], policy_feed),
        "network": lambda: network.run(None, network_feed),
        "eager": eager,
        "deploy": lambda: controller.step(step_obs),
    }
    for precision, (path, _) in variants.items():
        calls[f"policy_{precision}"] = functools.partial(
            session(path, threads).run, [keys.ACTION], policy_feed)
    times: dict[str, list[float]] = {name: [] for name in calls}
    per_block = -(-args.runs // args.blocks)
    for call in calls.values():  # warm-up: first calls allocate
        timed(call, 0, args.warmup)
    for _ in range(args.blocks):
        for name in calls:
            controller.inference_times.clear()
            step_times = timed(calls[name], per_block, args.discard)
            if name == "deploy":  # the controller's own clock around the policy call
                step_times = list(controller.inference_times)[args.discard :]
            times[name].extend(step_times)
    controller.close()
    return times


def machine_info() -> str:
    cpu = platform.processor() or platform.machine()
    cpuinfo = Path("/proc/cpuinfo")
    if cpuinfo.exists():
        names = [
            ln.split(":", 1)[1].strip()
            for ln in cpuinfo.read_text().splitlines()
            if ln.startswith("model name")
        ]
        cpu = names[0] if names else cpu
    return (
        f"{cpu}, {os.cpu_count()} logical CPUs; Python {platform.python_version()}, "
        f"torch {torch.__version__}, onnxruntime {ort.__version__} (CPUExecutionProvider, "
        f"inter-op 1 thread)"
    )


def load_average() -> str:
    return ", ".join(f"{v:.2f}" for v in os.getloadavg())


def tables(results: list[dict]) -> list[str]:
    lines = [
        "| preset | threads | (a) policy, ORT | (b) network, ORT | (c) eager torch | "
        "(d) deploy Controller |",
        "|---|---|---|---|---|---|",
    ]
    for r in results:
        cells = []
        for name in PATHS:
            ms = np.asarray(r["times"][name]) * 1e3
            cells.append(f"{np.median(ms):.2f} / {np.percentile(ms, 95):.2f}")
        lines.append(f"| {r['preset']} | {r['threads']} | " + " | ".join(cells) + " |")
    lines += [
        "",
        "| preset | threads | (a)/(b), target <= 1.15 | (c)/(a), target >= 2 | (d)/(a) | "
        "network params | parity (a) vs torch |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in results:
        med = {name: float(np.median(r["times"][name])) for name in PATHS}
        ab, ca = med["policy"] / med["network"], med["eager"] / med["policy"]
        lines.append(
            f"| {r['preset']} | {r['threads']} | {ab:.2f} ({'met' if ab <= 1.15 else 'missed'}) "
            f"| {ca:.2f} ({'met' if ca >= 2 else 'missed'}) | {med['deploy'] / med['policy']:.2f} "
            f"| {r['params'] / 1e6:.1f}M | {r['parity']:.1g} |"
        )
    if any(r["variants"] for r in results):
        lines += [
            "",
            "Reduced precision: the graph (a) exported with the networks in float16 or int8 "
            "(median / p95 in ms; ratio = (a) fp32 median / variant median, > 1 is faster).",
            "",
            "| preset | threads | precision | median / p95 | latency ratio to fp32 | file (MB) "
            "| max abs diff vs torch fp32 (normalised) |",
            "|---|---|---|---|---|---|---|",
        ]
    for r in results:
        fp32 = float(np.median(r["times"]["policy"]))
        rows = [("fp32", "policy", r["policy_path"], r["parity"])]
        rows += [(p, f"policy_{p}", path, parity) for p, (path, parity) in r["variants"].items()]
        if len(rows) == 1:
            continue
        for precision, name, path, parity in rows:
            ms = np.asarray(r["times"][name]) * 1e3
            lines.append(
                f"| {r['preset']} | {r['threads']} | {precision} | {np.median(ms):.2f} / "
                f"{np.percentile(ms, 95):.2f} | {fp32 / float(np.median(r['times'][name])):.2f} "
                f"| {path.stat().st_size / 1e6:.1f} | {parity:.2g} |"
            )
    return lines


NOTES = """\
How to read it: (a) is one network call plus what surrounds it in the deployed graph
(observation normalisation and encoding, the prior from the noise, one Euler step with the
manifold maps, unnormalisation); (b) is the network call alone, so (a)/(b) is the price of that
surrounding graph. (d) is the same session call as (a) behind `Policy`'s input checks and the
Controller's observation window. The comparison the targets refer to is at 2 threads; the 1-thread
rows are a control. The machine may be shared (see the load averages): when the load approaches
the CPU count, every 2-thread parallel op waits for a busy sibling core, torch's OpenMP barriers
(hundreds of ms per call) far more than onnxruntime's pool, so 2-thread eager figures then measure
the contention as much as the framework; the 1-thread rows do not have that problem.

Reduced precision on the measured CPU (AMD EPYC, AVX-512 VNNI): static int8 (`QLinearConv`
with calibrated activation ranges) is the one that is faster; fp16 halves the file but
onnxruntime's CPU provider runs its convolutions through casts to float32, so it costs what
float32 costs (fp16 is for execution providers with half-precision kernels: CUDA, ARM CPUs);
dynamic int8 quantises the activations at every call (`ConvInteger`), which costs what the int8
arithmetic saves. The closed-loop effect of each on a trained policy:
`results/pusht_onnx_precision.md`."""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--presets", nargs="+", default=["paper", "small"])
    parser.add_argument("--runs", type=int, default=300, help="timed calls per path (>= 200)")
    parser.add_argument("--blocks", type=int, default=10, help="turns the paths take")
    parser.add_argument("--warmup", type=int, default=20, help="untimed calls per path at start")
    parser.add_argument("--discard", type=int, default=3, help="untimed calls per path per block")
    parser.add_argument(
        "--threads", type=int, nargs="+", default=[2, 1], help="torch and onnxruntime threads"
    )
    parser.add_argument("--precisions", nargs="*", default=["fp16", "int8"],
                        help="reduced-precision exports of (a) timed beside it")
    parser.add_argument("--out", default=None, help="also write the tables to this markdown file")
    args = parser.parse_args()
    torch.set_num_threads(args.threads[0])
    load_before = load_average()
    results = []
    with tempfile.TemporaryDirectory(prefix="rfmp_latency_") as tmp:
        for preset in args.presets:
            model, policy_path, network_path, parity, variants = export_all(
                preset, Path(tmp), args.precisions)
            params = sum(p.numel() for p in model.network.parameters())
            for threads in args.threads:
                times = measure(model, policy_path, network_path, threads, args, variants)
                results.append(
                    {
                        "preset": preset,
                        "threads": threads,
                        "params": params,
                        "parity": parity,
                        "times": times,
                        "policy_path": policy_path,
                        "variants": variants,
                    }
                )
                print(f"[{preset}] measured at {threads} thread(s)", flush=True)
            runs = len(results[0]["times"]["policy"])
            lines = tables(results)  # file sizes are read while the files exist
    lines = [
        f'Push-T state (`task_config("pusht_state", "srfmp", preset)`), SRFMP, NFE 1, '
        f"batch 1, random weights: **median / p95 in ms** over {runs} timed calls per path "
        f"({args.blocks} blocks per path, taking turns; {args.warmup} warm-up calls per path "
        f"first). Same thread count for torch and onnxruntime in each row.",
        "",
        f"Machine: {machine_info()}. Load average (1, 5, 15 min) at start {load_before}, "
        f"at end {load_average()}.",
        "",
        *lines,
        "",
        NOTES,
    ]
    print("\n" + "\n".join(lines), flush=True)
    if args.out:
        command = shlex.join([*COMMAND.split(), *sys.argv[1:]])
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.out).write_text(
            f"{command}\n\n# Inference latency: exported policy, bare network, eager PyTorch, "
            f"deploy controller\n\n" + "\n".join(lines) + "\n"
        )


if __name__ == "__main__":
    main()
