"""The Push-T task for the recipes (TorchRL sota-implementations style): the data (Diffusion
Policy's zarr as demonstration stores and replay buffers), the model's task-derived settings, the
evaluation env and the task's figures (maximum coverage, Diffusion Policy's score, success, jerk,
distance of the actions from S^2), with the paper's Push-T figures beside them."""

from __future__ import annotations

import functools
from dataclasses import replace

import torch
from omegaconf import DictConfig

from recipes import paper
from recipes.common import (
    TaskEval,
    check_algo,
    check_runtime_config,
    eval_config,
    make_actor,
    model_config,
    resolve,
    split_stores,
)
from rfmp_rl import keys
from rfmp_rl.data import DemonstrationStore, read_dp_zarr
from rfmp_rl.envs.pusht import PUSHT_SUCCESS_COVERAGE, make_pusht_env, pusht_episodes
from rfmp_rl.eval import Column, evaluate, seed_max, seed_mean, seed_std
from rfmp_rl.eval.metrics import jerk
from rfmp_rl.modules import ModelConfig, build_model

CONTROL_DT = 0.1  # Push-T runs at 10 Hz
CONTROL_RATE_HZ = 1.0 / CONTROL_DT  # stored in the checkpoints and the ONNX metadata
#: Task choices that define a run besides ``model`` and ``loss`` (a resume may not change them).
TASK_KEYS = ("obs", "space")

#: The paper's Euclidean Push-T scores (mean maximum coverage over 50 seeds, from images) by
#: algorithm at (NFE, T): its NFE table at T = 1 and its integration-time table at NFE 3, T 1.2
#: and NFE 4, T 1.6 (`recipes.paper.pusht_euclidean`).
PAPER = {algo: paper.pusht_euclidean(algo) for algo in ("rfmp", "srfmp", "ddim")}


def paper_figures(cfg: DictConfig) -> tuple[dict, dict, list[str]]:
    """The paper's scores for a run of ``cfg``: ``(figures at (NFE, T), its integration-time
    table's own figures, the note naming their tables)``; empty where the paper reports none
    (Consistency Policy: it evaluates CP on robomimic only).

    Euclidean: `recipes.paper.pusht_euclidean`. Sphere: the prior table's row of the run's prior
    (DDIM: DP's Euclidean Gaussian projected onto the sphere) at T = 1, then the integration-time
    table, which states no prior (`recipes.paper.pusht_sphere`).
    """
    algo, space, prior = cfg.algo, cfg.space, cfg.model.get("prior_sphere", "uniform")
    figures = PAPER.get(algo, {}) if space == "euclidean" else paper.pusht_sphere(algo, prior)
    if not figures:
        return {}, {}, []
    own = paper.PUSHT_TIME.rows.get(f"{space}/{algo}", {})
    if space == "euclidean":
        source = f'table "{paper.PUSHT_NFE.caption}"'
    else:
        row = ("DP euclidean Gaussian" if algo == "ddim" else f"{algo.upper()} sphere "
               + {"uniform": "uniform", "wrapped": "Gaussian"}[prior])
        source = f'table "{paper.SPHERE_PRIORS.caption}", row "{row}",'
    note = (f"paper: the paper's {space.capitalize()} Push-T score at that setting (image "
            f"observations, 50 seeds): {source} at T = 1")
    if own:
        note += (f'; table "{paper.PUSHT_TIME.caption}" at NFE 3, T 1.2 and NFE 4, T 1.6'
                 + (" (it states no prior)" if space == "sphere" else "")
                 + ". At NFE 3, T 1 the integration-time paper row gives both tables' figures "
                 "where they differ (first / second)")
    return figures, own, [note + "."]


def check_config(cfg: DictConfig) -> None:
    check_algo(cfg)
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
        start = int(cfg.select.seed_start)
        chosen = range(start, start + int(cfg.select.seeds))
        tested = range(int(cfg.eval.seed_start), int(cfg.eval.seed_start) + int(cfg.eval.seeds))
        if len(chosen) < 1 or (chosen.start < tested.stop and tested.start < chosen.stop):
            raise ValueError(
                f"select.seeds/select.seed_start give seeds {chosen.start}-{chosen.stop - 1}"
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
        cfg.model.horizon,
        observation_keys=[keys.OBSERVATION],
        camera_keys=[keys.PIXELS] if cfg.obs == "image" else [],
        obs_horizon=cfg.model.obs_horizon,
        batch_size=cfg.train.batch_size,
        generator=torch.Generator().manual_seed(seed),
    )


# ----- model -----------------------------------------------------------------------------------
def make_model_config(cfg: DictConfig) -> ModelConfig:
    """``cfg.model`` with what the task fixes: the action manifold (R^2 or S^2), the observation
    keys (keypoints and agent position, or the agent position beside the camera) and sizes."""
    sphere = cfg.space == "sphere"
    points = 10 if cfg.obs == "state" else 1
    point_dim = 3 if sphere else 2
    if cfg.obs == "state":
        obs_keys = [["keypoints", 9 * point_dim], ["agent_pos", point_dim]]
    else:
        obs_keys = [["agent_pos", point_dim]]
    return model_config(
        cfg,
        action_manifold="S2" if sphere else "R2",
        obs_dim=points * point_dim,
        obs_manifold=" x ".join(["S2"] * points) if sphere else None,
        obs_keys=obs_keys,
        cameras={keys.PIXELS: [3, 96, 96]} if cfg.obs == "image" else {},
        crop_shape=[84, 84] if cfg.obs == "image" else None,
    )


def make_model(cfg: DictConfig, store: DemonstrationStore):
    """The network, with its normalisers fitted to the training store."""
    model = build_model(make_model_config(cfg))
    model.action_normalizer.set_stats(*store.stats(keys.ACTION))
    if model.cfg.obs_dim > 0:
        model.obs_normalizer.set_stats(*store.stats(keys.OBSERVATION))
    return model


# ----- evaluation ------------------------------------------------------------------------------
def metrics(cfg: DictConfig):
    """Per episode: the maximum coverage (the paper's score), Diffusion Policy's score
    min(coverage / 0.95, 1), success, the jerk of the executed actions and, on the sphere, their
    largest distance from unit norm."""
    def per_seed(rollout, steps) -> dict:
        score = rollout["next", "max_coverage"][:, -1, 0]  # (N,)
        actions = rollout[keys.ACTION]  # (N, L, D)
        jerks, errors = [], []
        for i in range(actions.shape[0]):
            executed = actions[i, : int(steps[i])]
            jerks.append(float(jerk(executed.double(), CONTROL_DT))
                         if executed.shape[0] >= 4 else float("nan"))
            errors.append(float((executed.norm(dim=-1) - 1).abs().max())
                          if cfg.space == "sphere" else float("nan"))
        return {"score": score.tolist(),
                "dp_score": (score / PUSHT_SUCCESS_COVERAGE).clamp(max=1.0).tolist(),
                "success": rollout["next", "success"][:, -1, 0].float().tolist(),
                "jerk": jerks, "manifold_err": errors}

    return per_seed


def summary(values) -> dict:
    return {"score": seed_mean(values["score"]), "score_std": seed_std(values["score"]),
            "dp_score": seed_mean(values["dp_score"]), "success": seed_mean(values["success"]),
            "jerk": seed_mean(values["jerk"]), "manifold_err": seed_max(values["manifold_err"])}


def eval_task(cfg: DictConfig) -> TaskEval:
    """The Push-T evaluation of ``cfg``: env, actor, figures, table and the paper's scores."""
    unit = "S^2 coords/s^3" if cfg.space == "sphere" else "px/s^3"  # the actions' own units
    figures, time_figures, notes = paper_figures(cfg)
    return TaskEval(
        env_fn=make_pusht_env,
        env_kwargs={"obs_type": cfg.obs, "space": cfg.space,
                    "max_steps": int(cfg.eval.max_steps), "obs_horizon": cfg.model.obs_horizon},
        make_actor=lambda model, nfe, t_end: make_actor(
            model, nfe, t_end, camera_keys={keys.PIXELS: keys.PIXELS_WINDOW}),
        metrics=metrics(cfg), summary=summary,
        columns=[Column("score", "score (max coverage)",
                        lambda r: f"{r['score']:.3f} ± {r['score_std']:.3f}", paper=True),
                 Column("dp_score", "DP score"), Column("success", "success", "{:.2f}"),
                 Column("jerk", f"jerk ({unit})", "{:.3g}"),
                 Column("manifold_err", "on-S^2 err", "{:.1e}"),
                 Column("env_steps", "env steps", "{}"), Column("seconds", "s", "{:.0f}")],
        labels={"algo": cfg.algo},
        paper=figures, time_paper=time_figures,
        plot=("score", "mean max coverage", (0.0, 1.0)),
        notes=notes,
    )


def selection_score(cfg: DictConfig):
    """``train.select_by=rollout``: the function `fit` calls on the EMA model at every
    validation, the mean max coverage over the selection seeds at ``select.nfe`` /
    ``select.t_end`` (seeds disjoint from the evaluation ones, `check_config`); else None."""
    if cfg.train.get("select_by", "val_loss") != "rollout":
        return None
    select = cfg.select
    chosen = replace(eval_config(cfg), seeds=int(select.seeds), seed_start=int(select.seed_start),
                     num_envs=None)
    nfe, t_end, task = int(select.nfe), float(select.t_end), eval_task(cfg)

    def score(model) -> float:
        result = evaluate(task.env_fn, model, lambda n, t: task.make_actor(model, n, t), nfe,
                          t_end, chosen, task.metrics, seed=int(cfg.seed),
                          env_kwargs=task.env_kwargs)
        return seed_mean(result.values["score"])

    return score
