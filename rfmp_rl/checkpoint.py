"""Checkpoints: one file with weights, EMA weights, normalisers, manifold spec, horizons, config.

Writes are atomic: the payload goes to a temporary file in the same folder, is flushed to disk,
and only then renamed over the target (``os.replace``), so a crash or a kill during a save never
leaves a half-written checkpoint — the previous one stays readable.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import torch

from rfmp_rl import __version__
from rfmp_rl.modules.ema import EMA
from rfmp_rl.modules.policy_model import (
    DiffusionModel,
    FlowModel,
    ModelConfig,
    build_model,
    unwrap_policy_model,
)
from rfmp_rl.solvers import SolverConfig

__all__ = ["save_checkpoint", "load_checkpoint", "read_checkpoint", "CHECKPOINT_FORMAT"]

CHECKPOINT_FORMAT = "rfmp_rl.checkpoint/1"


def save_checkpoint(
    path: str | os.PathLike,
    model: FlowModel | DiffusionModel,
    ema: EMA | None = None,
    config: Mapping[str, Any] | None = None,
    training_state: Mapping[str, Any] | None = None,
    solver: SolverConfig | None = None,
    **extra: Any,
) -> Path:
    """Atomically write a checkpoint.

    Args:
        path: destination file.
        model: the trained network (its normalisers are part of its state), or a `FlowPolicy`
            / ``MultiStepActorWrapper`` around it.
        ema: the EMA of the weights, if any.
        config: the run configuration (plain, JSON-like values), stored for reproducibility.
        training_state: what a resumed run needs beyond the weights (optimiser, step, RNG
            states; written by `rfmp_rl.training.Trainer` into ``last.pt``).
        solver: the inference budget the policy is meant to run with (stored resolved;
            default: the algorithm's defaults at NFE 1). `FlowPolicy.from_checkpoint` and
            ``export/to_onnx.py`` start from it.
        **extra: further plain values (epoch, step, validation loss, ...).

    Returns:
        The path written.

    Example:
        >>> from rfmp_rl.modules import ModelConfig, build_model
        >>> model = build_model(ModelConfig("srfmp", "S2", obs_dim=3, horizon=4, action_steps=2,
        ...                                 down_dims=[32, 64]))
        >>> p = save_checkpoint("ckpt.pt", model, epoch=3)
        >>> load_checkpoint(p)[0].cfg.algorithm
        'srfmp'
    """
    path = Path(path)
    model = unwrap_policy_model(model, "save_checkpoint")
    path.parent.mkdir(parents=True, exist_ok=True)
    cfg: ModelConfig = model.cfg
    payload = {
        "format": CHECKPOINT_FORMAT,
        "rfmp_rl_version": __version__,
        "algorithm": cfg.algorithm,
        "manifold": model.step_manifold.spec(),
        "horizons": {"T_p": cfg.horizon, "T_a": cfg.action_steps, "T_o": cfg.obs_horizon},
        "model_config": cfg.to_dict(),
        "state_dict": model.state_dict(),
        "ema_state_dict": ema.module.state_dict() if ema is not None else None,
        "ema_num_updates": int(ema.num_updates) if ema is not None else 0,
        "config": dict(config) if config is not None else {},
        "solver": (solver or SolverConfig()).resolve(cfg.algorithm).to_dict(),
        "extra": extra,
    }
    if training_state is not None:
        payload["training_state"] = dict(training_state)
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    try:
        with open(tmp, "wb") as f:
            torch.save(payload, f)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()
    return path


def read_checkpoint(path: str | os.PathLike) -> dict[str, Any]:
    """Load and validate a checkpoint's payload (no model is built)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"checkpoint not found: {path}")
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as err:  # truncated or foreign file
        raise ValueError(f"{path}: not a readable rfmp_rl checkpoint ({err})") from err
    if not isinstance(payload, dict) or payload.get("format") != CHECKPOINT_FORMAT:
        found = payload.get("format") if isinstance(payload, dict) else type(payload).__name__
        raise ValueError(f"{path}: expected format {CHECKPOINT_FORMAT!r}, found {found!r}")
    for key in ("model_config", "state_dict"):
        if key not in payload:
            raise ValueError(f"{path}: checkpoint lacks the {key!r} entry")
    return payload


def load_checkpoint(
    path: str | os.PathLike, use_ema: bool = True
) -> tuple[FlowModel | DiffusionModel, dict[str, Any]]:
    """Rebuild the policy network from a checkpoint.

    Args:
        path: checkpoint file.
        use_ema: load the EMA weights when the checkpoint has them (what one evaluates and
            deploys); otherwise the raw training weights.

    Returns:
        ``(model in eval mode, payload)``.
    """
    payload = read_checkpoint(path)
    model = build_model(payload["model_config"])
    state = payload["state_dict"]
    if use_ema and payload.get("ema_state_dict") is not None:
        state = payload["ema_state_dict"]
    missing, unexpected = model.load_state_dict(state, strict=False)
    if missing or unexpected:
        raise ValueError(
            f"{path}: weights do not match the stored model config "
            f"(missing {sorted(missing)[:5]}, unexpected {sorted(unexpected)[:5]})"
        )
    return model.eval(), payload
