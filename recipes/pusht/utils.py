"""Factories for the Push-T recipes (TorchRL sota-implementations style): data, model, loss,
optimiser, logger, env, policy, and the evaluation sweep."""

from __future__ import annotations

import csv
import functools
import math
import sys
import time
from pathlib import Path

import torch
from omegaconf import DictConfig, OmegaConf
from torchrl.envs.utils import ExplorationType, set_exploration_type

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # recipes/: the shared pieces

from common import (  # noqa: E402
    ALGOS,
    ROOT,
    build_training,
    check_runtime_config,
    deploy_classes,
    end_time,
    eval_model,
    exit_code,
    fit,
    load_for_eval,
    make_actor,
    resolve,
    split_stores,
    start_run,
    sweep_settings,
)

from rfmp_rl import keys  # noqa: E402
from rfmp_rl.data import DemonstrationStore, read_dp_zarr  # noqa: E402
from rfmp_rl.envs.pusht import (  # noqa: E402
    PUSHT_SUCCESS_COVERAGE,
    make_pusht_env,
    pusht_episodes,
)
from rfmp_rl.eval.metrics import jerk  # noqa: E402
from rfmp_rl.eval.parallel import FlatBatch, evaluation_env, flatten_workers  # noqa: E402
from rfmp_rl.modules import ModelConfig, build_model  # noqa: E402
from rfmp_rl.objectives import LossConfig  # noqa: E402

__all__ = ["ROOT", "build_training", "resolve", "end_time", "fit", "load_for_eval", "start_run",
           "eval_model", "exit_code", "deploy_classes"]

CONTROL_DT = 0.1  # Push-T runs at 10 Hz
CONTROL_RATE_HZ = 1.0 / CONTROL_DT  # stored in checkpoints; the ONNX metadata's


def check_config(cfg: DictConfig) -> None:
    if cfg.algo not in ALGOS:
        raise ValueError(f"algo must be one of {sorted(ALGOS)}, got {cfg.algo!r}")
    if cfg.obs not in ("state", "image"):
        raise ValueError(f"obs must be 'state' or 'image', got {cfg.obs!r}")
    if cfg.space not in ("euclidean", "sphere"):
        raise ValueError(f"space must be 'euclidean' or 'sphere', got {cfg.space!r}")
    train = cfg.get("train", {})
    if train.get("select_by", "val_loss") not in ("val_loss", "rollout"):
        raise ValueError(f"train.select_by must be 'val_loss' or 'rollout', got "
                         f"{train.select_by!r}")
    check_runtime_config(cfg)
    if train.get("select_by") == "rollout":
        chosen = range(int(train.select_seed_start),
                       int(train.select_seed_start) + int(train.select_seeds))
        tested = range(int(cfg.eval.seed_start), int(cfg.eval.seed_start) + int(cfg.eval.seeds))
        if len(chosen) < 1 or (chosen.start < tested.stop and tested.start < chosen.stop):
            raise ValueError(
                f"train.select_seeds/select_seed_start give seeds {chosen.start}-{chosen.stop - 1}"
                f", which must be at least one and must not overlap the evaluation seeds "
                f"{tested.start}-{tested.stop - 1} (eval.seed_start, eval.seeds)")


# ----- data ------------------------------------------------------------------------------------
def make_stores(cfg: DictConfig) -> tuple[DemonstrationStore, DemonstrationStore]:
    """Train and validation stores (the last ``data.val_episodes`` episodes are held out)."""
    path = resolve(cfg.data.path)
    raw, source = _read_pusht(str(path), cfg.obs == "image")
    episodes = pusht_episodes(raw, cfg.obs, cfg.space)
    return split_stores(episodes, source, cfg.data, f"pusht/{cfg.obs}/{cfg.space}")


@functools.lru_cache(maxsize=1)
def _read_pusht(path: str, images: bool):
    """The zarr is read once per process (tests and sweeps build several stores from it)."""
    names = ["state", "keypoint", "action"] + (["img"] if images else [])
    return read_dp_zarr(path, names)


def make_replay_buffer(store: DemonstrationStore, cfg: DictConfig, seed: int):
    return store.replay_buffer(
        cfg.horizon,
        observation_keys=[keys.OBSERVATION],
        camera_keys=[keys.PIXELS] if cfg.obs == "image" else [],
        obs_horizon=cfg.obs_horizon,
        batch_size=cfg.train.batch_size,
        generator=torch.Generator().manual_seed(seed),
    )


# ----- model -----------------------------------------------------------------------------------
def make_model_config(cfg: DictConfig) -> ModelConfig:
    sphere = cfg.space == "sphere"
    points = 10 if cfg.obs == "state" else 1
    point_dim = 3 if sphere else 2
    if cfg.obs == "state":
        obs_keys = [["keypoints", 9 * point_dim], ["agent_pos", point_dim]]
    else:
        obs_keys = [["agent_pos", point_dim]]
    algorithm = ALGOS[cfg.algo]
    return ModelConfig(
        algorithm=algorithm,
        action_manifold="S2" if sphere else "R2",
        horizon=cfg.horizon,
        action_steps=cfg.action_steps,
        obs_horizon=cfg.obs_horizon,
        obs_dim=points * point_dim,
        obs_manifold=" x ".join(["S2"] * points) if sphere else None,
        obs_keys=obs_keys,
        cameras={keys.PIXELS: [3, 96, 96]} if cfg.obs == "image" else {},
        crop_shape=[84, 84] if cfg.obs == "image" else None,
        unet_preset=cfg.preset,
        down_dims=list(cfg.down_dims) if cfg.down_dims else None,
        prior_sphere=cfg.prior,
        prior_scale=cfg.prior_scale,
        prior_repeat=cfg.prior_repeat,
        lambda_x=cfg.lambda_x,
    )


def make_loss_config(cfg: DictConfig) -> LossConfig:
    """The loss's training-time options (`rfmp_rl.objectives.LossConfig`) from the flat keys."""
    algorithm = ALGOS[cfg.algo]
    return LossConfig(
        time_max=cfg.time_max if algorithm == "srfmp" else 1.0,
        t0_fraction=cfg.t0_fraction if algorithm != "ddim" else 0.0,
        lambda_x=cfg.lambda_x,
        lambda_tau=cfg.lambda_tau,
    )


def make_model(cfg: DictConfig, store: DemonstrationStore):
    """The network, with its normalisers fitted to the training store."""
    model = build_model(make_model_config(cfg))
    model.action_normalizer.set_stats(*store.stats(keys.ACTION))
    if model.cfg.obs_dim > 0:
        model.obs_normalizer.set_stats(*store.stats(keys.OBSERVATION))
    return model


# ----- acting ----------------------------------------------------------------------------------
def make_env(cfg: DictConfig, seeds: list[int], max_steps: int, noise_dim: int | None = None):
    """The evaluation env over ``seeds``: ``(env, number of seeds)``, stepped by ``eval.workers``
    processes (TorchRL ``ParallelEnv``) when more than one; with ``noise_dim`` each episode's
    prior noise comes from its own seed (`rfmp_rl.eval.parallel.PriorNoise`)."""
    return evaluation_env(
        make_pusht_env, seeds, int(cfg.eval.get("workers", 1)), noise_dim=noise_dim,
        noise_seed=int(cfg.seed), obs_type=cfg.obs, space=cfg.space, max_steps=max_steps,
        obs_horizon=cfg.obs_horizon,
    )


@torch.no_grad()
def evaluate(model, cfg: DictConfig, nfe: int, t_end: float) -> dict:
    """One closed-loop evaluation over ``eval.seeds`` seeds in one batched env (over
    ``eval.workers`` processes); each episode's prior noise comes from its own seed, so per-seed
    results do not depend on the number of workers."""
    seeds = list(range(int(cfg.eval.seed_start), int(cfg.eval.seed_start) + int(cfg.eval.seeds)))
    deterministic = cfg.eval.sampling == "deterministic"
    env, _ = make_env(cfg, seeds, int(cfg.eval.max_steps),
                      None if deterministic else int(model.noise_dim))
    actor = FlatBatch(make_actor(model, nfe, t_end, camera_keys={keys.PIXELS: keys.PIXELS_WINDOW}))
    mode = ExplorationType.DETERMINISTIC if deterministic else ExplorationType.RANDOM
    torch.manual_seed(int(cfg.seed))
    start = time.perf_counter()
    try:
        with set_exploration_type(mode):
            out = env.rollout(int(cfg.eval.max_steps), actor, break_when_any_done=False,
                              break_when_all_done=True)
    finally:
        env.close()  # worker processes end even when a rollout fails
    out = flatten_workers(out, len(seeds))
    seconds = time.perf_counter() - start
    score = out["next", "max_coverage"][:, -1, 0]  # (N,)
    success = out["next", "success"][:, -1, 0].float()
    steps = out["next", "step_count"][:, -1, 0]  # executed steps per env
    actions = out[keys.ACTION]  # (N, L, D)
    jerks, manifold_err = [], 0.0
    for i in range(len(seeds)):
        executed = actions[i, : int(steps[i])]
        if executed.shape[0] >= 4:
            jerks.append(float(jerk(executed.double(), CONTROL_DT)))
        if cfg.space == "sphere":
            manifold_err = max(manifold_err, float((executed.norm(dim=-1) - 1).abs().max()))
    return {
        "algo": cfg.algo,
        "nfe": nfe,
        "t_end": t_end,
        "t_reached": end_time(model, nfe, t_end),
        "score": float(score.mean()),
        "score_std": float(score.std()),
        # Diffusion Policy's metric: the maximum clipped reward min(coverage / 0.95, 1).
        "dp_score": float((score / PUSHT_SUCCESS_COVERAGE).clamp(max=1.0).mean()),
        "success": float(success.mean()),
        "jerk": float(torch.tensor(jerks).mean()) if jerks else float("nan"),
        "manifold_err": manifold_err if cfg.space == "sphere" else float("nan"),
        "env_steps": int(steps.sum()),
        "seconds": seconds,
        "seeds": f"{seeds[0]}-{seeds[-1]}",
    }


def selection_score(cfg: DictConfig):
    """``train.select_by=rollout``: the function `fit` calls on the EMA model at every
    validation, the mean max coverage over the selection seeds at ``train.select_nfe`` /
    ``select_t_end`` (seeds disjoint from the evaluation ones, `check_config`); else None."""
    if cfg.train.get("select_by", "val_loss") != "rollout":
        return None
    chosen = OmegaConf.merge(cfg, {"eval": {"seeds": cfg.train.select_seeds,
                                            "seed_start": cfg.train.select_seed_start}})

    def score(model) -> float:
        return evaluate(model, chosen, int(cfg.train.select_nfe),
                        float(cfg.train.select_t_end))["score"]

    return score


def sweep(model, cfg: DictConfig, progress=None) -> list[dict]:
    """Every NFE x end time T of ``cfg.eval`` plus the ``eval.time_table`` pairs (DDIM: every
    NFE at T = 1)."""
    rows = []
    for nfe, t_end in sweep_settings(model, cfg.eval.nfes, cfg.eval.t_ends,
                                     cfg.eval.get("time_table")):
        row = evaluate(model, cfg, nfe, t_end)
        rows.append(row)
        if progress is not None:
            progress(row)
    return rows


def write_tables(
    rows: list[dict], out_dir: Path, title: str, command: str, time_table=None
) -> Path:
    """CSV + markdown table + plots (score vs NFE per T; score vs T per NFE)."""
    out_dir.mkdir(parents=True, exist_ok=True)
    with open(out_dir / "eval.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    sphere = any(not math.isnan(float(r["manifold_err"])) for r in rows)
    unit = "S^2 coords/s^3" if sphere else "px/s^3"  # the executed actions' own units
    lines = [f"## {title}", "", f"Command: `{command}`", "",
             "| algo | NFE | T | T reached | score (max coverage) | DP score | success | "
             f"jerk ({unit}) | on-S^2 err | env steps | s |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        err = "-" if math.isnan(r["manifold_err"]) else f"{r['manifold_err']:.1e}"
        lines.append(
            f"| {r['algo']} | {r['nfe']} | {r['t_end']:.1f} | {r['t_reached']:.2f} | "
            f"{r['score']:.3f} ± {r['score_std']:.3f} | {r['dp_score']:.3f} | {r['success']:.2f} | "
            f"{r['jerk']:.3g} | "
            f"{err} | {r['env_steps']} | {r['seconds']:.0f} |"
        )
    pairs = [(int(n), float(t)) for n, t in (time_table or [])]
    chosen = [r for p in pairs for r in rows if (r["nfe"], r["t_end"]) == p]
    if chosen and rows[0]["algo"] != "dp":
        lines += ["", "Integration time (the paper's table: " + ", ".join(
            f"NFE={n} at T={t:g}" for n, t in pairs) + ")", "",
            "| algo | " + " | ".join(f"T={r['t_end']:g} (NFE {r['nfe']})" for r in chosen) + " |",
            "|---|" + "---|" * len(chosen),
            f"| {rows[0]['algo']} | " + " | ".join(f"{r['score']:.3f}" for r in chosen) + " |"]
    (out_dir / "eval.md").write_text("\n".join(lines) + "\n")
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, axes = plt.subplots(1, 2, figsize=(9, 3.5))
        for t_end in sorted({r["t_end"] for r in rows}):
            sel = [r for r in rows if r["t_end"] == t_end]
            axes[0].plot([r["nfe"] for r in sel], [r["score"] for r in sel], "o-",
                         label=f"T={t_end:g}")
        axes[0].set(xlabel="NFE", ylabel="mean max coverage", title="score vs NFE", ylim=(0, 1))
        axes[0].legend()
        for nfe in sorted({r["nfe"] for r in rows}):
            sel = [r for r in rows if r["nfe"] == nfe]
            axes[1].plot([r["t_end"] for r in sel], [r["score"] for r in sel], "o-",
                         label=f"NFE={nfe}")
        axes[1].set(xlabel="end time T", title="score vs T", ylim=(0, 1))
        axes[1].legend()
        fig.suptitle(title)
        fig.tight_layout()
        fig.savefig(out_dir / "eval.png", dpi=100)
        plt.close(fig)
    except ImportError:  # pragma: no cover - matplotlib is a dependency
        pass
    return out_dir / "eval.md"
