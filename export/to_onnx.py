"""Export a checkpoint's fixed-NFE inference to ONNX and prove parity with PyTorch.

    python export/to_onnx.py --checkpoint runs/x/ckpt.pt [--nfe 1] [--t-end 1.0]
        [--method euler] [--schedule srfmp] [--out policy.onnx] [--opset 18] [--raw-weights]
        [--precision fp32|fp16|int8|int8-dynamic] [--calibration STORE] [--max-diff X]
        [--rate HZ]

Writes one ONNX graph (normalise -> encode -> NFE solver steps with manifold maps ->
unnormalise), checks it with ``onnx.checker``, runs it in onnxruntime against the PyTorch
policy on the same inputs and prior noise, prints the max difference and the latency, and exits
non-zero if the difference exceeds 1e-4 (in normalised action units: Euclidean coordinates
divided by their half-range) or a sphere component is off the manifold by > 1e-5.
The EMA weights are exported unless ``--raw-weights`` is given. The solver settings not given
on the command line come from the checkpoint (the `SolverConfig` its run stored; for older
checkpoints, the algorithm's defaults at NFE 1). The control rate written into the metadata is
``--rate``, else the one the checkpoint carries (its environment's); a checkpoint without one
needs ``--rate``.

``--precision`` exports the networks (observation encoder, UNet) in float16 or int8 while the
normalisation, manifold maps and solver steps stay float32 (`rfmp_rl.onnx_export`); the
difference to the float32 PyTorch policy is printed, stored in the model's metadata and must
stay below ``--max-diff`` (default per precision: `PARITY_LIMITS`). ``int8`` calibrates its
activation ranges on observation windows from ``--calibration`` (a store written by
`rfmp-convert`, holding the policy's observation fields and cameras); without it, on windows drawn
uniformly in the observation normaliser's range, which is cruder.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

import torch  # noqa: E402

from rfmp_rl import keys  # noqa: E402
from rfmp_rl.checkpoint import load_checkpoint  # noqa: E402
from rfmp_rl.data import DemonstrationStore  # noqa: E402
from rfmp_rl.onnx_export import (  # noqa: E402
    EXPORT_PRECISIONS,
    calibration_inputs,
    export_onnx,
)
from rfmp_rl.solvers import SolverConfig  # noqa: E402


def store_calibration(model, path: str, windows: int, nfe: int = 1) -> list:
    """Calibration inputs from a saved store: the policy's observation fields (concatenated in
    the metadata order) and cameras, as training windows, with the prior noise of a graph at
    ``nfe``."""
    cfg = model.cfg
    store = DemonstrationStore.load(path)
    fields = [name for name, _ in cfg.obs_keys]
    concat = None if fields in ([], [keys.OBSERVATION]) else {keys.OBSERVATION: fields}
    rb = store.replay_buffer(
        cfg.horizon,
        observation_keys=[keys.OBSERVATION] if cfg.obs_dim > 0 else [],
        camera_keys=list(cfg.cameras),
        concat=concat,
        obs_horizon=cfg.obs_horizon,
        batch_size=windows,
        generator=torch.Generator().manual_seed(0),
    )
    return calibration_inputs(model, rb.sample(), nfe=nfe)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--checkpoint", required=True, help="checkpoint written by training")
    parser.add_argument("--nfe", type=int, default=None,
                        help="function evaluations, unrolled (default: the checkpoint's)")
    parser.add_argument("--t-end", "--horizon", dest="t_end", type=float, default=None,
                        help="integration end time T, may exceed 1 (default: the checkpoint's; "
                        "--horizon is the former name)")
    parser.add_argument("--method", default=None,
                        help="euler | euler_projx | midpoint | rk4 (default: the checkpoint's)")
    parser.add_argument(
        "--schedule",
        default=None,
        help="uniform | srfmp (default: srfmp for SRFMP, uniform for RFMP)",
    )
    parser.add_argument("--refine-dt", type=float, default=None, help="SRFMP refinement step")
    parser.add_argument("--out", default=None, help="output .onnx (default: next to checkpoint)")
    parser.add_argument("--opset", type=int, default=18)
    parser.add_argument("--raw-weights", action="store_true", help="export non-EMA weights")
    parser.add_argument("--precision", default="fp32", choices=EXPORT_PRECISIONS,
                        help="the networks' precision in the graph (default fp32)")
    parser.add_argument("--calibration", default=None,
                        help="int8: a DemonstrationStore folder to calibrate on")
    parser.add_argument("--calibration-windows", type=int, default=256,
                        help="int8: observation windows drawn from --calibration")
    parser.add_argument("--max-diff", type=float, default=None,
                        help="parity limit in normalised action units (default per precision)")
    parser.add_argument("--rate", type=float, default=None,
                        help="control rate in Hz written into the metadata (default: the "
                        "checkpoint's)")
    args = parser.parse_args(argv)
    if args.calibration and args.precision != "int8":
        parser.error("--calibration applies to --precision int8 only")

    try:
        model, payload = load_checkpoint(args.checkpoint, use_ema=not args.raw_weights)
    except (FileNotFoundError, ValueError) as err:
        print(f"export failed: {err}", file=sys.stderr)
        return 1
    rate = args.rate if args.rate is not None else payload.get("control_rate_hz")
    if rate is None:
        print(f"export failed: {args.checkpoint} carries no control rate: give the rate the "
              "policy's actions are executed at with --rate HZ", file=sys.stderr)
        return 1
    if not rate > 0:
        print(f"export failed: --rate must be > 0 Hz, got {rate}", file=sys.stderr)
        return 1
    given = {"nfe": args.nfe, "t_end": args.t_end, "method": args.method,
             "schedule": args.schedule, "refine_dt": args.refine_dt}
    try:
        stored = SolverConfig.from_dict(payload.get("solver") or {})
        solver = replace(stored, **{k: v for k, v in given.items() if v is not None})
        solver = solver.resolve(model.cfg.algorithm)
    except ValueError as err:
        print(f"export failed: {err}", file=sys.stderr)
        return 1
    suffix = "" if args.precision == "fp32" else f"_{args.precision}"
    out = (
        Path(args.out)
        if args.out
        else Path(args.checkpoint).with_name(
            f"policy_{payload['algorithm']}_nfe{solver.nfe}{suffix}.onnx")
    )
    try:
        calibration = None
        if args.calibration:
            calibration = store_calibration(model, args.calibration, args.calibration_windows,
                                            solver.nfe)
        report = export_onnx(
            model,
            out,
            solver=solver,
            opset=args.opset,
            atol=args.max_diff,
            precision=args.precision,
            calibration=calibration,
            control_rate_hz=rate,
        )
    except (RuntimeError, ValueError, OSError) as err:
        print(f"export failed: {err}", file=sys.stderr)
        return 1
    print(report.summary())
    return 0


if __name__ == "__main__":
    sys.exit(main())
