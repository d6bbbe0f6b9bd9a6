"""The training-time options of the losses: how flow times are drawn, the SRFMP rates, and the
Consistency Policy's teacher.

`LossConfig` is what `make_loss` and the losses take beside the actor, what checkpoints store
under ``payload["loss"]`` and what the recipes' ``loss`` settings map onto. The policy network's
architecture and inference settings stay in `rfmp_rl.modules.ModelConfig`.

Example:
    >>> cfg = LossConfig(time_sampling="tau", time_max=3.0).check("srfmp")
    >>> LossConfig.from_dict(cfg.to_dict()) == cfg
    True
    >>> LossConfig(time_max=2.0).check("rfmp")
    Traceback (most recent call last):
    ...
    ValueError: LossConfig.time_max must be > 0, and 1 for RFMP (its path ends at t = 1), ...
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import asdict, dataclass, fields
from typing import Any

import torch

from rfmp_rl.flows import StablePath, sample_time, sample_time_via_tau

__all__ = ["LossConfig", "TIME_SAMPLINGS"]

#: How training flow times are drawn: t uniform, or (SRFMP) pseudo-time tau uniform.
TIME_SAMPLINGS = ("uniform", "tau")

_ALGORITHMS = ("rfmp", "srfmp", "ddim", "cp")


@dataclass
class LossConfig:
    """Training-time options of `RFMPLoss`, `SRFMPLoss`, `DiffusionPolicyLoss` and
    `ConsistencyDistillationLoss`.

    ``check(algorithm)`` validates them for one algorithm (the losses call it).

    Example:
        >>> LossConfig().to_dict()  # doctest: +NORMALIZE_WHITESPACE
        {'time_sampling': 'uniform', 'time_max': 1.0, 't0_fraction': 0.0,
         'lambda_x': 2.5, 'lambda_tau': 2.5, 'teacher': None, 'teacher_step': 10}
    """

    time_sampling: str = "uniform"  # uniform | tau (SRFMP only: tau uniform in pseudo-time)
    time_max: float = 1.0  # SRFMP: train on t in [0, time_max]; > 1 teaches the field to hold
    t0_fraction: float = 0.0  # RFMP/SRFMP: share of training times set to t = 0 (`sample_times`)
    lambda_x: float = 2.5  # SRFMP spatial rate of the stable path (must match the model's)
    lambda_tau: float = 2.5  # SRFMP pseudo-time rate of the stable path
    teacher: str | None = None  # CP: the ddim checkpoint distilled (its path)
    teacher_step: int = 10  # CP: diffusion steps of the teacher's DDIM step between the two times

    def check(self, algorithm: str) -> LossConfig:
        """Raise a ``ValueError`` naming the field if a setting does not apply to ``algorithm``
        (``rfmp``, ``srfmp``, ``ddim`` or ``cp``); returns ``self``."""
        if algorithm not in _ALGORITHMS:
            raise ValueError(f"LossConfig.check: algorithm must be one of {_ALGORITHMS}, "
                             f"got {algorithm!r}")
        if self.time_sampling not in TIME_SAMPLINGS:
            raise ValueError(f"LossConfig.time_sampling must be 'uniform' or 'tau', got "
                             f"{self.time_sampling!r}")
        if self.time_sampling == "tau" and algorithm != "srfmp":
            raise ValueError(f"LossConfig.time_sampling='tau' draws SRFMP pseudo-times; "
                             f"{algorithm} takes 'uniform'")
        if self.time_max <= 0 or (algorithm != "srfmp" and self.time_max != 1.0):
            raise ValueError(
                f"LossConfig.time_max must be > 0, and 1 for RFMP (its path ends at t = 1), "
                f"got {self.time_max} for {algorithm}"
            )
        if not 0.0 <= self.t0_fraction < 1.0 or (algorithm in ("ddim", "cp")
                                                  and self.t0_fraction):
            raise ValueError(
                f"LossConfig.t0_fraction must lie in [0, 1) and is for the flows (rfmp, srfmp), "
                f"got {self.t0_fraction} for {algorithm}"
            )
        for name in ("lambda_x", "lambda_tau"):
            if not float(getattr(self, name)) > 0:
                raise ValueError(f"LossConfig.{name} must be > 0, got {getattr(self, name)}")
        if self.teacher is not None and algorithm != "cp":
            raise ValueError(f"LossConfig.teacher is the Consistency Policy's (cp) teacher, got "
                             f"{self.teacher!r} for {algorithm}")
        if int(self.teacher_step) != self.teacher_step or self.teacher_step < 1:
            raise ValueError(f"LossConfig.teacher_step must be a positive integer, got "
                             f"{self.teacher_step!r}")
        return self

    def sample_times(
        self, batch: int, path=None, device=None, dtype=None
    ) -> torch.Tensor:
        """Training flow times ``(B, 1)``.

        ``t ~ U[0, time_max]`` (or uniform in tau with ``time_sampling='tau'``, which needs the
        SRFMP ``path``); then a share ``t0_fraction`` of them is set to exactly ``t = 0``. That
        is where every sample takes its first step, and a one-step (NFE = 1) SRFMP sample its
        only one: there the field must map a prior draw straight to its target
        (``x1 = Exp_x0(v / lambda_x)``), which uniform times visit rarely.
        """
        if self.time_sampling == "tau":
            if not isinstance(path, StablePath):
                raise ValueError("LossConfig.time_sampling='tau' needs the SRFMP StablePath")
            t = sample_time_via_tau(path, batch, t_max=self.time_max, device=device, dtype=dtype)
        else:
            t = self.time_max * sample_time(batch, device=device, dtype=dtype)
        if self.t0_fraction > 0:
            at_start = torch.rand(t.shape, device=t.device) < self.t0_fraction
            t = t.masked_fill(at_start, 0.0)
        return t

    def trained_tau_max(self, path: StablePath) -> float:
        """The largest pseudo-time these settings train SRFMP at: tau of ``path`` at
        ``time_max`` (`ModelConfig.tau_max`)."""
        return float(path.tau_at(torch.tensor(float(self.time_max))))

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: Mapping[str, Any] | None) -> LossConfig:
        """From `to_dict`'s output (None: the defaults); an unknown field raises, naming it."""
        data = dict(data or {})
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise ValueError(f"LossConfig: unknown fields {unknown} (known: {sorted(known)})")
        return cls(**data)
