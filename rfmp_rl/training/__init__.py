"""The one training engine (`Trainer`), its settings, the runtime (device, precision, compile,
DDP under torchrun) and resume."""

from rfmp_rl.training.engine import (
    SNAPSHOT_DIR,
    FitResult,
    LoggerConfig,
    OptimConfig,
    TrainConfig,
    Trainer,
    check_resumable,
    compile_networks,
    lr_at,
    snapshot_path,
    steps_per_epoch,
    validation_loss,
)
from rfmp_rl.training.loggers import LOGGER_BACKENDS, make_logger
from rfmp_rl.training.runtime import (
    PRECISIONS,
    Runtime,
    check_settings,
    rank_seed,
    resolve_device,
    rng_state,
    set_rng_state,
    setup_runtime,
)

__all__ = [
    "Trainer",
    "TrainConfig",
    "OptimConfig",
    "LoggerConfig",
    "FitResult",
    "check_resumable",
    "compile_networks",
    "lr_at",
    "validation_loss",
    "steps_per_epoch",
    "snapshot_path",
    "SNAPSHOT_DIR",
    "make_logger",
    "LOGGER_BACKENDS",
    "Runtime",
    "check_settings",
    "setup_runtime",
    "resolve_device",
    "rank_seed",
    "rng_state",
    "set_rng_state",
    "PRECISIONS",
]
