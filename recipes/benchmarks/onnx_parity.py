"""ONNX vs PyTorch parity matrix: RFMP and SRFMP, Euclidean and R^3 x S^3 x R^1 actions,
low-dim and image observations, NFE 1, 3 and 10.

    bash recipes/venv.sh python recipes/benchmarks/onnx_parity.py [--out results/onnx_parity.md]

Each cell exports a freshly initialised policy (small UNet, full ResNet-18 trunk for images)
with `rfmp_rl.onnx_export.export_onnx`, which runs onnxruntime against PyTorch on the same
inputs and prior noise at batch 1, 3 and 8 and fails above 1e-4 (or a sphere component off the
manifold by more than 1e-5). Untrained weights are a harder parity test than trained ones: the
outputs are not saturated.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import torch

from rfmp_rl.modules import ModelConfig, build_model
from rfmp_rl.onnx_export import export_onnx


def make(algorithm: str, manifold: str, obs: str):
    cameras = {"image": [3, 96, 96]} if obs == "image" else {}
    cfg = ModelConfig(
        algorithm=algorithm, action_manifold=manifold, obs_dim=4, horizon=16,
        down_dims=[32, 64, 128], cameras=cameras, crop_shape=[84, 84] if cameras else None,
        vision_out_dim=64,
    )
    torch.manual_seed(0)
    model = build_model(cfg)
    chunk = model.chunk.unflatten(model.chunk.random_base(64))
    model.action_normalizer.fit(chunk * 3)
    model.obs_normalizer.fit(torch.randn(64, 4) * 2)
    return model.eval()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--nfes", nargs="+", type=int, default=[1, 3, 10])
    parser.add_argument("--out", default=None)
    args = parser.parse_args()
    lines = ["| algorithm | actions | observations | NFE | max abs diff | max sphere error | "
             "onnxruntime (ms) | torch eager (ms) |", "|---|---|---|---|---|---|---|---|"]
    print("\n".join(lines), flush=True)
    failures = 0
    with tempfile.TemporaryDirectory() as tmp:
        for algorithm in ("rfmp", "srfmp"):
            for manifold in ("R2", "R3 x S3 x R1"):
                for obs in ("lowdim", "image"):
                    model = make(algorithm, manifold, obs)
                    for nfe in args.nfes:
                        try:
                            r = export_onnx(model, Path(tmp) / "p.onnx", nfe=nfe,
                                            control_rate_hz=10.0)
                            row = (f"| {algorithm} | {manifold} | {obs} | {nfe} | "
                                   f"{r.max_abs_diff:.2e} | {r.max_sphere_error:.2e} | "
                                   f"{r.onnx_latency_ms:.2f} | {r.torch_latency_ms:.2f} |")
                        except RuntimeError as err:
                            failures += 1
                            row = f"| {algorithm} | {manifold} | {obs} | {nfe} | FAILED: {err} |"
                        lines.append(row)
                        print(row, flush=True)
    if args.out:
        cmd = "bash recipes/venv.sh python recipes/benchmarks/onnx_parity.py " + " ".join(
            sys.argv[1:])
        Path(args.out).write_text(
            "# ONNX export parity (limit 1e-4; sphere components within 1e-5 of unit norm)\n\n"
            f"Regenerate with:\n\n```\n{cmd}\n```\n\n" + "\n".join(lines)
            + f"\n\n{len(lines) - 2 - failures} of {len(lines) - 2} cells pass.\n"
        )
    sys.exit(1 if failures else 0)


if __name__ == "__main__":
    main()
