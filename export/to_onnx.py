"""Export a checkpoint's fixed-NFE inference to ONNX and prove parity with PyTorch.

    python export/to_onnx.py --checkpoint runs/x/ckpt.pt --nfe 1 [--horizon 1.0]
        [--method euler] [--schedule srfmp] [--out policy.onnx] [--opset 18] [--raw-weights]

Writes one ONNX graph (normalise -> encode -> NFE solver steps with manifold maps ->
unnormalise), checks it with ``onnx.checker``, runs it in onnxruntime against the PyTorch
policy on the same inputs and prior noise, prints the max difference and the latency, and exits
non-zero if the difference exceeds 1e-4 (in normalised action units: Euclidean coordinates
divided by their half-range) or a sphere component is off the manifold by > 1e-5.
The EMA weights are exported unless ``--raw-weights`` is given.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from rfmp_rl.checkpoint import load_checkpoint  # noqa: E402
from rfmp_rl.onnx_export import export_onnx  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--checkpoint", required=True, help="checkpoint written by training")
    parser.add_argument("--nfe", type=int, required=True, help="function evaluations, unrolled")
    parser.add_argument(
        "--horizon", type=float, default=1.0, help="integration end time T (may exceed 1)"
    )
    parser.add_argument("--method", default="euler", help="euler | euler_projx | midpoint | rk4")
    parser.add_argument(
        "--schedule",
        default=None,
        help="uniform | srfmp (default: srfmp for SRFMP, uniform for RFMP)",
    )
    parser.add_argument("--refine-dt", type=float, default=None, help="SRFMP refinement step")
    parser.add_argument("--out", default=None, help="output .onnx (default: next to checkpoint)")
    parser.add_argument("--opset", type=int, default=18)
    parser.add_argument("--raw-weights", action="store_true", help="export non-EMA weights")
    args = parser.parse_args(argv)

    model, payload = load_checkpoint(args.checkpoint, use_ema=not args.raw_weights)
    out = (
        Path(args.out)
        if args.out
        else Path(args.checkpoint).with_name(f"policy_{payload['algorithm']}_nfe{args.nfe}.onnx")
    )
    try:
        report = export_onnx(
            model,
            out,
            args.nfe,
            args.method,
            args.horizon,
            args.schedule,
            args.refine_dt,
            opset=args.opset,
        )
    except (RuntimeError, ValueError) as err:
        print(f"export failed: {err}", file=sys.stderr)
        return 1
    print(report.summary())
    return 0


if __name__ == "__main__":
    sys.exit(main())
