"""Where and how a run executes: device, precision, torch.compile, and the DDP process group.

One `Runtime` is made per process at start (`setup_runtime`) and handed to the training engine
and the evaluation helpers. Launched plainly, it is a single process; launched by ``torchrun``
(which sets ``RANK``, ``WORLD_SIZE``, ``LOCAL_RANK``, ``MASTER_ADDR``, ``MASTER_PORT``), it joins
the process group: ``gloo`` on CPU, ``nccl`` on CUDA, one GPU per local rank.

Precision applies to the networks only (`rfmp_rl.modules.PolicyModel.set_precision`): the
normalisers, the manifold maps of the losses, the solver and its projections, and the EMA stay
in float32, so sphere outputs stay on S^n to float32 accuracy whatever the precision.
"""

from __future__ import annotations

import os
import random
from dataclasses import dataclass
from datetime import timedelta

import numpy as np
import torch
import torch.distributed as dist
from tensordict import TensorDictBase

from rfmp_rl.modules.policy_model import PRECISIONS

__all__ = [
    "PRECISIONS",
    "Runtime",
    "check_settings",
    "setup_runtime",
    "resolve_device",
    "rank_seed",
    "rng_state",
    "set_rng_state",
]


def resolve_device(device: str) -> torch.device:
    """``auto`` (CUDA when present, else CPU), ``cpu``, ``cuda`` or ``cuda:N``; anything else,
    or CUDA on a machine without it, raises a `ValueError` naming the setting."""
    name = str(device).strip().lower()
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if name == "cpu":
        return torch.device("cpu")
    if name == "cuda" or (name.startswith("cuda:") and name[5:].isdigit()):
        if not torch.cuda.is_available():
            raise ValueError(f"device={device}: CUDA was requested but torch sees no CUDA device "
                             f"(torch {torch.__version__}); use device=cpu or device=auto")
        index = int(name[5:]) if ":" in name else 0
        if index >= torch.cuda.device_count():
            raise ValueError(f"device={device}: only {torch.cuda.device_count()} CUDA device(s) "
                             "are visible")
        return torch.device("cuda", index)
    raise ValueError(f"device={device!r} is not a device: use auto, cpu, cuda or cuda:N")


@dataclass
class Runtime:
    """The execution settings of one process.

    Attributes:
        device: where the networks and batches live.
        precision: ``fp32``, ``bf16`` or ``fp16`` (autocast of the networks).
        compile: whether the network calls are compiled with ``torch.compile``.
        rank, world_size, local_rank: the DDP coordinates (0, 1, 0 for a single process).

    Example:
        >>> rt = setup_runtime("cpu", "fp32", False)
        >>> rt.device.type, rt.world_size, rt.is_main
        ('cpu', 1, True)
    """

    device: torch.device
    precision: str = "fp32"
    compile: bool = False
    rank: int = 0
    world_size: int = 1
    local_rank: int = 0
    cpu_group: object = None  # a gloo group for small control messages (stop flags, minutes)

    @property
    def distributed(self) -> bool:
        return self.world_size > 1

    @property
    def is_main(self) -> bool:
        """Rank 0: the process that logs, validates, evaluates and writes checkpoints."""
        return self.rank == 0

    def to_device(self, batch: TensorDictBase) -> TensorDictBase:
        """Move a sampled batch to the device: pinned memory and a non-blocking copy on CUDA."""
        if self.device.type == "cpu":
            return batch
        if self.device.type == "cuda":
            batch = batch.pin_memory()
        return batch.to(self.device, non_blocking=True)

    def barrier(self) -> None:
        if self.distributed:
            dist.barrier()

    def shutdown(self) -> None:
        """Leave the process group (idempotent)."""
        if dist.is_available() and dist.is_initialized():
            dist.destroy_process_group()


def check_settings(device: str, precision: str) -> torch.device:
    """The device a ``device`` / ``precision`` pair runs on; a `ValueError` naming the setting
    for an unknown device or precision, CUDA without CUDA, or fp16 off CUDA."""
    if precision not in PRECISIONS:
        raise ValueError(f"precision={precision!r}: use one of {sorted(PRECISIONS)}")
    dev = resolve_device(device)
    if precision == "fp16" and dev.type != "cuda":
        raise ValueError(f"precision=fp16 needs a CUDA device (fp16 autocast with a gradient "
                         f"scaler; device={device} is {dev.type}); use precision=bf16 or fp32")
    return dev


def setup_runtime(device: str = "auto", precision: str = "fp32", compile: bool = False,
                  *, distributed: bool | None = None) -> Runtime:
    """Check the settings and, under ``torchrun``, join the process group.

    Args:
        device: ``auto | cpu | cuda | cuda:N``. Under torchrun with CUDA each process takes the
            GPU of its local rank (``cuda`` and ``auto`` alike).
        precision: ``fp32 | bf16 | fp16``; fp16 needs CUDA (it trains with a gradient scaler).
        compile: compile the network calls with ``torch.compile``.
        distributed: force (True) or forbid (False) DDP; default: when ``WORLD_SIZE`` > 1.

    Raises:
        ValueError: naming the setting, for an unknown device or precision, CUDA without CUDA,
            fp16 on CPU, or ``cuda:N`` under torchrun.
    """
    dev = check_settings(device, precision)
    world = int(os.environ.get("WORLD_SIZE", "1"))
    if distributed is None:
        distributed = world > 1
    if not distributed:
        return Runtime(dev, precision, bool(compile))
    local_rank = int(os.environ.get("LOCAL_RANK", "0"))
    if dev.type == "cuda":
        if ":" in str(device) and str(device).strip().lower() != "cuda":
            raise ValueError(f"device={device}: under torchrun every process uses the GPU of its "
                             "local rank; use device=cuda or device=auto")
        if local_rank >= torch.cuda.device_count():
            raise ValueError(f"LOCAL_RANK={local_rank} but only {torch.cuda.device_count()} "
                             "CUDA device(s) are visible on this node")
        dev = torch.device("cuda", local_rank)
        torch.cuda.set_device(dev)
    if not dist.is_initialized():
        # rank 0 validates and rolls out policies while the others wait at a barrier: allow an
        # hour before a silent rank counts as failed (NCCL's default is 10 minutes)
        dist.init_process_group(backend="nccl" if dev.type == "cuda" else "gloo",
                                device_id=dev if dev.type == "cuda" else None,
                                timeout=timedelta(minutes=60))
    # control messages go over gloo on the CPU: no GPU synchronisation per training step
    cpu_group = dist.new_group(backend="gloo") if dev.type == "cuda" else dist.group.WORLD
    return Runtime(dev, precision, bool(compile), dist.get_rank(), dist.get_world_size(),
                   local_rank, cpu_group)


def rank_seed(seed: int, rank: int) -> int:
    """The seed of rank ``rank``: rank 0 keeps ``seed`` (a single process is unchanged); the
    others are spread far apart so neighbouring run seeds never share a stream."""
    return int(seed) + 1_000_003 * int(rank)


# ----- RNG state (resume continues every stream where it stopped) ----------------------------
def rng_state(generators: dict[str, torch.Generator] | None = None) -> dict:
    """Every RNG state of this process: torch (CPU and every CUDA device), numpy, python, and
    the named ``generators`` (e.g. the replay buffer's sampler)."""
    np_state = np.random.get_state()  # noqa: NPY002 - the legacy global stream users seed
    state = {
        "torch": torch.get_rng_state(),
        # the training GPU's stream only (another machine may show a different GPU count)
        "cuda": torch.cuda.get_rng_state() if torch.cuda.is_available() else None,
        "numpy": {"name": np_state[0], "keys": torch.from_numpy(np_state[1].astype(np.int64)),
                  "pos": int(np_state[2]), "has_gauss": int(np_state[3]),
                  "cached_gaussian": float(np_state[4])},
        "python": random.getstate(),
        "generators": {k: g.get_state() for k, g in (generators or {}).items()},
    }
    return state


def set_rng_state(state: dict, generators: dict[str, torch.Generator] | None = None) -> None:
    """Restore what `rng_state` captured."""
    torch.set_rng_state(state["torch"])
    if isinstance(state.get("cuda"), torch.Tensor) and torch.cuda.is_available():
        torch.cuda.set_rng_state(state["cuda"])
    np_state = state["numpy"]
    np.random.set_state((np_state["name"], np_state["keys"].numpy().astype(np.uint32),  # noqa: NPY002
                         np_state["pos"], np_state["has_gauss"], np_state["cached_gaussian"]))
    py = state["python"]
    random.setstate((py[0], tuple(py[1]), py[2]))
    for name, gen in (generators or {}).items():
        if name in state.get("generators", {}):
            gen.set_state(state["generators"][name])
