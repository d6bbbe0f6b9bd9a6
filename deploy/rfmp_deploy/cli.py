"""Command line: check a model on the robot PC, or drive a robot with it.

    PYTHONPATH=deploy python -m rfmp_deploy --model policy.onnx --check
    PYTHONPATH=deploy:. python -m rfmp_deploy --model policy.onnx --robot my_arm:make_robot

``--check`` loads the model (validating its metadata against the graph), prints the metadata
summary, runs 20 inferences with random valid inputs and prints the latency (median, p95)
against the control period. ``--robot module:factory`` imports ``factory`` (a callable taking
no arguments and returning a `RobotInterface`) and runs the fixed-rate loop.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys
import time
from collections.abc import Sequence

import numpy as np

from rfmp_deploy.controller import Controller
from rfmp_deploy.loop import RobotInterface, run
from rfmp_deploy.policy import Policy

__all__ = ["check", "main"]


def check(policy: Policy, runs: int = 20, seed: int = 0, rate_hz: float | None = None
          ) -> dict[str, float]:
    """Time ``runs`` batch-1 inferences on random valid inputs (after one warm-up call).

    Args:
        rate_hz: the control rate the robot will run at (default: the model's); the period
            the latency is judged against.

    Returns:
        ``{"median_ms", "p95_ms", "max_ms", "period_ms"}``.

    Raises:
        RuntimeError: when the policy returns non-finite actions.
    """
    rng = np.random.default_rng(seed)
    policy(**policy.random_inputs(1, rng))  # warm-up: first call allocates
    times = []
    for _ in range(runs):
        inputs = policy.random_inputs(1, rng)
        start = time.perf_counter()
        action = policy(**inputs)
        times.append(time.perf_counter() - start)
        if not np.all(np.isfinite(action)):
            raise RuntimeError(f"{policy.path}: non-finite action for random valid inputs")
    ms = np.asarray(times) * 1e3
    return {
        "median_ms": float(np.median(ms)),
        "p95_ms": float(np.percentile(ms, 95)),
        "max_ms": float(ms.max()),
        "period_ms": (1.0 / rate_hz if rate_hz else policy.meta.period) * 1e3,
    }


def _advice(t: dict[str, float]) -> str:
    if t["p95_ms"] > t["period_ms"]:
        return "SLOWER than the control period: use --async (inference in the background)"
    if t["p95_ms"] > t["period_ms"] / 2:
        return "OK, but over half the period: --async is recommended"
    return "OK"


def _load_robot(spec: str) -> RobotInterface:
    module_name, _, attr = spec.partition(":")
    if not module_name or not attr:
        raise SystemExit(f"--robot expects module:factory, got {spec!r}")
    robot = getattr(importlib.import_module(module_name), attr)()
    if not isinstance(robot, RobotInterface):
        raise SystemExit(f"{spec}() returned {type(robot).__name__}, which has no "
                         f"read_observation/send_action")
    return robot


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m rfmp_deploy", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--model", required=True, help="the exported .onnx policy")
    parser.add_argument("--check", action="store_true",
                        help="print the metadata and inference latency, then exit")
    parser.add_argument("--runs", type=int, default=20, help="timed inferences for --check")
    parser.add_argument("--robot", help="module:factory returning a RobotInterface")
    parser.add_argument("--rate", type=float, help="control rate in Hz (default: the model's)")
    parser.add_argument("--max-steps", type=int, help="stop after this many steps")
    parser.add_argument("--async", dest="asynchronous", action="store_true", default=None,
                        help="run inference in a background thread (the default when p95 "
                             "inference exceeds half the control period)")
    parser.add_argument("--sync", dest="asynchronous", action="store_false",
                        help="run inference in the control loop, whatever its latency")
    parser.add_argument("--deterministic", action="store_true",
                        help="feed zero noise (the policy's deterministic mode)")
    parser.add_argument("--seed", type=int, default=0, help="noise generator seed")
    parser.add_argument("--threads", type=int, help="onnxruntime intra-op threads")
    parser.add_argument("--provider", action="append",
                        help="onnxruntime execution provider (repeatable; default CPU)")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(levelname)s %(message)s")

    try:
        policy = Policy(args.model, providers=tuple(args.provider or ["CPUExecutionProvider"]),
                        intra_op_threads=args.threads)
    except (FileNotFoundError, ValueError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    print(policy.meta.summary())
    print(f"providers:    {', '.join(policy.providers)}")
    if args.rate is not None and not args.rate > 0:
        parser.error(f"--rate must be positive, got {args.rate}")
    if args.check:
        t = check(policy, runs=args.runs, seed=args.seed, rate_hz=args.rate)
        print(f"latency:      median {t['median_ms']:.2f} ms, p95 {t['p95_ms']:.2f} ms, "
              f"max {t['max_ms']:.2f} ms over {args.runs} runs at batch 1 "
              f"(period {t['period_ms']:.1f} ms: {_advice(t)})")
        return 0
    if not args.robot:
        parser.error("pass --check, or --robot module:factory to drive a robot")
    robot = _load_robot(args.robot)
    asynchronous = args.asynchronous
    if asynchronous is None:  # neither --async nor --sync: decide from the measured latency
        t = check(policy, runs=10, seed=args.seed, rate_hz=args.rate)
        asynchronous = t["p95_ms"] > t["period_ms"] / 2
        print(f"inference p95 {t['p95_ms']:.2f} ms, control period {t['period_ms']:.1f} ms: "
              + ("over half the period, so inference runs asynchronously (--sync to keep it in "
                 "the loop)" if asynchronous else "synchronous inference (--async to change)"))
    with Controller(policy, seed=args.seed, deterministic=args.deterministic or None,
                    asynchronous=asynchronous, control_rate_hz=args.rate) as controller:
        try:
            stats = run(controller, robot, rate_hz=args.rate, max_steps=args.max_steps,
                        stop=lambda: bool(getattr(robot, "done", False)))
        except KeyboardInterrupt:
            print("interrupted")
            return 130
    print(stats.summary())
    print("events:", dict(controller.event_counts) or "none")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
