"""Checkpoints: one file with weights, EMA weights, normalisers, manifold spec, horizons, the
model config, the loss config (training-time options), the solver and the control rate.

Checkpoints written before `LossConfig` existed held the training options and the control rate
in their model config; `read_checkpoint` (and so `load_checkpoint`) moves them to the ``loss``
and ``control_rate_hz`` entries (`split_legacy_model_config`).

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
    MOVED_FIELDS,
    DiffusionModel,
    FlowModel,
    ModelConfig,
    build_model,
    unwrap_policy_model,
)
from rfmp_rl.objectives.config import LossConfig
from rfmp_rl.solvers import SolverConfig

__all__ = ["save_checkpoint", "load_checkpoint", "read_checkpoint", "split_legacy_model_config",
           "CHECKPOINT_FORMAT"]

CHECKPOINT_FORMAT = "rfmp_rl.checkpoint/1"


def save_checkpoint(
    path: str | os.PathLike,
    model: FlowModel | DiffusionModel,
    ema: EMA | None = None,
    config: Mapping[str, Any] | None = None,
    training_state: Mapping[str, Any] | None = None,
    solver: SolverConfig | None = None,
    loss: LossConfig | None = None,
    control_rate_hz: float | None = None,
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
        loss: the training-time options the model was trained with (`LossConfig`, or a loss
            module holding one), stored as ``payload["loss"]`` (None when not given).
        control_rate_hz: the rate the policy's actions are executed at (the environment's),
            stored as ``payload["control_rate_hz"]``; the exporter writes it into the ONNX
            metadata unless told another rate.
        **extra: further plain values (epoch, step, validation loss, ...).

    Returns:
        The path written.

    Example:
        >>> from rfmp_rl.modules import ModelConfig, build_model
        >>> model = build_model(ModelConfig("srfmp", "S2", obs_dim=3, horizon=4, action_steps=2,
        ...                                 down_dims=[32, 64]))
        >>> from rfmp_rl.objectives import LossConfig
        >>> p = save_checkpoint("ckpt.pt", model, loss=LossConfig(time_max=2.0),
        ...                     control_rate_hz=10.0, epoch=3)
        >>> load_checkpoint(p)[0].cfg.algorithm, read_checkpoint(p)["loss"]["time_max"]
        ('srfmp', 2.0)
    """
    path = Path(path)
    model = unwrap_policy_model(model, "save_checkpoint")
    path.parent.mkdir(parents=True, exist_ok=True)
    cfg: ModelConfig = model.cfg
    loss = getattr(loss, "loss_cfg", loss)  # a loss module: its options
    if loss is not None and not isinstance(loss, LossConfig):
        raise TypeError(f"save_checkpoint: loss must be a LossConfig or a loss module, got "
                        f"{type(loss).__name__}")
    if control_rate_hz is not None and not float(control_rate_hz) > 0:
        raise ValueError(f"save_checkpoint: control_rate_hz must be > 0, got {control_rate_hz}")
    payload = {
        "format": CHECKPOINT_FORMAT,
        "rfmp_rl_version": __version__,
        "algorithm": cfg.algorithm,
        "manifold": model.step_manifold.spec(),
        "horizons": {"T_p": cfg.horizon, "T_a": cfg.action_steps, "T_o": cfg.obs_horizon},
        "model_config": cfg.to_dict(),
        "loss": loss.to_dict() if loss is not None else None,
        "control_rate_hz": float(control_rate_hz) if control_rate_hz is not None else None,
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


def split_legacy_model_config(
    data: Mapping[str, Any],
) -> tuple[dict[str, Any], dict[str, Any] | None, float | None]:
    """Split a model config dict written before `LossConfig` existed.

    Returns ``(model config dict, loss config dict or None, control rate or None)``: the
    training options (``time_sampling``, ``time_max``, ``t0_fraction``, ``lambda_tau``, with the
    model's ``lambda_x``) go to the loss config, ``control_rate_hz`` to the rate. A dict without
    them comes back unchanged with ``(None, None)``.

    Example:
        >>> old = ModelConfig("srfmp", "S2", obs_dim=3, horizon=4).to_dict()
        >>> old.update(time_sampling="tau", time_max=3.0, t0_fraction=0.0, lambda_tau=2.5,
        ...            control_rate_hz=10.0)
        >>> model_cfg, loss_cfg, rate = split_legacy_model_config(old)
        >>> ModelConfig.from_dict(model_cfg).algorithm, loss_cfg["time_max"], rate
        ('srfmp', 3.0, 10.0)
    """
    model = dict(data)
    moved = {k: model.pop(k) for k in list(model) if k in MOVED_FIELDS}
    if not moved:
        return model, None, None
    rate = moved.pop("control_rate_hz", None)
    loss = None
    if moved:
        loss = dict(moved)
        loss["lambda_x"] = model.get("lambda_x", LossConfig.lambda_x)
        loss = LossConfig.from_dict(loss).to_dict()
    return model, loss, (float(rate) if rate is not None else None)


def read_checkpoint(path: str | os.PathLike) -> dict[str, Any]:
    """Load and validate a checkpoint's payload (no model is built).

    A checkpoint written before `LossConfig` existed is converted in memory (the file is left
    as it is): its model config's training options become the ``loss`` entry and its
    ``control_rate_hz`` the ``control_rate_hz`` entry (`split_legacy_model_config`). A ``loss``
    entry written before a `LossConfig` option existed (the Consistency Policy's ``teacher``,
    ``teacher_step``) reads with that option's default, so such a run resumes as it was.
    """
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
    model_cfg, loss, rate = split_legacy_model_config(payload["model_config"])
    payload["model_config"] = model_cfg
    if payload.get("loss") is None:
        payload["loss"] = loss
    if payload["loss"] is not None:  # options added since it was written: their defaults
        payload["loss"] = {**LossConfig().to_dict(), **payload["loss"]}
    if payload.get("control_rate_hz") is None:
        payload["control_rate_hz"] = rate
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
    try:
        model = build_model(payload["model_config"])
    except (TypeError, ValueError) as err:
        raise ValueError(f"{path}: cannot rebuild the model from its config: {err}") from err
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
