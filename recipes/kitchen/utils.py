"""Franka Kitchen for the recipes: the data (a Minari dataset, the scripted expert's or a
``D4RL/kitchen`` copy, read into demonstration stores and replay buffers), the model's
task-derived settings (the R3 x S3 x R2 end-effector action), the evaluation env and actor, and
the task's figures (success on all four subtasks, each subtask's rate, the distance of the
executed quaternions from unit norm)."""

from __future__ import annotations

import functools
from pathlib import Path

from omegaconf import DictConfig

from recipes.common import (
    ROOT,
    TaskEval,
    check_algo,
    check_demo_count,
    check_runtime_config,
    make_actor,
    model_config,
    resolve,
    split_stores,
)
from rfmp_rl import keys
from rfmp_rl.data import DemonstrationStore
from rfmp_rl.envs.kitchen import (
    KITCHEN_CONTROL_FREQ,
    KITCHEN_MAX_STEPS,
    KITCHEN_OBS_DIMS,
    KITCHEN_SUBTASK_KEYS,
    kitchen_episodes,
    make_kitchen_env,
)
from rfmp_rl.eval import Column, seed_max, seed_mean
from rfmp_rl.eval.metrics import jerk
from rfmp_rl.modules import ModelConfig, build_model

CONTROL_DT = 1.0 / KITCHEN_CONTROL_FREQ
CONTROL_RATE_HZ = float(KITCHEN_CONTROL_FREQ)  # stored in the checkpoints and ONNX metadata
#: Task choices that define a run besides ``model`` and ``loss`` (a resume may not change them).
TASK_KEYS = ("data.source",)
ACTION_MANIFOLD = "R3 x S3 x R2"  # site position, quaternion xyzw, two finger positions
#: ``observation``: robot_qpos 9, robot_qvel 9, ee_pos 3, ee_quat 4 (left unnormalised), object 41
OBS_MANIFOLD = "R21 x S3 x R41"

#: The paper's success rates (its table "Success rate as a function of NFE on the Franka kitchen
#: benchmark"), at T = 1.
_PAPER_NFES = (1, 2, 3, 5, 10)
PAPER = {
    algo: {(nfe, 1.0): v for nfe, v in zip(_PAPER_NFES, values, strict=True)}
    for algo, values in {
        "rfmp": (0.04, 0.08, 0.12, 0.14, 0.14),
        "srfmp": (1.0, 1.0, 1.0, 1.0, 1.0),
        "ddim": (0.0, 0.0, 0.0, 0.02, 0.02),
    }.items()
}


def check_config(cfg: DictConfig) -> None:
    check_algo(cfg)
    if cfg.algo == "cp":
        raise ValueError("the kitchen recipe trains rfmp, srfmp or ddim (the paper's kitchen "
                         "comparison); it does not offer algo=cp")
    check_runtime_config(cfg)


# ----- data ------------------------------------------------------------------------------------
def data_path(cfg: DictConfig) -> Path | str:
    """``data.source``: ``expert`` (the scripted expert's dataset under data/kitchen), a local
    Minari folder, or a Minari dataset id under ``$MINARI_DATASETS_PATH``."""
    source = str(cfg.data.source)
    if source == "expert":
        return resolve(cfg.data.path) if cfg.data.path else \
            ROOT / "data" / "kitchen" / "kitchen-expert-v0"
    local = resolve(source)
    return local if local.exists() else source


def ensure_demos(cfg: DictConfig) -> Path | str:
    """The dataset; the scripted expert writes it when ``data.source=expert`` and it is
    missing (and ``data.generate``). Its own dataset (no ``data.path``) must hold the
    ``data.demos`` asked for."""
    path = data_path(cfg)
    if cfg.data.source != "expert":
        return path
    main_data = Path(path) / "data" / "main_data.hdf5"
    if main_data.exists():
        import h5py

        with h5py.File(main_data, "r") as f:
            count = sum(1 for name in f if name.startswith("episode_"))
        check_demo_count(path, count, cfg.data)
        return path
    if not cfg.data.generate:
        raise FileNotFoundError(f"no kitchen dataset at {path} (data.generate=true writes it "
                                "with the scripted expert)")
    from experts import generate_demos  # recipes/kitchen/experts.py

    print(f"generating {cfg.data.demos} expert demonstrations -> {path}")
    result = generate_demos(int(cfg.data.demos), path, verbose=False)
    print(f"expert success rate {result['success_rate']:.3f} "
          f"({result['successes']}/{result['attempts']})")
    return path


@functools.lru_cache(maxsize=2)
def _read(source: str):
    return kitchen_episodes(source)


def make_stores(cfg: DictConfig) -> tuple[DemonstrationStore, DemonstrationStore]:
    path = ensure_demos(cfg)
    episodes, manifest = _read(str(path))
    episodes = [ep.select(keys.OBSERVATION, keys.ACTION) for ep in episodes]
    return split_stores(episodes, manifest, cfg.data, "kitchen")


def make_replay_buffer(store: DemonstrationStore, cfg: DictConfig, seed: int):
    import torch

    return store.replay_buffer(
        cfg.model.horizon,
        observation_keys=[keys.OBSERVATION],
        obs_horizon=cfg.model.obs_horizon,
        batch_size=cfg.train.batch_size,
        generator=torch.Generator().manual_seed(seed),
    )


# ----- model -----------------------------------------------------------------------------------
def make_model_config(cfg: DictConfig) -> ModelConfig:
    """``cfg.model`` with what the task fixes: the action manifold R3 x S3 x R2 (Euclidean
    Gaussian prior on the R parts, ``model.prior_sphere`` on S^3; DDIM projects its samples onto
    it, the paper's post-hoc normalisation) and the 66-D observation."""
    obs_dim = sum(KITCHEN_OBS_DIMS.values())
    return model_config(cfg, action_manifold=ACTION_MANIFOLD, obs_dim=obs_dim,
                        obs_manifold=OBS_MANIFOLD, obs_keys=[[keys.OBSERVATION, obs_dim]])


def make_model(cfg: DictConfig, store: DemonstrationStore):
    model = build_model(make_model_config(cfg))
    model.action_normalizer.set_stats(*store.stats(keys.ACTION))
    model.obs_normalizer.set_stats(*store.stats(keys.OBSERVATION))
    return model


# ----- evaluation ------------------------------------------------------------------------------
def env_kwargs(cfg: DictConfig) -> dict:
    """`make_kitchen_env`'s settings (besides the batch and the seeds)."""
    return {"obs_horizon": cfg.model.obs_horizon, "max_steps": cfg.eval.max_steps,
            "init_noise": float(cfg.env.init_noise), "kettle_noise": float(cfg.env.kettle_noise)}


def metrics(rollout, steps) -> dict:
    """Per episode: success (all four subtasks), each subtask's completion, the jerk of the
    executed positions and the largest distance of an executed quaternion from unit norm."""
    out = {"success": rollout["next", "success"][:, -1, 0].float().tolist()}
    for name in KITCHEN_SUBTASK_KEYS:
        out[name] = rollout["next", "subtasks", name][:, -1, 0].float().tolist()
    jerks, errors = [], []
    action = rollout[keys.ACTION]
    for i in range(action.shape[0]):
        executed = action[i, : int(steps[i])].double()
        jerks.append(float(jerk(executed[:, :3], CONTROL_DT)) if executed.shape[0] >= 4
                     else float("nan"))
        errors.append(float((executed[:, 3:7].norm(dim=-1) - 1).abs().max()))
    out.update(jerk=jerks, quat_norm_err=errors)
    return out


def summary(values) -> dict:
    row = {k: seed_mean(values[k]) for k in ("success", *KITCHEN_SUBTASK_KEYS, "jerk")}
    row["quat_norm_err"] = seed_max(values["quat_norm_err"])
    return row


def eval_task(cfg: DictConfig) -> TaskEval:
    """The kitchen evaluation of ``cfg``: env, actor, figures and table."""
    return TaskEval(
        env_fn=make_kitchen_env, env_kwargs=env_kwargs(cfg),
        make_actor=lambda model, nfe, t_end: make_actor(model, nfe, t_end),
        metrics=metrics, summary=summary,
        columns=[Column("success", "success (all 4)", "{:.2f}", paper=True),
                 *(Column(n, n.replace("_", " "), "{:.2f}") for n in KITCHEN_SUBTASK_KEYS),
                 Column("quat_norm_err", "max abs(norm(q)-1)", "{:.1e}"),
                 Column("jerk", "jerk (pos, /s^3)", "{:.3g}"),
                 Column("env_steps", "env steps", "{}"), Column("seconds", "s", "{:.0f}")],
        labels={"task": "kitchen", "algo": cfg.algo},
        max_steps=KITCHEN_MAX_STEPS,
        paper=PAPER.get(cfg.algo, {}),
        notes=["paper: the paper's success rate (all four subtasks) at that setting, trained "
               "on Minari's D4RL/kitchen human demonstrations (19 episodes, 4209 steps)."],
    )
