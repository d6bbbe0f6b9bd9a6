"""Run a Push-T checkpoint's exported ONNX controllers in closed loop: float32 beside the
reduced-precision exports (fp16, int8), against the PyTorch policy, on the same seeds.

    python recipes/pusht/eval_onnx.py checkpoint=runs/pusht/<run>/best.pt
    python recipes/pusht/eval_onnx.py checkpoint=... onnx_precisions=[fp32,int8] eval.seeds=10

Each precision in ``onnx_precisions`` is exported at ``onnx_nfe`` (T = 1) with
`rfmp_rl.onnx_export` (int8 calibrated on 256 observation windows of the training data) and run by
the torch-free deploy controller (``deploy/rfmp_deploy``, zero prior noise: the prior's mode) in a
batch-1 env per seed. The PyTorch reference is the same policy with deterministic sampling in
eval.py's batched env. Seeds: ``eval.seed_start .. + eval.seeds``; score: the maximum coverage over
the episode, as in eval.py.

Writes policy_nfe<N>_<precision>.onnx, eval_onnx.md and eval_onnx.csv (one row per seed) to
``eval.out`` (default ``<checkpoint folder>/eval_onnx``).
"""

from __future__ import annotations

import csv
import statistics
import sys
from collections import Counter
from pathlib import Path

import hydra
import numpy as np
from omegaconf import DictConfig, OmegaConf
from utils import CONTROL_RATE_HZ, check_config, eval_task, make_replay_buffer, make_stores

from recipes.common import deploy_classes, eval_config, load_for_eval, run_cli
from rfmp_rl import keys
from rfmp_rl.eval import evaluate, seed_mean
from rfmp_rl.eval.controller import run_controller, split_fields
from rfmp_rl.eval.parallel import evaluation_env
from rfmp_rl.onnx_export import calibration_inputs, export_onnx


def run_onnx(path: Path, task: DictConfig, seeds: list[int]):
    """`ControllerRollouts` of the deploy controller on ``path``: max coverage per seed."""
    Controller, Policy = deploy_classes()
    controller = Controller(Policy(str(path), intra_op_threads=int(task.threads)),
                            deterministic=True)
    fields = controller.meta.observation_keys

    def observe(td) -> dict:
        # per-step entries: the controller keeps its own observation window
        observation = split_fields(td[keys.OBSERVATION][0].numpy(), fields)
        if task.obs == "image":
            observation[keys.PIXELS] = td[keys.PIXELS][0].permute(1, 2, 0).numpy()
        return observation

    env_task = eval_task(task)
    return run_controller(
        controller, lambda seed: evaluation_env(env_task.env_fn, [seed],
                                                **env_task.env_kwargs)[0], seeds,
        int(task.eval.max_steps), observe, outcome=lambda td: float(td["max_coverage"][0, 0]),
    )


def write_report(out: Path, seeds: list[int], rows: list[dict], torch_row: dict, title: str,
                 command: str) -> Path:
    """eval_onnx.csv (seed x precision scores) and eval_onnx.md; returns the md path."""
    out.mkdir(parents=True, exist_ok=True)
    with open(out / "eval_onnx.csv", "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(["seed"] + [f"onnx_{r['precision']}" for r in rows])
        writer.writerows(zip(seeds, *(r["rollouts"].outcomes for r in rows), strict=True))
    n, nfe = len(seeds), rows[0]["nfe"]
    base = next((r for r in rows if r["precision"] == "fp32"), None)
    lines = [
        f"## Exported controllers in closed loop: {title}", "", f"Command: `{command}`", "",
        f"Seeds {seeds[0]}-{seeds[-1]} ({n}); NFE {nfe}, T = 1 (reached "
        f"{torch_row['t_reached']:.2f}); deterministic "
        "(the prior's mode). Score: mean maximum coverage over the seeds.", "",
        "| policy | precision | NFE | T | score | change vs ONNX fp32 | seeds differing by > 0.05 "
        "| file (MB) | max abs diff vs PyTorch fp32 (normalised) | controller step median / max "
        "(ms) |",
        "|---|---|---|---|---|---|---|---|---|---|",
        f"| PyTorch (eval.py env) | fp32 | {nfe} | 1 | {torch_row['score']:.3f} | | | | | |",
    ]
    for r in rows:
        outcomes = np.array(r["rollouts"].outcomes)
        change = differ = ""
        if base is not None:
            ref = np.array(base["rollouts"].outcomes)
            change = f"{outcomes.mean() - ref.mean():+.3f}"
            differ = str(int((np.abs(outcomes - ref) > 0.05).sum()))
        ms = [t * 1e3 for t in r["rollouts"].step_seconds]
        lines.append(
            f"| ONNX controller | {r['precision']} | {nfe} | 1 | {outcomes.mean():.3f} | {change} "
            f"| {differ} | {r['path'].stat().st_size / 1e6:.1f} | {r['report'].max_abs_diff:.3g} "
            f"| {statistics.median(ms):.2f} / {max(ms):.2f} |")
    events = Counter(e.kind for r in rows for _, e in r["rollouts"].events if e.kind != "clamped")
    lines += ["", "Controller events other than clamped: "
              + (", ".join(f"{k} x{v}" for k, v in sorted(events.items())) if events else "none")]
    (out / "eval_onnx.md").write_text("\n".join(lines) + "\n")
    return out / "eval_onnx.md"


def evaluate_onnx(cfg: DictConfig, command: str | None = None) -> dict:
    """Export each precision, run it and the PyTorch policy on the same seeds, write the
    tables; returns ``{"torch": score, "<precision>": score, ..., "md": path}``."""
    model, task, extra, _ = load_for_eval(cfg, check_config)
    out = Path(cfg.eval.out) if cfg.eval.out else Path(cfg.checkpoint).parent / "eval_onnx"
    command = command or "python recipes/pusht/eval_onnx.py " + " ".join(sys.argv[1:])
    nfe = int(cfg.onnx_nfe)
    task = OmegaConf.merge(task, {"eval": {"sampling": "deterministic"}})
    seeds = list(range(int(task.eval.seed_start), int(task.eval.seed_start) + int(task.eval.seeds)))
    calibration = None
    if "int8" in cfg.onnx_precisions:
        train_store, _ = make_stores(task)
        samples = make_replay_buffer(train_store, task, seed=int(task.seed)).sample(256)
        calibration = calibration_inputs(model.cpu(), samples, nfe=nfe)
    rows = []
    for precision in cfg.onnx_precisions:
        path = out / f"policy_nfe{nfe}_{precision}.onnx"
        try:
            report = export_onnx(model.cpu(), path, nfe, precision=precision,
                                 calibration=calibration if precision == "int8" else None,
                                 control_rate_hz=CONTROL_RATE_HZ)
        except (RuntimeError, ValueError) as err:
            raise SystemExit(f"eval_onnx.py: {precision} export failed: {err}") from err
        print(report.summary())
        rollouts = run_onnx(path, task, seeds)
        print(f"  ONNX {precision}: score {rollouts.mean:.3f}")
        rows.append({"precision": precision, "nfe": nfe, "path": path, "report": report,
                     "rollouts": rollouts})
    env_task = eval_task(task)
    result = evaluate(env_task.env_fn, model, lambda n, t: env_task.make_actor(model, n, t), nfe,
                      1.0, eval_config(task), env_task.metrics, seed=int(task.seed),
                      env_kwargs=env_task.env_kwargs)
    torch_row = {"score": seed_mean(result.values["score"]), "t_reached": result.t_reached}
    print(f"  PyTorch (deterministic): score {torch_row['score']:.3f}")
    title = (f"Push-T {task.obs} {task.space}: {task.algo} ({task.model.unet_preset}, step "
             f"{extra.get('step')})")
    md = write_report(out, seeds, rows, torch_row, title, command)
    print(md.read_text())
    return {"torch": torch_row["score"], "md": md,
            **{r["precision"]: r["rollouts"].mean for r in rows}}


@hydra.main(config_path=".", config_name="config", version_base="1.3")
def main(cfg: DictConfig) -> None:
    evaluate_onnx(cfg)


if __name__ == "__main__":
    run_cli(main)  # settings of earlier versions renamed (printed)
