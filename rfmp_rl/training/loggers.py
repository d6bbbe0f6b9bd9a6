"""TorchRL loggers chosen by name: ``csv`` (default), ``tensorboard``, ``wandb`` or ``none``."""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

__all__ = ["make_logger", "LOGGER_BACKENDS"]

LOGGER_BACKENDS = ("csv", "tensorboard", "wandb", "none")


def make_logger(cfg, run_dir: Path, hparams: Mapping[str, Any] | None = None,
                state: Mapping[str, Any] | None = None):
    """A TorchRL logger writing under ``run_dir`` (``logs/`` for csv and tensorboard, wandb's
    own folder for wandb), with the run configuration as hyper-parameters.

    Args:
        cfg: a `rfmp_rl.training.LoggerConfig` (``backend``, ``project``, ``wandb_mode``).
        run_dir: the run folder.
        hparams: the configuration to record (logged on a new run only).
        state: a logger ``state_dict()`` saved in ``last.pt``: a resumed run continues the same
            logs (CSV files appended, the same wandb run id).
    """
    from torchrl.record.loggers import get_logger

    backend = cfg.backend
    if backend not in LOGGER_BACKENDS:
        raise ValueError(f"logger.backend={backend!r}: use one of {LOGGER_BACKENDS}")
    if backend == "none":
        return None
    kwargs = {}
    if backend == "wandb":
        if cfg.wandb_mode not in ("online", "offline"):
            raise ValueError(f"logger.wandb_mode={cfg.wandb_mode!r}: use online or offline")
        if cfg.wandb_mode == "offline":
            os.environ.setdefault("WANDB_MODE", "offline")
        kwargs["wandb_kwargs"] = {"project": cfg.project, "offline": cfg.wandb_mode == "offline"}
    try:
        logger = get_logger(backend, logger_name=str(run_dir), experiment_name="logs",
                            state_dict=dict(state) if state else None, **kwargs)
    except ImportError as err:
        raise ValueError(f"logger.backend={backend}: {err} (pip install {backend})") from err
    if hparams and not state:
        logger.log_hparams(dict(hparams))
    return logger
