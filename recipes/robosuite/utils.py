"""Factories for the robosuite recipes: data (robomimic HDF5 from the scripted experts), model,
env, actor and the NFE sweep with success rate, jerk and on-manifold error."""

from __future__ import annotations

import csv
import functools
import math
import sys
import time
from pathlib import Path

import torch
from omegaconf import DictConfig
from tensordict import TensorDict
from tensordict.nn import TensorDictModule, TensorDictSequential
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
from rfmp_rl.data import DemonstrationStore, read_robomimic  # noqa: E402
from rfmp_rl.envs.robosuite import (  # noqa: E402
    ROBOSUITE_CONTROL_FREQ,
    ROBOSUITE_LOW_DIM_KEYS,
    ROBOSUITE_MAX_STEPS,
    ROBOSUITE_PROPRIO_KEYS,
    ROBOSUITE_TASKS,
    low_dim_key_dims,
    make_robosuite_env,
)
from rfmp_rl.eval.metrics import jerk  # noqa: E402
from rfmp_rl.eval.parallel import FlatBatch, evaluation_env, flatten_workers  # noqa: E402
from rfmp_rl.manifolds.quaternion import hemisphere_continuous  # noqa: E402
from rfmp_rl.modules import ModelConfig, build_model  # noqa: E402

__all__ = ["ROOT", "build_training", "fit", "end_time", "load_for_eval", "start_run",
           "eval_model", "exit_code", "deploy_classes"]

CAMERAS = ("agentview_image", "robot0_eye_in_hand_image")
CONTROL_DT = 1.0 / ROBOSUITE_CONTROL_FREQ


def check_config(cfg: DictConfig) -> None:
    if cfg.task not in ROBOSUITE_TASKS:
        raise ValueError(f"task must be one of {ROBOSUITE_TASKS}, got {cfg.task!r}")
    if cfg.algo not in ALGOS:
        raise ValueError(f"algo must be one of {sorted(ALGOS)}, got {cfg.algo!r}")
    if cfg.obs not in ("state", "image"):
        raise ValueError(f"obs must be 'state' or 'image', got {cfg.obs!r}")
    if cfg.action_space not in ("delta", "abs_pose"):
        raise ValueError(f"action_space must be 'delta' or 'abs_pose', got {cfg.action_space!r}")
    if cfg.geometry not in ("riemannian", "euclidean"):
        raise ValueError(f"geometry must be 'riemannian' or 'euclidean', got {cfg.geometry!r}")
    check_runtime_config(cfg)


def pose_action(cfg: DictConfig) -> bool:
    return cfg.action_space == "abs_pose"


def low_dim_keys(cfg: DictConfig) -> tuple[str, ...]:
    """The low-dim keys of ``observation``: all four with state observations, robomimic's
    proprioception alone (no object state) with images."""
    return ROBOSUITE_PROPRIO_KEYS if cfg.obs == "image" else ROBOSUITE_LOW_DIM_KEYS


def low_dim_sizes(cfg: DictConfig) -> list[list]:
    sizes = low_dim_key_dims(cfg.task)
    return [[k, sizes[k]] for k in low_dim_keys(cfg)]


# ----- data ------------------------------------------------------------------------------------
def data_path(cfg: DictConfig) -> Path:
    if cfg.data.path:
        return resolve(cfg.data.path)
    suffix = "_images" if cfg.obs == "image" else ""
    return ROOT / "data" / "robosuite" / f"{cfg.task.lower()}_{cfg.action_space}{suffix}.hdf5"


def ensure_demos(cfg: DictConfig) -> Path:
    """The demonstration file; written by the scripted expert when missing and data.generate."""
    path = data_path(cfg)
    if path.exists():
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
def _read(path: str, images: bool):
    keys_ = list(ROBOSUITE_LOW_DIM_KEYS) + (list(CAMERAS) if images else [])
    # Raw signs: the policy sees robosuite's eef quaternion as the environment reports it at
    # evaluation, so the training observations keep the recorded signs too.
    return read_robomimic(path, obs_keys=keys_, load_images=images, raw_quaternion_signs=True)


def policy_episodes(raw: list[TensorDict], cfg: DictConfig) -> list[TensorDict]:
    """robomimic episodes -> ``observation`` (the low-dim keys concatenated in robomimic's order),
    camera images, and ``action`` (abs_pose quaternions made hemisphere-continuous)."""
    out = []
    for ep in raw:
        n = ep.batch_size[0]
        obs = torch.cat([ep["obs", k].float().reshape(n, -1) for k in low_dim_keys(cfg)], -1)
        action = ep["action"].float()
        if pose_action(cfg):
            action = torch.cat([action[:, :3], hemisphere_continuous(action[:, 3:7]),
                                action[:, 7:]], dim=-1)
        sample = TensorDict({keys.OBSERVATION: obs, keys.ACTION: action}, [n])
        if cfg.obs == "image":
            for cam in CAMERAS:
                sample.set(cam, ep["obs", cam])
        out.append(sample)
    return out


def make_stores(cfg: DictConfig) -> tuple[DemonstrationStore, DemonstrationStore]:
    path = ensure_demos(cfg)
    raw, source = _read(str(path), cfg.obs == "image")
    episodes = policy_episodes(raw, cfg)
    return split_stores(episodes, source, cfg.data, f"robosuite/{cfg.task}")


def make_replay_buffer(store: DemonstrationStore, cfg: DictConfig, seed: int):
    return store.replay_buffer(
        cfg.horizon,
        observation_keys=[keys.OBSERVATION],
        camera_keys=list(CAMERAS) if cfg.obs == "image" else [],
        obs_horizon=cfg.obs_horizon,
        batch_size=cfg.train.batch_size,
        generator=torch.Generator().manual_seed(seed),
    )


# ----- model -----------------------------------------------------------------------------------
def make_model_config(cfg: DictConfig) -> ModelConfig:
    obs_keys = low_dim_sizes(cfg)
    obs_dim = sum(d for _, d in obs_keys)
    if not pose_action(cfg):
        action_manifold = "R7"
    elif cfg.geometry == "riemannian":
        action_manifold = "R3 x S3 x R1"
    else:
        action_manifold = "R8"
    algorithm = ALGOS[cfg.algo]
    return ModelConfig(
        algorithm=algorithm,
        action_manifold=action_manifold,
        horizon=cfg.horizon,
        action_steps=cfg.action_steps,
        obs_horizon=cfg.obs_horizon,
        obs_dim=obs_dim,
        obs_manifold=f"R3 x S3 x R{obs_dim - 7}",  # the eef quaternion is left unnormalised
        obs_keys=obs_keys,
        cameras={cam: [3, 84, 84] for cam in CAMERAS} if cfg.obs == "image" else {},
        crop_shape=[76, 76] if cfg.obs == "image" else None,
        unet_preset=cfg.preset,
        down_dims=list(cfg.down_dims) if cfg.down_dims else None,
        prior_sphere=cfg.prior,
        prior_scale=cfg.prior_scale,
        prior_repeat=cfg.prior_repeat,
        lambda_x=cfg.lambda_x,
        lambda_tau=cfg.lambda_tau,
        time_max=cfg.time_max if algorithm == "srfmp" else 1.0,
        t0_fraction=cfg.t0_fraction if algorithm != "ddim" else 0.0,
        control_rate_hz=float(ROBOSUITE_CONTROL_FREQ),
    )


def make_model(cfg: DictConfig, store: DemonstrationStore):
    model = build_model(make_model_config(cfg))
    model.action_normalizer.set_stats(*store.stats(keys.ACTION))
    model.obs_normalizer.set_stats(*store.stats(keys.OBSERVATION))
    return model


# ----- acting ----------------------------------------------------------------------------------
def _normalise_quaternion(action: torch.Tensor) -> torch.Tensor:
    q = action[..., 3:7]
    return torch.cat([action[..., :3], q / q.norm(dim=-1, keepdim=True).clamp_min(1e-12),
                      action[..., 7:]], dim=-1)


def make_env_actor(model, cfg: DictConfig, nfe: int, t_end: float):
    """The acting module. A Euclidean (R^8) pose policy keeps its raw output in ``raw_action``
    and sends the action with its quaternion normalised (post-hoc normalisation)."""
    actor = make_actor(model, nfe, t_end, camera_keys={c: f"{c}_window" for c in CAMERAS})
    if pose_action(cfg) and cfg.geometry == "euclidean":
        keep = TensorDictModule(lambda a: a.clone(), in_keys=[keys.ACTION], out_keys=["raw_action"])
        norm = TensorDictModule(_normalise_quaternion, in_keys=[keys.ACTION],
                                out_keys=[keys.ACTION])
        return TensorDictSequential(actor, keep, norm)
    return actor


def make_env(cfg: DictConfig, seeds: list[int], noise_dim: int | None = None):
    """The evaluation env over ``seeds``: ``(env, number of seeds)``, stepped by ``eval.workers``
    processes (TorchRL ``ParallelEnv``) when more than one; with ``noise_dim`` each episode's
    prior noise comes from its own seed (`rfmp_rl.eval.parallel.PriorNoise`)."""
    return evaluation_env(
        make_robosuite_env, seeds, int(cfg.eval.get("workers", 1)), noise_dim=noise_dim,
        noise_seed=int(cfg.seed), task=cfg.task, obs_horizon=cfg.obs_horizon,
        action_space=cfg.action_space,
        cameras=tuple(c.removesuffix("_image") for c in CAMERAS) if cfg.obs == "image" else (),
        low_dim_keys=low_dim_keys(cfg), max_steps=cfg.eval.max_steps,
    )


IMAGE_EVAL_ENVS = 10  # rendering envs stepped at once by default: 50 at once need over 20 GB


def eval_num_envs(cfg: DictConfig) -> int:
    """Envs stepped side by side: ``eval.num_envs``, else every seed at once for state policies
    and `IMAGE_EVAL_ENVS` for image policies (each rendering robosuite env holds ~0.4 GB and the
    rollout keeps every frame)."""
    n = cfg.eval.get("num_envs")
    if n is None:
        n = IMAGE_EVAL_ENVS if cfg.obs == "image" else int(cfg.eval.seeds)
    if int(n) < 1:
        raise ValueError(f"eval.num_envs must be >= 1, got {n}")
    return int(n)


def _noise_dim(model, cfg: DictConfig) -> int | None:
    """Prior noise per episode from its seed (random sampling); None for the prior's mode."""
    return None if cfg.eval.sampling == "deterministic" else int(model.noise_dim)


@torch.no_grad()
def evaluate(model, cfg: DictConfig, nfe: int, t_end: float, env, seeds: list[int]) -> dict:
    """One closed-loop evaluation over ``seeds`` in ``env`` (from `make_env`, reset here); the
    row's ``per_seed`` lists each seed's success (0/1, in seed order). Each episode's prior noise
    comes from its own seed, so the row does not depend on ``eval.workers`` or
    ``eval.num_envs``."""
    actor = FlatBatch(make_env_actor(model, cfg, nfe, t_end))  # workers x envs -> one batch
    mode = (ExplorationType.DETERMINISTIC if cfg.eval.sampling == "deterministic"
            else ExplorationType.RANDOM)
    max_steps = int(cfg.eval.max_steps or ROBOSUITE_MAX_STEPS[cfg.task])
    torch.manual_seed(int(cfg.seed))
    start = time.perf_counter()
    with set_exploration_type(mode):
        out = env.rollout(max_steps, actor, break_when_any_done=False, break_when_all_done=True)
    out = flatten_workers(out, len(seeds))
    seconds = time.perf_counter() - start
    success = out["next", "success"][:, -1, 0].float()
    steps = out["next", "step_count"][:, -1, 0]
    raw = out.get("raw_action", out[keys.ACTION])
    jerks, manifold_err = [], 0.0
    for i in range(raw.shape[0]):
        executed = raw[i, : int(steps[i])].double()
        if executed.shape[0] >= 4:
            jerks.append(float(jerk(executed[:, :3], CONTROL_DT)))  # position part (m or units)
        if pose_action(cfg):
            manifold_err = max(manifold_err, float((executed[:, 3:7].norm(dim=-1) - 1).abs().max()))
    del out
    return {
        "task": cfg.task,
        "algo": cfg.algo,
        "action_space": cfg.action_space + ("" if not pose_action(cfg) else f"/{cfg.geometry}"),
        "nfe": nfe,
        "t_end": t_end,
        "t_reached": end_time(model, nfe, t_end),
        "success": float(success.mean()),
        "jerk": float(torch.tensor(jerks).mean()) if jerks else float("nan"),
        "quat_norm_err": manifold_err if pose_action(cfg) else float("nan"),
        "env_steps": int(steps.sum()),
        "seconds": seconds,
        "seeds": f"{seeds[0]}-{seeds[-1]}",
        "per_seed": [int(v) for v in success.tolist()],
        "per_seed_jerk": jerks,
    }


def _merge(parts: list[dict]) -> dict:
    """One row from the rows of consecutive seed chunks (same NFE and T)."""
    if len(parts) == 1:
        return parts[0]
    per_seed = [v for p in parts for v in p["per_seed"]]
    jerks = [v for p in parts for v in p["per_seed_jerk"]]
    row = dict(parts[0])
    row.update(
        success=sum(per_seed) / len(per_seed),
        jerk=sum(jerks) / len(jerks) if jerks else float("nan"),
        quat_norm_err=max(p["quat_norm_err"] for p in parts),  # nan stays nan (not a pose task)
        env_steps=sum(p["env_steps"] for p in parts),
        seconds=sum(p["seconds"] for p in parts),
        seeds=f"{parts[0]['seeds'].split('-')[0]}-{parts[-1]['seeds'].split('-')[-1]}",
        per_seed=per_seed,
        per_seed_jerk=jerks,
    )
    return row


def sweep(model, cfg: DictConfig, progress=None) -> list[dict]:
    """Every (NFE, T) of ``cfg.eval`` on ``eval.seeds`` seeds, stepped `eval_num_envs` at a time
    (one env per chunk of seeds, built once for all settings, over ``eval.workers``
    processes)."""
    seeds = list(range(int(cfg.eval.seed_start), int(cfg.eval.seed_start) + int(cfg.eval.seeds)))
    size = eval_num_envs(cfg)
    chunks = [seeds[i:i + size] for i in range(0, len(seeds), size)]
    settings = list(sweep_settings(model, cfg.eval.nfes, cfg.eval.t_ends,
                                   cfg.eval.get("time_table")))
    parts: list[list[dict]] = [[] for _ in settings]
    for chunk in chunks:
        env, _ = make_env(cfg, chunk, _noise_dim(model, cfg))
        try:
            for k, (nfe, t_end) in enumerate(settings):
                parts[k].append(evaluate(model, cfg, nfe, t_end, env, chunk))
                if len(chunks) > 1:
                    print(f"  NFE={nfe} T={t_end:g}: seeds {chunk[0]}-{chunk[-1]} done "
                          f"({sum(parts[k][-1]['per_seed'])}/{len(chunk)} successes)")
        finally:
            env.close()
    rows = []
    for k in range(len(settings)):
        rows.append(_merge(parts[k]))
        if progress is not None:
            progress(rows[-1])
    return rows


def write_tables(rows: list[dict], out_dir: Path, title: str, command: str) -> Path:
    out_dir.mkdir(parents=True, exist_ok=True)
    with open(out_dir / "eval.csv", "w", newline="") as f:
        fields = [k for k in rows[0] if not k.startswith("per_seed")]
        writer = csv.DictWriter(f, fieldnames=fields, extrasaction="ignore")
        writer.writeheader()
        writer.writerows(rows)
    lines = [f"## {title}", "", f"Command: `{command}`", "",
             "| task | algo | actions | NFE | T | success | jerk (pos, /s^3) | max abs(norm(q)-1) "
             "| env steps | s |", "|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        err = "-" if math.isnan(r["quat_norm_err"]) else f"{r['quat_norm_err']:.1e}"
        lines.append(f"| {r['task']} | {r['algo']} | {r['action_space']} | {r['nfe']} | "
                     f"{r['t_end']:g} | {r['success']:.2f} | {r['jerk']:.3g} | {err} | "
                     f"{r['env_steps']} | {r['seconds']:.0f} |")
    (out_dir / "eval.md").write_text("\n".join(lines) + "\n")
    return out_dir / "eval.md"
