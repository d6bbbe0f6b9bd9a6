"""A policy's inference budget, defined once: method, NFE, end time T, schedule, refinement step.

`SolverConfig` is what `FlowPolicy`, the ONNX exporter (`rfmp_rl.onnx_export`), the evaluation
sweeps and the recipes read. Each algorithm's defaults live in `SolverConfig.resolve`:

- SRFMP: the paper's schedule (first step ``1 / lambda_x``, then refinement steps up to T);
- RFMP: ``NFE`` uniform steps covering ``[0, T]``;
- DDIM: ``NFE`` DDIM steps; the method, schedule and T do not apply (reported as ``ddim``,
  ``ddim`` and 1);
- CP (Consistency Policy): ``NFE`` consistency evaluations (one-step at NFE 1), reported as
  ``consistency``, ``consistency`` and T = 1.

Checkpoints store the solver they were selected and evaluated with (``payload["solver"]``), and
the ONNX metadata the one unrolled in the graph, so a policy loaded later integrates the same way
unless told otherwise (`FlowPolicy.from_checkpoint`).

Example:
    >>> solver = SolverConfig(nfe=3).resolve("srfmp")
    >>> solver.schedule, solver.step_sizes(lambda_x=2.5)
    ('srfmp', [0.4, 0.3, 0.3])
    >>> SolverConfig(nfe=3, t_end=1.6).resolve("rfmp").reached(lambda_x=2.5)
    1.6
    >>> SolverConfig.from_dict(SolverConfig(nfe=5).resolve("ddim").to_dict())
    SolverConfig(nfe=5, t_end=1.0, method='ddim', schedule='ddim', refine_dt=None)
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import asdict, dataclass, fields, replace
from typing import Any

from rfmp_rl.solvers.ode import EVALS_PER_STEP, step_sizes

__all__ = ["SolverConfig", "DEFAULT_SCHEDULES"]

#: Algorithm -> the schedule it integrates with when none is given.
DEFAULT_SCHEDULES = {"srfmp": "srfmp", "rfmp": "uniform", "ddim": "ddim", "cp": "consistency"}
#: The samplers that are not ODE methods: their NFE alone defines them.
SAMPLERS = ("ddim", "consistency")


@dataclass(frozen=True)
class SolverConfig:
    """How a policy turns prior noise into an action chunk.

    Attributes:
        nfe: network evaluations per chunk (DDIM: denoising steps).
        t_end: end time T of the integration (flows; may exceed 1).
        method: ``euler`` (the paper's), ``euler_projx``, ``midpoint`` or ``rk4``.
        schedule: ``uniform`` or ``srfmp``; None: the algorithm's (`DEFAULT_SCHEDULES`).
        refine_dt: SRFMP refinement step (None: split the rest of T evenly, capped at
            ``1 / lambda_x``).
    """

    nfe: int = 1
    t_end: float = 1.0
    method: str = "euler"
    schedule: str | None = None
    refine_dt: float | None = None

    def resolve(self, algorithm: str) -> SolverConfig:
        """This config with the algorithm's defaults filled in (DDIM: ``ddim`` method and
        schedule, T = 1)."""
        if algorithm not in DEFAULT_SCHEDULES:
            raise ValueError(f"unknown algorithm {algorithm!r}; choose from "
                             f"{sorted(DEFAULT_SCHEDULES)}")
        if int(self.nfe) != self.nfe or self.nfe < 1:
            raise ValueError(f"NFE must be a positive integer, got {self.nfe!r}")
        if algorithm in ("ddim", "cp"):
            sampler = DEFAULT_SCHEDULES[algorithm]
            return SolverConfig(int(self.nfe), 1.0, sampler, sampler, None)
        if self.method not in EVALS_PER_STEP:
            raise ValueError(f"unknown ODE method {self.method!r}; choose from "
                             f"{sorted(EVALS_PER_STEP)}")
        return replace(self, nfe=int(self.nfe), t_end=float(self.t_end),
                       schedule=self.schedule or DEFAULT_SCHEDULES[algorithm])

    def step_sizes(self, lambda_x: float | None = None) -> list[float]:
        """The flow's step sizes (a resolved flow config; SRFMP's schedule needs ``lambda_x``)."""
        if self.method in SAMPLERS:
            raise ValueError(f"a {self.method} solver has denoising steps, not step sizes")
        return step_sizes(self.nfe, self.method, self.t_end, self.schedule or "uniform",
                          lambda_x, self.refine_dt)

    def reached(self, lambda_x: float | None = None) -> float:
        """The flow time actually reached (SRFMP at NFE 1 stops at ``1 / lambda_x``); DDIM and
        CP report 1."""
        if self.method in SAMPLERS:
            return 1.0
        return float(sum(self.step_sizes(lambda_x)))

    def sample_kwargs(self) -> dict[str, Any]:
        """Keyword arguments of ``model.sample`` (`FlowModel`, `DiffusionModel` or
        `ConsistencyModel`)."""
        if self.method in SAMPLERS:
            return {"nfe": self.nfe}
        return {"nfe": self.nfe, "method": self.method, "t_end": self.t_end,
                "schedule": self.schedule, "refine_dt": self.refine_dt}

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> SolverConfig:
        """The config a checkpoint stored; unknown fields are refused (naming them)."""
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise ValueError(f"unknown solver field(s) {unknown}; known: {sorted(known)}")
        return cls(**dict(data))
