"""The training engine every recipe calls: one update step, EMA, the learning-rate rule,
validation and checkpoint selection, logging, checkpoints and resume, on any device, in any
precision, compiled or eager, in one process or under ``torchrun`` (DDP).

    runtime = setup_runtime(cfg.device, cfg.precision, cfg.compile)
    trainer = Trainer(model, train_rb, val_rb, runtime=runtime, run_dir=run_dir, recipe="pusht",
                      optim=OptimConfig.from_config(cfg.optim),
                      train=TrainConfig.from_config(cfg.train), config=cfg_as_dict,
                      seed=cfg.seed, resume=None)
    result = trainer.fit()

One step (``update``)::

    batch = rb.sample() -> device (pinned, non-blocking)      # each rank its own batches
    loss  = sum of the loss_* entries (networks under autocast, manifold maps in fp32)
    backward (DDP all-reduces the gradients; fp16: scaled)    # mean over ranks
    AdamW step at lr(step, progress); EMA update              # identical on every rank

Rank 0 alone validates, logs and writes checkpoints. ``last.pt`` is written atomically every
``checkpoint_every`` steps, at the end, and when SIGTERM / SIGINT arrives (the step in flight
finishes first); it holds what a resumed run needs to continue exactly where this one stopped:
weights, EMA, optimiser, gradient scaler, step, elapsed minutes, the best score so far, the
history, the logger's counters and every rank's RNG states (torch, CUDA, numpy, python, the
replay buffer's sampler).

Epochs: one epoch is one pass over the training windows at the global batch,
``ceil(windows / (batch_size x world_size))`` steps, where ``windows`` is ``len(data)`` (one
window per stored step for a `DemonstrationStore` replay buffer: every step is a reference step
of its sampler). ``train.epochs`` sets the budget to ``epochs x steps per epoch`` (it wins over
``train.steps``); ``train.snapshot_every_epochs`` makes rank 0 write ``snapshots/epoch_010.pt``,
... (the checkpoint best.pt would be at that step: weights and EMA weights, loadable by the
recipes' eval.py) as those epochs end. A resumed run keeps the snapshots it has and never
rewrites one.
"""

from __future__ import annotations

import json
import math
import signal
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

import torch
import torch.distributed as dist
from tensordict import TensorDictBase
from torch import nn
from torch.nn.parallel import DistributedDataParallel
from tqdm import tqdm

from rfmp_rl.checkpoint import read_checkpoint, save_checkpoint
from rfmp_rl.modules.ema import EMA
from rfmp_rl.objectives import LossConfig, make_loss
from rfmp_rl.solvers import SolverConfig
from rfmp_rl.training.loggers import make_logger
from rfmp_rl.training.resume import check_resumable
from rfmp_rl.training.runtime import Runtime, rank_seed, rng_state, set_rng_state

__all__ = ["OptimConfig", "TrainConfig", "LoggerConfig", "FitResult", "Trainer", "lr_at",
           "validation_loss", "compile_networks", "check_resumable", "steps_per_epoch",
           "snapshot_path", "SNAPSHOT_DIR"]

#: The folder of a run's epoch snapshots (``<run>/snapshots/epoch_010.pt``, ...).
SNAPSHOT_DIR = "snapshots"


def snapshot_path(run_dir: str | Path, epoch: int) -> Path:
    """Where a run keeps the snapshot taken as ``epoch`` ends.

    Example:
        >>> snapshot_path("runs/x", 10).as_posix()
        'runs/x/snapshots/epoch_010.pt'
    """
    return Path(run_dir) / SNAPSHOT_DIR / f"epoch_{int(epoch):03d}.pt"


def _pick(cls, mapping: Mapping[str, Any] | None):
    """A dataclass from the matching keys of ``mapping`` (recipes keep extra keys alongside)."""
    names = {f.name for f in fields(cls)}
    return cls(**{k: v for k, v in dict(mapping or {}).items() if k in names})


@dataclass
class OptimConfig:
    """AdamW and the EMA (the paper: lr 1e-4, weight decay 1e-3, EMA 0.999)."""

    lr: float = 1.0e-4
    weight_decay: float = 1.0e-3
    warmup_steps: int = 500  # linear warm-up, then a cosine decay to 0
    ema_decay: float = 0.999

    @classmethod
    def from_config(cls, mapping) -> OptimConfig:
        return _pick(cls, mapping)


@dataclass
class TrainConfig:
    """The loop's budget and cadence (``batch_size`` is per rank: the global batch is
    ``batch_size x world_size``).

    The budget is ``steps``, or with ``epochs`` set ``epochs x`` `steps_per_epoch` (``epochs``
    wins; ``steps`` is then ignored); ``max_minutes`` caps either. ``snapshot_every_epochs``
    keeps ``snapshots/epoch_NNN.pt`` as every such epoch ends (see the module docstring).

    Example:
        >>> TrainConfig(epochs=50, snapshot_every_epochs=10).counts_epochs
        True
    """

    steps: int = 12000
    max_minutes: float = math.inf  # wall-clock cap; the lr decay follows whichever ends first
    batch_size: int = 256
    val_every: int = 500
    val_batches: int = 8
    log_every: int = 50
    checkpoint_every: int = 500  # last.pt (resumable) every this many steps
    select_by: str = "val_loss"  # best.pt: val_loss (lowest) | rollout (highest score)
    epochs: int | None = None  # when set, the budget is epochs x steps per epoch (not steps)
    snapshot_every_epochs: int | None = None  # snapshots/epoch_NNN.pt every this many epochs

    def __post_init__(self) -> None:
        for name in ("steps", "batch_size", "val_every", "val_batches", "log_every",
                     "checkpoint_every"):
            if int(getattr(self, name)) < 1:
                raise ValueError(f"train.{name} must be >= 1, got {getattr(self, name)}")
        for name in ("epochs", "snapshot_every_epochs"):
            value = getattr(self, name)
            if value is not None and (isinstance(value, bool) or int(value) != value
                                      or int(value) < 1):
                raise ValueError(f"train.{name} must be null or an integer >= 1, got {value!r}")
        if self.max_minutes is None:
            self.max_minutes = math.inf
        if float(self.max_minutes) <= 0:
            raise ValueError(f"train.max_minutes must be > 0, got {self.max_minutes}")
        if self.select_by not in ("val_loss", "rollout"):
            raise ValueError(f"train.select_by must be 'val_loss' or 'rollout', got "
                             f"{self.select_by!r}")

    @classmethod
    def from_config(cls, mapping) -> TrainConfig:
        return _pick(cls, mapping)

    @property
    def counts_epochs(self) -> bool:
        """Whether the run needs its steps per epoch (an epoch budget or epoch snapshots)."""
        return self.epochs is not None or self.snapshot_every_epochs is not None


def steps_per_epoch(windows: int, batch_size: int, world_size: int = 1) -> int:
    """Optimiser steps of one pass over ``windows`` training windows at the global batch
    ``batch_size x world_size`` (the last batch of an epoch may be partly a repeat).

    Example:
        >>> steps_per_epoch(1000, 256), steps_per_epoch(1000, 256, world_size=2)
        (4, 2)
    """
    if int(windows) < 1:
        raise ValueError(f"an epoch needs at least one training window, got {windows}")
    return math.ceil(int(windows) / (int(batch_size) * int(world_size)))


@dataclass
class LoggerConfig:
    """A TorchRL logger: ``csv`` (default), ``tensorboard``, ``wandb`` or ``none``."""

    backend: str = "csv"
    project: str = "rfmp_rl"  # wandb project
    wandb_mode: str = "online"  # online | offline (no network; `wandb sync` uploads later)

    @classmethod
    def from_config(cls, mapping) -> LoggerConfig:
        if isinstance(mapping, str):
            return cls(backend=mapping)
        return _pick(cls, mapping)


@dataclass
class FitResult:
    steps: int
    minutes: float
    best: float  # the lowest validation loss, or the highest rollout score
    best_step: int
    interrupted: str | None = None  # the signal that stopped the run ("SIGTERM"), if any
    history: list = field(default_factory=list)


def lr_at(optim: OptimConfig, step: int, progress: float) -> float:
    """Linear warm-up over ``warmup_steps``, then a cosine decay to 0 over the run's progress
    ``max(step / steps, minutes / max_minutes)`` (a wall-clock-capped run still ends at 0)."""
    progress = min(max(progress, 0.0), 1.0)
    warm = min(1.0, step / max(1, int(optim.warmup_steps)))
    return optim.lr * warm * 0.5 * (1 + math.cos(math.pi * progress))


def _total_loss(out: TensorDictBase) -> torch.Tensor:
    return sum(v for k, v in out.items() if k.startswith("loss_"))


def validation_loss(loss_fn, data, batches: int, seed: int, runtime: Runtime | None = None
                    ) -> float:
    """Mean loss over ``batches`` fixed batches with fixed noise (comparable across calls);
    the global RNG streams are left as they were."""
    generator = getattr(getattr(data, "sampler", None), "generator", None)
    saved = generator.get_state() if generator is not None else None
    if generator is not None:
        generator.manual_seed(seed)
    total = 0.0
    with torch.random.fork_rng(), torch.no_grad():
        torch.manual_seed(seed)
        for _ in range(batches):
            batch = data.sample()
            if runtime is not None:
                batch = runtime.to_device(batch)
            total += float(_total_loss(loss_fn(batch)))
    if generator is not None:
        generator.set_state(saved)
    return total / batches


def compile_networks(model: nn.Module) -> nn.Module:
    """``torch.compile`` the network calls of a policy model in place (observation encoder and
    UNet; state-dict keys, manifold maps and solver stay as they are)."""
    model.network.compile()
    model.obs_encoder.compile()
    return model


class _StepLoss(nn.Module):
    """The summed loss as one module, so DDP sees one forward per step."""

    def __init__(self, loss_fn: nn.Module) -> None:
        super().__init__()
        self.loss_fn = loss_fn

    def forward(self, batch: TensorDictBase) -> torch.Tensor:
        return _total_loss(self.loss_fn(batch))


class _StopSignals:
    """SIGTERM / SIGINT set a flag (the loop saves and stops after the step in flight); a second
    SIGINT interrupts at once."""

    def __init__(self) -> None:
        self.received: str | None = None
        self._first = 0.0
        self._previous: dict = {}

    def __enter__(self) -> _StopSignals:
        if threading.current_thread() is threading.main_thread():
            for sig in (signal.SIGTERM, signal.SIGINT):
                self._previous[sig] = signal.signal(sig, self._handle)
        return self

    def _handle(self, signum, frame) -> None:
        name = signal.Signals(signum).name
        now = time.monotonic()
        # torchrun forwards the terminal's Ctrl-C to workers that already received it: only a
        # second SIGINT more than 2 s after the first interrupts at once
        if self.received == "SIGINT" and name == "SIGINT" and now - self._first > 2.0:
            raise KeyboardInterrupt
        if self.received is None:
            self.received, self._first = name, now

    def __exit__(self, *exc) -> None:
        for sig, handler in self._previous.items():
            signal.signal(sig, handler)


class Trainer:
    """Trains one policy model (see the module docstring for the step and the checkpoints).

    Args:
        model: a `FlowModel` or `DiffusionModel` with fitted normalisers (on the CPU is fine;
            it is moved to ``runtime.device``).
        data: the training batches: anything with ``sample() -> TensorDict`` (a TorchRL replay
            buffer); its ``sampler.generator``, when present, is saved and restored on resume.
            Under DDP each rank passes its own (seeded by seed and rank).
        val_data: the validation batches (rank 0 only; may be None on the other ranks).
        runtime: from `setup_runtime`.
        run_dir: where ``best.pt``, ``last.pt``, ``history.json`` and the logs go.
        recipe: the recipe's name, stored in ``last.pt`` and checked on resume.
        optim, train, logger: the settings.
        config: the run's whole configuration (plain values), stored in every checkpoint.
        seed: the validation noise seed.
        camera_keys: ``{camera: batch key}`` for the loss.
        rollout_score: ``f(ema_model) -> float`` (higher is better), computed at every
            validation on rank 0; with ``train.select_by=rollout`` it chooses ``best.pt``.
        resume: a ``last.pt`` to continue (see `rfmp_rl.training.resume`).
        solver: the inference budget stored in the checkpoints (what the run selects and
            evaluates with; default: the algorithm's defaults at NFE 1).
        loss: the training-time options of the loss (`rfmp_rl.objectives.LossConfig`; default:
            its defaults with the model's ``lambda_x``), stored in the checkpoints; a resumed
            run must keep them.
        control_rate_hz: the rate the environment executes actions at, stored in the
            checkpoints (the exporter writes it into the ONNX metadata).
        epoch_windows: the training windows one epoch passes over (default ``len(data)``);
            read only with ``train.epochs`` or ``train.snapshot_every_epochs``.

    Example:
        >>> from tensordict import TensorDict
        >>> from rfmp_rl.data import DemonstrationStore
        >>> from rfmp_rl.modules import ModelConfig, build_model
        >>> from rfmp_rl.training import setup_runtime
        >>> store = DemonstrationStore.from_episodes([TensorDict(
        ...     {"observation": torch.randn(20, 3), "action": torch.randn(20, 2)}, [20])])
        >>> rb = store.replay_buffer(4, ["observation"], batch_size=8)
        >>> model = build_model(ModelConfig("rfmp", "R2", obs_dim=3, horizon=4,
        ...                                 down_dims=[16, 32]))
        >>> trainer = Trainer(model, rb, rb, runtime=setup_runtime("cpu"), run_dir="run",
        ...                   recipe="toy", train=TrainConfig(steps=3, val_batches=1),
        ...                   logger=LoggerConfig("none"), progress=False)
        >>> trainer.fit().steps
        trained 3 steps in ...
        3
        >>> sorted(p.name for p in Path("run").iterdir())
        ['best.pt', 'history.json', 'last.pt', 'runtime.json']
    """

    def __init__(
        self,
        model: nn.Module,
        data,
        val_data,
        *,
        runtime: Runtime,
        run_dir: str | Path,
        recipe: str,
        optim: OptimConfig | None = None,
        train: TrainConfig | None = None,
        logger: LoggerConfig | None = None,
        config: Mapping[str, Any] | None = None,
        seed: int = 0,
        camera_keys: Mapping[str, Any] | None = None,
        rollout_score: Callable[[nn.Module], float] | None = None,
        resume: str | Path | None = None,
        progress: bool = True,
        solver: SolverConfig | None = None,
        loss: LossConfig | None = None,
        control_rate_hz: float | None = None,
        epoch_windows: int | None = None,
    ) -> None:
        self.runtime, self.recipe = runtime, recipe
        self.control_rate_hz = control_rate_hz
        self.solver = (solver or SolverConfig()).resolve(model.cfg.algorithm)
        self.optim_cfg, self.train_cfg = optim or OptimConfig(), train or TrainConfig()
        self.logger_cfg = logger or LoggerConfig()
        self.run_dir, self.config, self.seed = Path(run_dir), dict(config or {}), int(seed)
        self.data, self.val_data = data, val_data
        self.rollout_score, self.progress = rollout_score, progress
        if self.train_cfg.select_by == "rollout" and rollout_score is None:
            raise ValueError("train.select_by=rollout needs a rollout_score function")
        self.resume_state = None
        if resume is not None:  # checked before anything is built or written
            payload = read_checkpoint(resume)
            check_resumable(payload, resume, recipe, model.cfg.to_dict())
            stored, now = payload.get("loss"), loss.to_dict() if loss is not None else None
            if stored is not None and now is not None and stored != now:
                details = ", ".join(f"{k}: run {stored.get(k)!r} vs now {now[k]!r}"
                                    for k in sorted(now) if stored.get(k) != now[k])
                raise ValueError(f"resume={resume}: the run trained with other loss settings "
                                 f"({details}); resume with the run's settings")
            stored = payload["training_state"].get("select_by", self.train_cfg.select_by)
            if stored != self.train_cfg.select_by:
                raise ValueError(f"resume={resume}: train.select_by={self.train_cfg.select_by} "
                                 f"but the run keeps best.pt by {stored} (its best score is of "
                                 "that kind); resume with the run's setting")
            self.resume_state = payload
        self.epoch_windows, self.steps_per_epoch = self._epochs(data, epoch_windows)
        self.total_steps = (self.train_cfg.epochs * self.steps_per_epoch
                            if self.train_cfg.epochs is not None else int(self.train_cfg.steps))
        if self.train_cfg.snapshot_every_epochs is not None and resume is None:
            taken = sorted((self.run_dir / SNAPSHOT_DIR).glob("epoch_*.pt"))
            if taken:
                raise ValueError(f"{self.run_dir / SNAPSHOT_DIR} already holds snapshots "
                                 f"({taken[0].name}, ...) of another run: resume that run or "
                                 "choose another run folder")

        self.model = model.set_precision(runtime.precision).to(runtime.device)
        self.loss_fn = make_loss(self.model, loss, camera_keys)
        self.loss_cfg = self.loss_fn.loss_cfg
        step_loss = _StepLoss(self.loss_fn)
        if runtime.distributed:  # wrapping copies rank 0's weights and buffers to every rank
            ids = [runtime.device.index] if runtime.device.type == "cuda" else None
            step_loss = DistributedDataParallel(step_loss, device_ids=ids,
                                                forward_sync_buffers=False)
        self.step_loss = step_loss
        self.ema = EMA(self.model, decay=self.optim_cfg.ema_decay)  # after: the same on all ranks
        self.val_loss_fn = make_loss(self.ema.module, self.loss_cfg, camera_keys)
        if runtime.compile:
            compile_networks(self.model)
            compile_networks(self.ema.module)
        fused = runtime.device.type in ("cpu", "cuda")
        self.optimizer = torch.optim.AdamW(self.model.parameters(), lr=self.optim_cfg.lr,
                                           weight_decay=self.optim_cfg.weight_decay, fused=fused)
        self.scaler = torch.amp.GradScaler(runtime.device.type,
                                           enabled=runtime.precision == "fp16")
        self.step, self.minutes = 0, 0.0
        self.sign = -1.0 if self.train_cfg.select_by == "rollout" else 1.0  # minimise sign * x
        self.best, self.best_step, self.history = self.sign * math.inf, 0, []
        self.running: torch.Tensor | float | None = None  # smoothed training loss
        self.pending_validation = False  # stopped on a validation step before validating
        self.logger_state = None
        if self.resume_state is not None:
            self._load_state(self.resume_state)

    def _epochs(self, data, windows: int | None) -> tuple[int | None, int | None]:
        """``(training windows, steps per epoch)``, or ``(None, None)`` when the run counts no
        epochs; the data's own batch size must be ``train.batch_size`` (what an epoch uses)."""
        cfg = self.train_cfg
        if not cfg.counts_epochs:
            return None, None
        if windows is None:
            if not hasattr(data, "__len__"):
                raise ValueError("train.epochs / train.snapshot_every_epochs count epochs over "
                                 f"the training windows, but the training data "
                                 f"({type(data).__name__}) has no len(); pass epoch_windows")
            windows = len(data)
        sampled = getattr(data, "batch_size", None)
        if isinstance(sampled, int) and sampled != int(cfg.batch_size):
            raise ValueError(f"train.batch_size={cfg.batch_size} but the training data samples "
                             f"batches of {sampled}: an epoch would be miscounted")
        return int(windows), steps_per_epoch(windows, cfg.batch_size, self.runtime.world_size)

    # ----- checkpoints -------------------------------------------------------------------------
    def save_snapshot(self) -> Path | None:
        """Rank 0: write ``snapshots/epoch_NNN.pt`` for the epoch ending at this step (weights,
        EMA weights, step, epoch; as best.pt). A snapshot already there (a resumed run) is kept
        as it is; returns the path written, or None."""
        epoch = self.step // self.steps_per_epoch
        path = snapshot_path(self.run_dir, epoch)
        if not self.runtime.is_main or path.exists():
            return None
        return save_checkpoint(path, self.model, self.ema, self.config, step=self.step,
                               epoch=epoch, steps_per_epoch=self.steps_per_epoch,
                               train_minutes=self.minutes, solver=self.solver, loss=self.loss_cfg,
                               control_rate_hz=self.control_rate_hz)

    def _snapshot_due(self) -> bool:
        every = self.train_cfg.snapshot_every_epochs
        return every is not None and self.step % (int(every) * self.steps_per_epoch) == 0

    def _generators(self) -> dict[str, torch.Generator]:
        gen = getattr(getattr(self.data, "sampler", None), "generator", None)
        return {"sampler": gen} if gen is not None else {}

    def _gather_rng(self) -> list[dict]:
        """Every rank's RNG states, in rank order (a collective under DDP)."""
        mine = rng_state(self._generators())
        if not self.runtime.distributed:
            return [mine]
        gathered = [None] * self.runtime.world_size
        dist.all_gather_object(gathered, mine)
        return gathered

    def training_state(self, rng: list[dict], logger) -> dict:
        return {
            "recipe": self.recipe,
            "step": self.step,
            "minutes": self.minutes,
            "optimizer": self.optimizer.state_dict(),
            "scaler": self.scaler.state_dict(),
            "best": self.best,
            "best_step": self.best_step,
            "select_by": self.train_cfg.select_by,
            "history": self.history,
            "running": None if self.running is None else float(self.running),
            "pending_validation": bool(self.pending_validation),
            "world_size": self.runtime.world_size,
            "rng": rng,
            "logger": logger.state_dict() if logger is not None else None,
            "logger_backend": self.logger_cfg.backend,
        }

    def save_last(self, logger) -> None:
        """Write ``last.pt`` (collective under DDP: every rank must call it)."""
        rng = self._gather_rng()
        if self.runtime.is_main:
            save_checkpoint(self.run_dir / "last.pt", self.model, self.ema, self.config,
                            training_state=self.training_state(rng, logger), step=self.step,
                            train_minutes=self.minutes, solver=self.solver, loss=self.loss_cfg,
                            control_rate_hz=self.control_rate_hz)

    def _load_state(self, payload: dict) -> None:
        state = payload["training_state"]
        self.model.load_state_dict(payload["state_dict"])
        self.ema.module.load_state_dict(payload["ema_state_dict"])
        self.ema.set_num_updates(int(payload.get("ema_num_updates", 0)))
        self.optimizer.load_state_dict(state["optimizer"])
        if state["scaler"] and self.scaler.is_enabled():  # fp16 runs only (empty otherwise)
            self.scaler.load_state_dict(state["scaler"])
        self.step, self.minutes = int(state["step"]), float(state["minutes"])
        self.best, self.best_step = float(state["best"]), int(state["best_step"])
        self.history = list(state["history"])
        self.running = state.get("running")
        self.pending_validation = bool(state.get("pending_validation", False))
        rngs = state["rng"]
        if len(rngs) == self.runtime.world_size:
            set_rng_state(rngs[self.runtime.rank], self._generators())
        else:  # a different number of processes: fresh streams per rank, continued schedule
            fresh = rank_seed(self.seed + 7919 * self.step, self.runtime.rank)
            torch.manual_seed(fresh)
            for gen in self._generators().values():
                gen.manual_seed(fresh + 1)
            if self.runtime.is_main:
                print(f"resume: the run had {len(rngs)} process(es), this one has "
                      f"{self.runtime.world_size}; random streams restart (schedule, weights and "
                      "optimiser continue exactly)")
        if state.get("logger_backend") == self.logger_cfg.backend and state.get("logger"):
            # the logs stay with the run folder, wherever it has moved since
            self.logger_state = {**state["logger"], "log_dir": str(self.run_dir.resolve())}

    # ----- the loop ----------------------------------------------------------------------------
    def update(self, batch: TensorDictBase, lr: float) -> torch.Tensor:
        """One optimiser step on ``batch``; returns the (detached) loss."""
        for group in self.optimizer.param_groups:
            group["lr"] = lr
        loss = self.step_loss(self.runtime.to_device(batch))
        self.optimizer.zero_grad(set_to_none=True)
        self.scaler.scale(loss).backward()
        self.scaler.step(self.optimizer)
        self.scaler.update()
        self.ema.update(self.model)
        return loss.detach()

    def _agree(self, minutes: float, flag: bool) -> tuple[float, bool]:
        """Under DDP every rank acts on the same values: the largest elapsed minutes and any
        rank's flag (one small all-reduce on the CPU side group: no GPU sync)."""
        if not self.runtime.distributed:
            return minutes, flag
        t = torch.tensor([minutes, float(flag)], dtype=torch.float64)
        dist.all_reduce(t, op=dist.ReduceOp.MAX, group=self.runtime.cpu_group)
        return float(t[0]), bool(t[1])

    def _validate(self, logger) -> None:
        """Rank 0: validation loss (and rollout score) of the EMA weights; keeps best.pt."""
        model = self.ema.module
        val = validation_loss(self.val_loss_fn, self.val_data, self.train_cfg.val_batches,
                              self.seed, self.runtime)
        running = None if self.running is None else float(self.running)
        entry = {"step": self.step, "minutes": self.minutes, "train": running, "val": val}
        extra, criterion = {}, val
        if logger is not None:
            logger.log_scalar("val/loss", val, step=self.step)
        if self.rollout_score is not None:
            with torch.random.fork_rng():
                score = float(self.rollout_score(model))
            entry["rollout"] = extra["rollout_score"] = score
            if logger is not None:
                logger.log_scalar("val/rollout_score", score, step=self.step)
            if self.train_cfg.select_by == "rollout":
                criterion = score
        self.history.append(entry)
        if self.sign * criterion < self.sign * self.best or not self.best_step:
            self.best, self.best_step = criterion, self.step
            save_checkpoint(self.run_dir / "best.pt", self.model, self.ema, self.config,
                            step=self.step, val_loss=val, train_minutes=self.minutes,
                            solver=self.solver, loss=self.loss_cfg,
                            control_rate_hz=self.control_rate_hz, **extra)

    def fit(self) -> FitResult:
        rt, cfg = self.runtime, self.train_cfg
        main = rt.is_main
        logger = None
        if main:
            self.run_dir.mkdir(parents=True, exist_ok=True)
            logger = make_logger(self.logger_cfg, self.run_dir, self.config, self.logger_state)
            (self.run_dir / "runtime.json").write_text(json.dumps(self.runtime_info(), indent=1))
        self.model.train()
        # every rank starts the clock after the logger, and the minutes that drive the lr
        # schedule and the time cap are agreed (the maximum over ranks) after every step
        rt.barrier()
        start_minutes, clock = self.minutes, time.perf_counter()
        label = "score" if cfg.select_by == "rollout" else "val"
        total = self.total_steps
        if main and self.steps_per_epoch is not None:
            budget = (f"{cfg.epochs} epochs = {total} steps" if cfg.epochs is not None
                      else f"{total} steps")
            print(f"one epoch: {self.epoch_windows} training windows at global batch "
                  f"{cfg.batch_size * rt.world_size} = {self.steps_per_epoch} steps; {budget}")
        bar = tqdm(total=total, initial=self.step, desc=f"train {self.recipe}", unit="step",
                   dynamic_ncols=True, disable=not (main and self.progress))
        interrupted = None
        with _StopSignals() as signals:
            if self.pending_validation:  # the run stopped on a validation step before it ran
                self._validate_all(logger, signals)
            if self.step < total and self.minutes >= cfg.max_minutes and main:
                print(f"train.max_minutes={cfg.max_minutes} was reached at step {self.step} "
                      f"({self.minutes:.1f} min): nothing to train; raise it to continue")
            while self.step < total and self.minutes < cfg.max_minutes:
                self.step += 1
                progress = max(self.step / total, self.minutes / cfg.max_minutes)
                lr = lr_at(self.optim_cfg, self.step, progress)
                loss = self.update(self.data.sample(), lr)
                self.running = loss if self.running is None else 0.98 * self.running + 0.02 * loss
                bar.update(1)
                if self.step % cfg.log_every == 0 and main:
                    value = float(self.running)
                    if logger is not None:
                        logger.log_scalar("train/loss", value, step=self.step)
                        logger.log_scalar("train/lr", lr, step=self.step)
                    bar.set_postfix({"loss": f"{value:.4f}", f"best_{label}": f"{self.best:.4f}"})
                elapsed = start_minutes + (time.perf_counter() - clock) / 60
                self.minutes, signalled = self._agree(elapsed, signals.received is not None)
                time_up = self.minutes >= cfg.max_minutes
                last = self.step == total or time_up
                self.pending_validation = self.step % cfg.val_every == 0 or last
                if self.pending_validation and not signalled:
                    signalled = self._validate_all(logger, signals)
                if self._snapshot_due():
                    self.save_snapshot()
                if self.step % cfg.checkpoint_every == 0 or last or signalled:
                    self.save_last(logger)
                if signalled:
                    interrupted = signals.received or "signal on another rank"
                    if main:
                        print(f"\n{interrupted}: stopped at step {self.step}; last.pt holds the "
                              f"run; continue with resume={self.run_dir}")
                    break
                if time_up:
                    if main:
                        print(f"\nstopping at step {self.step}: train.max_minutes="
                              f"{cfg.max_minutes} reached")
                    break
        bar.close()
        if main:
            (self.run_dir / "history.json").write_text(json.dumps(self.history, indent=1))
            what = "rollout score" if cfg.select_by == "rollout" else "validation loss"
            if not interrupted:
                print(f"trained {self.step} steps in {self.minutes:.1f} min; best {what} "
                      f"{self.best:.4f} at step {self.best_step}")
            if logger is not None and self.logger_cfg.backend == "wandb":
                logger.experiment.finish()
        return FitResult(self.step, self.minutes, self.best, self.best_step, interrupted,
                         self.history)

    def _validate_all(self, logger, signals) -> bool:
        """Rank 0 validates while the others wait; returns whether a stop signal arrived (a
        signal during a rollout may end it early: the validation then counts as not run)."""
        if self.runtime.is_main:
            try:
                self._validate(logger)
                self.pending_validation = False
            except Exception:
                if signals.received is None:
                    raise
                print(f"\n{signals.received} during validation at step {self.step}: it runs "
                      "again when the run resumes")
        self.runtime.barrier()
        return self._agree(0.0, signals.received is not None)[1]

    def runtime_info(self) -> dict:
        """How the run executes (written to ``runtime.json``; the results' commands read it)."""
        return {"world_size": self.runtime.world_size, "device": str(self.runtime.device),
                "precision": self.runtime.precision, "compile": self.runtime.compile,
                "torch": torch.__version__}
