"""The robosuite tasks for the recipes: the data (robomimic HDF5 from the scripted experts as
demonstration stores and replay buffers), the model's task-derived settings, the evaluation env
and actor, and the task's figures (success, jerk, distance of the executed quaternions from unit
norm)."""

from __future__ import annotations

import functools
from pathlib import Path

import torch
from omegaconf import DictConfig
from tensordict import TensorDict
from tensordict.nn import TensorDictModule, TensorDictSequential

from recipes import paper
from recipes.common import (
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
from rfmp_rl.data import DemonstrationStore, read_robomimic
from rfmp_rl.data.quaternions import (
    canonical_quaternion_signs,
    canonicalize_observation_quaternions,
    parse_observation_quaternions,
)
from rfmp_rl.envs.robosuite import (
    ROBOSUITE_CONTROL_FREQ,
    ROBOSUITE_MAX_STEPS,
    ROBOSUITE_MUG_TASKS,
    ROBOSUITE_TASKS,
    action_dim,
    low_dim_key_dims,
    make_robosuite_env,
    num_arms,
    robosuite_obs_quaternions,
    task_cameras,
    task_low_dim_keys,
    task_proprio_keys,
)
from rfmp_rl.eval import Column, seed_max, seed_mean
from rfmp_rl.eval.metrics import jerk
from rfmp_rl.manifolds.quaternion import hemisphere_continuous
from rfmp_rl.modules import ModelConfig, build_model

CAMERAS = ("agentview_image", "robot0_eye_in_hand_image")  # the single-arm tasks' cameras
CONTROL_DT = 1.0 / ROBOSUITE_CONTROL_FREQ
CONTROL_RATE_HZ = float(ROBOSUITE_CONTROL_FREQ)  # stored in the checkpoints and ONNX metadata
#: Task choices that define a run besides ``model`` and ``loss`` (a resume may not change them).
#: (``obs_quaternions`` is guarded by the model config a resume compares: a run made before
#: it resumes with ``obs_quaternions=raw``.)
TASK_KEYS = ("task", "obs", "action_space", "geometry")
#: The hemisphere of the first abs_pose action quaternion (xyzw): the hand pointing down, the
#: reference of the observed ``robot0_eef_quat`` (`robosuite_obs_quaternions`).
HAND_REFERENCE = (1.0, 0.0, 0.0, 0.0)

#: The paper's success rates on the state-based robomimic tasks (its table "Success rate as a
#: function of different NFE values on the state-based Robomimic tasks"), at T = 1
#: (`recipes.paper.ROBOMIMIC_STATE`).
PAPER = {tuple(key.split("/")): figures for key, figures in paper.ROBOMIMIC_STATE.rows.items()}


def check_config(cfg: DictConfig) -> None:
    if cfg.task not in ROBOSUITE_TASKS:
        raise ValueError(f"task must be one of {ROBOSUITE_TASKS}, got {cfg.task!r}")
    check_algo(cfg)
    if cfg.obs not in ("state", "image"):
        raise ValueError(f"obs must be 'state' or 'image', got {cfg.obs!r}")
    if cfg.action_space not in ("delta", "abs_pose"):
        raise ValueError(f"action_space must be 'delta' or 'abs_pose', got {cfg.action_space!r}")
    if cfg.geometry not in ("riemannian", "euclidean"):
        raise ValueError(f"geometry must be 'riemannian' or 'euclidean', got {cfg.geometry!r}")
    if cfg.get("obs_quaternions", "raw") not in ("canonical", "raw"):
        raise ValueError(f"obs_quaternions must be 'canonical' or 'raw', got "
                         f"{cfg.obs_quaternions!r}")
    check_runtime_config(cfg)


def pose_action(cfg: DictConfig) -> bool:
    return cfg.action_space == "abs_pose"


def low_dim_keys(cfg: DictConfig) -> tuple[str, ...]:
    """The low-dim keys of ``observation``: all of the task's with state observations,
    robomimic's proprioception alone (no object state) with images."""
    return task_proprio_keys(cfg.task) if cfg.obs == "image" else task_low_dim_keys(cfg.task)


def cameras(task: str) -> tuple[str, ...]:
    """The image keys of ``task`` (`CAMERAS`; TwoArmTransport: its four cameras)."""
    return tuple(f"{cam}_image" for cam in task_cameras(task))


def quaternion_slices(cfg: DictConfig) -> list[slice]:
    """Where the quaternions sit in a pose action: ``3:7`` per arm (8 entries per arm)."""
    return [slice(8 * k + 3, 8 * k + 7) for k in range(num_arms(cfg.task))]


def obs_quaternions(cfg: DictConfig) -> list[dict] | None:
    """The observed quaternions made canonical (``obs_quaternions=canonical``): columns of
    ``observation`` and references (`robosuite_obs_quaternions`); None with ``raw``."""
    if cfg.get("obs_quaternions", "raw") != "canonical":
        return None
    return robosuite_obs_quaternions(cfg.task, low_dim_keys(cfg))


def low_dim_sizes(cfg: DictConfig) -> list[list]:
    sizes = low_dim_key_dims(cfg.task)
    return [[k, sizes[k]] for k in low_dim_keys(cfg)]


# ----- data ------------------------------------------------------------------------------------
def data_path(cfg: DictConfig) -> Path:
    if cfg.data.path:
        return resolve(cfg.data.path)
    from experts import default_demo_path  # recipes/robosuite/experts.py

    return default_demo_path(cfg.task, cfg.action_space, images=cfg.obs == "image")


def _demo_count(path: Path) -> int | None:
    """Episodes (groups under ``data``) of a robomimic file; None without ``data``."""
    import h5py

    with h5py.File(path, "r") as f:
        data = f.get("data")
        return None if data is None else sum(isinstance(v, h5py.Group) for v in data.values())


def ensure_demos(cfg: DictConfig) -> Path:
    """The demonstration file; written by the scripted expert when missing and data.generate.
    The recipe's own file (no data.path) must hold the data.demos asked for."""
    path = data_path(cfg)
    if path.exists():
        count = _demo_count(path)
        if count is not None:  # else read_robomimic names what the file lacks
            check_demo_count(path, count, cfg.data)
        return path
    if not cfg.data.generate:
        raise FileNotFoundError(f"no demonstration file {path} (data.generate=true writes it "
                                "with the scripted expert)")
    from experts import generate_demos  # recipes/robosuite/experts.py

    print(f"generating {cfg.data.demos} expert demonstrations -> {path}")
    result = generate_demos(cfg.task, int(cfg.data.demos), cfg.action_space,
                            images=cfg.obs == "image", path=str(path), verbose=False)
    print(f"expert success rate {result['success_rate']:.3f} "
          f"({result['successes']}/{result['attempts']})")
    return path


@functools.lru_cache(maxsize=2)
def _read(path: str, images: bool, task: str):
    keys_ = list(task_low_dim_keys(task)) + (list(cameras(task)) if images else [])
    # Raw signs here: `policy_episodes` applies the recipe's rule to the observation vector, as
    # the evaluation env and the controller do (the reader's default first-sample hemisphere,
    # w >= 0, is the boundary the Panda's downward hand sits on).
    return read_robomimic(path, obs_keys=keys_, load_images=images, raw_quaternion_signs=True)


def policy_episodes(raw: list[TensorDict], cfg: DictConfig) -> list[TensorDict]:
    """robomimic episodes -> ``observation`` (the low-dim keys concatenated in robomimic's order),
    camera images, and ``action``.

    With ``obs_quaternions=canonical`` the observed quaternions (`obs_quaternions`) and the
    abs_pose action quaternion follow one rule, `canonical_quaternion_signs`: continuity along
    the episode, the first sample in its reference's hemisphere (the action's: the hand's,
    `HAND_REFERENCE`). With ``raw`` (runs made before the rule) the observations keep the
    recorded signs and the action quaternions are only made continuous from the first one."""
    fields = parse_observation_quaternions(obs_quaternions(cfg))
    out = []
    for ep in raw:
        n = ep.batch_size[0]
        obs = torch.cat([ep["obs", k].float().reshape(n, -1) for k in low_dim_keys(cfg)], -1)
        if fields:
            obs = canonicalize_observation_quaternions(obs, fields)
        action = ep["action"].float()
        if pose_action(cfg):
            action = action.clone()
            for q in quaternion_slices(cfg):  # each arm's, by the hand's rule
                action[:, q] = (canonical_quaternion_signs(action[:, q], HAND_REFERENCE)
                                if fields else hemisphere_continuous(action[:, q]))
        sample = TensorDict({keys.OBSERVATION: obs, keys.ACTION: action}, [n])
        if cfg.obs == "image":
            for cam in cameras(cfg.task):
                sample.set(cam, ep["obs", cam])
        out.append(sample)
    return out


def make_stores(cfg: DictConfig) -> tuple[DemonstrationStore, DemonstrationStore]:
    path = ensure_demos(cfg)
    raw, source = _read(str(path), cfg.obs == "image", cfg.task)
    episodes = policy_episodes(raw, cfg)
    return split_stores(episodes, source, cfg.data, f"robosuite/{cfg.task}")


def make_replay_buffer(store: DemonstrationStore, cfg: DictConfig, seed: int):
    return store.replay_buffer(
        cfg.model.horizon,
        observation_keys=[keys.OBSERVATION],
        camera_keys=list(cameras(cfg.task)) if cfg.obs == "image" else [],
        obs_horizon=cfg.model.obs_horizon,
        batch_size=cfg.train.batch_size,
        generator=torch.Generator().manual_seed(seed),
    )


# ----- model -----------------------------------------------------------------------------------
def make_model_config(cfg: DictConfig) -> ModelConfig:
    """``cfg.model`` with what the task fixes: the action manifold (robomimic's delta R^7, or the
    pose R^3 x S^3 x R^1, or R^8 for the Euclidean baseline; per arm, so R^14 or
    (R^3 x S^3 x R^1)^2 for TwoArmTransport), the observation keys and cameras."""
    obs_keys = low_dim_sizes(cfg)
    obs_dim = sum(d for _, d in obs_keys)
    dim = action_dim(cfg.task, cfg.action_space)
    if not pose_action(cfg):
        action_manifold = f"R{dim}"
    elif cfg.geometry == "riemannian":
        action_manifold = " x ".join(["R3 x S3 x R1"] * num_arms(cfg.task))
    else:
        action_manifold = f"R{dim}"
    return model_config(
        cfg,
        action_manifold=action_manifold,
        obs_dim=obs_dim,
        obs_manifold=f"R3 x S3 x R{obs_dim - 7}",  # the eef quaternion is left unnormalised
        obs_quaternions=obs_quaternions(cfg),
        obs_keys=obs_keys,
        cameras={cam: [3, 84, 84] for cam in cameras(cfg.task)} if cfg.obs == "image" else {},
        crop_shape=[76, 76] if cfg.obs == "image" else None,
    )


def make_model(cfg: DictConfig, store: DemonstrationStore):
    model = build_model(make_model_config(cfg))
    model.action_normalizer.set_stats(*store.stats(keys.ACTION))
    model.obs_normalizer.set_stats(*store.stats(keys.OBSERVATION))
    return model


# ----- evaluation ------------------------------------------------------------------------------
def _normalise_quaternion(action: torch.Tensor) -> torch.Tensor:
    """Every arm's quaternion (entries ``8 k + 3 : 8 k + 7``) scaled to unit norm."""
    parts = []
    for arm in action.split(8, dim=-1):
        q = arm[..., 3:7]
        parts += [arm[..., :3], q / q.norm(dim=-1, keepdim=True).clamp_min(1e-12), arm[..., 7:]]
    return torch.cat(parts, dim=-1)


def make_env_actor(model, cfg: DictConfig, nfe: int, t_end: float):
    """The acting module. A Euclidean (R^8) pose policy keeps its raw output in ``raw_action``
    and sends the action with its quaternion normalised (post-hoc normalisation)."""
    actor = make_actor(model, nfe, t_end,
                       camera_keys={c: f"{c}_window" for c in cameras(cfg.task)})
    if pose_action(cfg) and cfg.geometry == "euclidean":
        keep = TensorDictModule(lambda a: a.clone(), in_keys=[keys.ACTION], out_keys=["raw_action"])
        norm = TensorDictModule(_normalise_quaternion, in_keys=[keys.ACTION],
                                out_keys=[keys.ACTION])
        return TensorDictSequential(actor, keep, norm)
    return actor


def env_kwargs(cfg: DictConfig, model=None) -> dict:
    """`make_robosuite_env`'s settings (besides the batch and the seeds). The observed
    quaternions' rule is the model's (``model.cfg.obs_quaternions``: None for checkpoints made
    before it, whose policies read raw signs), else the one ``cfg`` trains with."""
    quaternions = obs_quaternions(cfg) if model is None else model.cfg.obs_quaternions
    return {"task": cfg.task, "obs_horizon": cfg.model.obs_horizon,
            "obs_quaternions": quaternions,
            "action_space": cfg.action_space,
            "cameras": tuple(c.removesuffix("_image") for c in cameras(cfg.task))
            if cfg.obs == "image" else (),
            "low_dim_keys": low_dim_keys(cfg), "max_steps": cfg.eval.max_steps}


#: Rendering envs stepped at once by default (``eval.num_envs``): each rendering robosuite env
#: holds ~0.4 GB and the rollout keeps every frame, so 50 at once hold over 20 GB.
IMAGE_EVAL_ENVS = 10


def metrics(cfg: DictConfig):
    """Per episode: success (0/1), the jerk of the executed positions and, for pose actions,
    the largest distance of the executed (raw) quaternions from unit norm."""
    def per_seed(rollout, steps) -> dict:
        raw = rollout.get("raw_action", rollout[keys.ACTION])
        jerks, errors = [], []
        for i in range(raw.shape[0]):
            executed = raw[i, : int(steps[i])].double()
            jerks.append(float(jerk(executed[:, :3], CONTROL_DT))  # position part
                         if executed.shape[0] >= 4 else float("nan"))
            errors.append(max(float((executed[:, q].norm(dim=-1) - 1).abs().max())
                              for q in quaternion_slices(cfg))
                          if pose_action(cfg) else float("nan"))
        return {"success": rollout["next", "success"][:, -1, 0].float().tolist(),
                "jerk": jerks, "quat_norm_err": errors}

    return per_seed


def summary(values) -> dict:
    return {"success": seed_mean(values["success"]), "jerk": seed_mean(values["jerk"]),
            "quat_norm_err": seed_max(values["quat_norm_err"])}


def eval_task(cfg: DictConfig, model=None) -> TaskEval:
    """The robosuite evaluation of ``cfg``: env, actor, figures and table. Give the evaluated
    ``model`` so that its env applies the model's observed-quaternion rule (`env_kwargs`)."""
    actions = cfg.action_space + ("" if not pose_action(cfg) else f"/{cfg.geometry}")
    return TaskEval(
        env_fn=make_robosuite_env, env_kwargs=env_kwargs(cfg, model),
        make_actor=lambda model, nfe, t_end: make_env_actor(model, cfg, nfe, t_end),
        metrics=metrics(cfg), summary=summary,
        columns=[Column("success", "success", "{:.2f}", paper=True),
                 Column("jerk", "jerk (pos, /s^3)", "{:.3g}"),
                 Column("quat_norm_err", "max abs(norm(q)-1)", "{:.1e}"),
                 Column("env_steps", "env steps", "{}"), Column("seconds", "s", "{:.0f}")],
        labels={"task": cfg.task, "algo": cfg.algo, "action_space": actions},
        max_steps=ROBOSUITE_MAX_STEPS[cfg.task],
        num_envs=IMAGE_EVAL_ENVS if cfg.obs == "image" else None,
        paper=PAPER.get((cfg.task, cfg.algo), {}) if cfg.obs == "state" else {},
        notes=_notes(cfg),
    )


def _notes(cfg: DictConfig) -> list[str]:
    if cfg.task in ROBOSUITE_MUG_TASKS:
        return [f"{cfg.task}: a simulated stand-in for the paper's real-robot task (its figure "
                "of success and jerk over NFE gives no table to set beside ours)."]
    if cfg.obs == "state" and PAPER.get((cfg.task, cfg.algo)):
        return ["paper: the paper's success rate at that setting (state observations, "
                "robomimic's human demonstrations)."]
    return []
