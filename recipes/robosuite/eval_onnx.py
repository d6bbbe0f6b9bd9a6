"""Check that the exported ONNX controller of a robosuite checkpoint gets the same closed-loop
success as the PyTorch policy on the same seeds.

    python recipes/robosuite/eval_onnx.py checkpoint=runs/robosuite/<run>/best.pt
    python recipes/robosuite/eval_onnx.py checkpoint=... eval.seeds=10 onnx_nfe=3

The checkpoint is exported at ``onnx_nfe`` (default 1, T = 1) with `rfmp_rl.onnx_export` (its
onnxruntime-vs-PyTorch parity check runs and must pass). The PyTorch reference is eval.py's
sweep at that NFE with deterministic sampling (the prior's mode); the ONNX side runs the deploy
controller (``deploy/rfmp_deploy``: numpy and onnxruntime only, zero prior noise, its action
clipping and safety checks) in a batch-1 env per seed, fed the env's per-step observation keys.
Both use the seeds ``eval.seed_start .. + eval.seeds`` and the step limit ``eval.max_steps``.

Contact-rich episodes can end differently from actions that differ in the sixth decimal, so a
disagreeing seed is not by itself an export fault. The control (``onnx_control=true``, the
default) measures that floor: the PyTorch policy once more, with every executed action shifted
by the export's largest raw difference from PyTorch (``max_raw_diff`` of the parity check,
alternating signs over the action's coordinates), on the same seeds. Seeds on which that shifted
policy and the unshifted one disagree are flipped by numerical noise of the export's size.

Writes policy_nfe<N>.onnx, eval_onnx.md and eval_onnx.csv (seed, torch_success, onnx_success,
and torch_shifted_success with the control) to ``eval.out`` (default
``<checkpoint folder>/eval_onnx``); exits non-zero when the two success rates differ.
"""

from __future__ import annotations

import csv
import statistics
import sys
import time
from collections import Counter
from dataclasses import replace
from pathlib import Path

import hydra
import torch
from omegaconf import DictConfig, OmegaConf
from tensordict.nn import TensorDictModule, TensorDictSequential
from utils import CONTROL_RATE_HZ, check_config, eval_task

from recipes.common import deploy_classes, load_for_eval, run_cli, run_sweep
from rfmp_rl import keys
from rfmp_rl.envs.robosuite import ROBOSUITE_MAX_STEPS
from rfmp_rl.eval.controller import run_controller
from rfmp_rl.eval.parallel import evaluation_env
from rfmp_rl.onnx_export import export_onnx


def run_onnx_controller(onnx_path: Path, task: DictConfig, seeds: list[int]) -> dict:
    """One episode per seed with the deploy controller; per-seed success, step latencies (s) and
    the safety events other than ``clamped`` as ``(seed, Event)``."""
    Controller, Policy = deploy_classes()
    controller = Controller(Policy(str(onnx_path), intra_op_threads=int(task.threads)),
                            deterministic=True)
    fields = [f.key for f in controller.meta.observation_keys]
    cameras = list(controller.meta.cameras)

    def observe(td) -> dict:
        # the env's per-step entries (not its windows): the controller keeps the history
        observation = {k: td[k][0].numpy() for k in fields}
        observation.update({c: td[c][0].permute(1, 2, 0).numpy() for c in cameras})
        return observation

    env_task = eval_task(task)
    rollouts = run_controller(
        controller, lambda seed: evaluation_env(env_task.env_fn, [seed],
                                                **env_task.env_kwargs)[0], seeds,
        int(task.eval.max_steps or ROBOSUITE_MAX_STEPS[task.task]), observe,
        outcome=lambda td: int(td["success"][0, 0]),
    )
    return {"per_seed": [int(v) for v in rollouts.outcomes], "latencies": rollouts.step_seconds,
            "events": [(seed, e) for seed, e in rollouts.events if e.kind != "clamped"]}


def shifted_actor(actor, shift: float):
    """``actor`` with every executed action moved by ``shift``, the sign alternating over the
    action's coordinates (+, -, +, ...): the control of `evaluate_onnx`."""
    def move(action: torch.Tensor) -> torch.Tensor:
        signs = torch.ones(action.shape[-1], dtype=action.dtype, device=action.device)
        signs[1::2] = -1
        return action + shift * signs

    return TensorDictSequential(actor, TensorDictModule(move, in_keys=[keys.ACTION],
                                                        out_keys=[keys.ACTION]))


def _seeds(differ: list[int]) -> str:
    return f" ({', '.join(map(str, differ))})" if differ else ""


def write_report(out: Path, seeds: list[int], torch_row: dict, onnx: dict, differ: list[int],
                 report, title: str, command: str, control: dict | None = None) -> Path:
    """eval_onnx.csv (one row per seed) and eval_onnx.md; returns the md path. ``control``:
    the shifted PyTorch policy's ``per_seed`` successes and its ``shift``."""
    out.mkdir(parents=True, exist_ok=True)
    torch_ok, onnx_ok = torch_row["per_seed"], onnx["per_seed"]
    columns = [seeds, torch_ok, onnx_ok] + ([control["per_seed"]] if control else [])
    with open(out / "eval_onnx.csv", "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(["seed", "torch_success", "onnx_success"]
                        + (["torch_shifted_success"] if control else []))
        writer.writerows(zip(*columns, strict=True))
    n = len(seeds)
    torch_rate, onnx_rate = sum(torch_ok) / n, sum(onnx_ok) / n
    ms = [t * 1e3 for t in onnx["latencies"]] or [float("nan")]
    kinds = Counter(e.kind for _, e in onnx["events"])
    nfe, t_end, t_reached = torch_row["nfe"], torch_row["t_end"], torch_row["t_reached"]
    seed_range = f"{seeds[0]}-{seeds[-1]}"
    lines = [
        f"## ONNX controller vs PyTorch: {title}", "", f"Command: `{command}`", "",
        "| policy | NFE | T asked | T reached | success | successes | seeds |",
        "|---|---|---|---|---|---|---|",
        f"| PyTorch (deterministic: prior mode) | {nfe} | {t_end:g} | {t_reached:.2f} | "
        f"{torch_rate:.2f} | {sum(torch_ok)}/{n} | {seed_range} |",
        f"| ONNX controller (rfmp_deploy, zero noise) | {nfe} | {t_end:g} | {t_reached:.2f} | "
        f"{onnx_rate:.2f} | {sum(onnx_ok)}/{n} | {seed_range} |",
    ]
    if control:
        shifted = control["per_seed"]
        lines.append(f"| control: PyTorch, actions shifted by ±{control['shift']:.2g} | {nfe} | "
                     f"{t_end:g} | {t_reached:.2f} | {sum(shifted) / n:.2f} | "
                     f"{sum(shifted)}/{n} | {seed_range} |")
    lines += [
        "",
        f"- Seeds where PyTorch and the ONNX controller disagree: {len(differ)} of {n}"
        + _seeds(differ),
    ]
    if control:
        flipped = [s for s, a, b in zip(seeds, torch_ok, control["per_seed"], strict=True)
                   if a != b]
        lines.append(
            f"- Control: seeds where PyTorch and PyTorch with every executed action shifted by "
            f"±{control['shift']:.2g} (the export's largest raw difference) disagree: "
            f"{len(flipped)} of {n}{_seeds(flipped)}")
    lines += [
        f"- Controller step latency: median {statistics.median(ms):.2f} ms, max {max(ms):.2f} ms "
        f"over {len(onnx['latencies'])} steps",
        "- Safety events (other than clamped): "
        + (", ".join(f"{k} x{v}" for k, v in sorted(kinds.items())) if kinds else "none"),
        f"- Export parity ({report.path.name}): max |onnxruntime - torch| = "
        f"{report.max_abs_diff:.3g} in normalised action units (limit 1e-4; "
        f"{report.max_raw_diff:.3g} raw), max | |q| - 1 | = {report.max_sphere_error:.3g} "
        f"(limit 1e-5); batch-1 latency onnxruntime {report.onnx_latency_ms:.2f} ms, torch "
        f"eager {report.torch_latency_ms:.2f} ms",
    ]
    for seed, e in onnx["events"][:20]:
        lines.append(f"  - seed {seed}, step {e.step}: {e.kind}: {e.message}")
    if len(onnx["events"]) > 20:
        lines.append(f"  - ... {len(onnx['events']) - 20} more")
    (out / "eval_onnx.md").write_text("\n".join(lines) + "\n")
    return out / "eval_onnx.md"


def evaluate_onnx(cfg: DictConfig, command: str | None = None) -> dict:
    """Export ``cfg.checkpoint``, run PyTorch and the ONNX controller on the same seeds and
    write the tables; returns ``{"torch", "onnx", "differ", "md", "onnx_path"}`` (success
    rates, disagreeing seeds, paths)."""
    if not cfg.checkpoint:
        raise SystemExit("eval_onnx.py: give the checkpoint: "
                         "checkpoint=runs/robosuite/<run>/best.pt")
    if not Path(cfg.checkpoint).is_file():
        raise SystemExit(f"eval_onnx.py: no such checkpoint: {cfg.checkpoint}")
    model, task, extra, _ = load_for_eval(cfg, check_config)
    nfe, t_end = int(cfg.onnx_nfe), 1.0
    out = Path(cfg.eval.out) if cfg.eval.out else Path(cfg.checkpoint).parent / "eval_onnx"
    if command is None:
        command = "python recipes/robosuite/eval_onnx.py " + " ".join(sys.argv[1:])

    try:
        report = export_onnx(model, out / f"policy_nfe{nfe}.onnx", nfe, t_end=t_end,
                             control_rate_hz=CONTROL_RATE_HZ)
    except (RuntimeError, ValueError) as err:
        raise SystemExit(f"eval_onnx.py: export failed: {err}") from err
    print(report.summary())

    ref = OmegaConf.merge(task, {"eval": {"sampling": "deterministic", "nfes": [nfe],
                                          "t_ends": [t_end], "time_table": []}})
    seeds = list(range(int(ref.eval.seed_start), int(ref.eval.seed_start) + int(ref.eval.seeds)))
    base = eval_task(ref, model)
    (row,) = run_sweep(model, ref, base)
    torch_row = {**row, "per_seed": [int(v) for v in row["per_seed"]["success"]]}
    print(f"  PyTorch NFE={nfe} (deterministic): success {torch_row['success']:.2f} "
          f"({torch_row['seconds']:.0f} s)")
    start = time.perf_counter()
    onnx = run_onnx_controller(report.path, ref, seeds)
    onnx_rate = sum(onnx["per_seed"]) / len(seeds)
    print(f"  ONNX    NFE={nfe} (zero noise):    success {onnx_rate:.2f} "
          f"({time.perf_counter() - start:.0f} s)")
    control = None
    if cfg.get("onnx_control", True):
        shift = float(report.max_raw_diff)
        (shifted,) = run_sweep(model, ref, replace(
            base, make_actor=lambda m, n, t: shifted_actor(base.make_actor(m, n, t), shift)))
        control = {"shift": shift, "per_seed": [int(v) for v in shifted["per_seed"]["success"]]}
        print(f"  PyTorch NFE={nfe}, actions shifted by ±{shift:.2g}: success "
              f"{shifted['success']:.2f}")

    title = (f"{task.task} {task.obs} {task.action_space}: {task.algo} "
             f"({task.model.unet_preset}, step {extra.get('step')}, "
             f"{extra.get('train_minutes', float('nan')):.0f} min training)")
    differ = [s for s, a, b in zip(seeds, torch_row["per_seed"], onnx["per_seed"], strict=True)
              if a != b]
    md = write_report(out, seeds, torch_row, onnx, differ, report, title, command, control)
    print(md.read_text())
    return {"torch": sum(torch_row["per_seed"]) / len(seeds), "onnx": onnx_rate,
            "differ": differ, "md": md, "onnx_path": report.path,
            "control": None if control is None else control["per_seed"]}


@hydra.main(config_path=".", config_name="config", version_base="1.3")
def main(cfg: DictConfig) -> None:
    result = evaluate_onnx(cfg)
    if result["torch"] != result["onnx"]:
        print(f"eval_onnx.py: success rates differ: PyTorch {result['torch']:.2f}, ONNX "
              f"{result['onnx']:.2f}", file=sys.stderr)
        sys.exit(1)


if __name__ == "__main__":
    run_cli(main)  # settings of earlier versions renamed (printed)
