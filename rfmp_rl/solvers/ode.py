"""Fixed-budget ODE integration on manifolds.

A *vector field* is any callable ``field(t, x) -> u`` with ``t`` of shape ``(..., 1)`` and
``x, u`` of shape ``(..., dim)``. The budget is given as NFE, the number of field evaluations;
each method spends a fixed number of evaluations per step (Euler 1, midpoint 2, RK4 4), and an
NFE it cannot meet exactly is refused. Step sizes are Python floats fixed before integration, so
the loop unrolls into a static graph (no data-dependent branching): it exports to ONNX as is.

Methods (``x <- step(x)`` with ``k_i`` projected onto ``T_x M``):

- ``euler``: projected Euler with the exponential map, ``x <- Exp_x(dt k1)`` (the paper's).
- ``euler_projx``: ambient Euler, then the closest-point projection: ``projx(x + dt k1)``.
- ``midpoint``: ``k2 = f(t + dt/2, Exp_x(dt/2 k1))``, ``x <- Exp_x(dt k2)``.
- ``rk4``: classical Runge-Kutta in ambient coordinates with ``projx`` retractions (4th order).

Schedules:

- ``uniform``: ``NFE / evals`` equal steps covering ``[0, t_end]``.
- ``srfmp``: the paper's SRFMP schedule (Sec. III-B-3): the first step is ``dt = 1 / lambda_x``,
  which lands on the target in one step for a perfectly learned stable field; the remaining
  steps refine with ``refine_dt`` (default: split ``t_end - 1/lambda_x`` evenly, capped at
  ``1 / lambda_x``).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import torch

from rfmp_rl.manifolds import Manifold

__all__ = ["EVALS_PER_STEP", "ODESolver", "integrate", "step_sizes", "VectorFieldFn"]

VectorFieldFn = Callable[[torch.Tensor, torch.Tensor], torch.Tensor]

#: field evaluations each method spends per step
EVALS_PER_STEP = {"euler": 1, "euler_projx": 1, "midpoint": 2, "rk4": 4}
SCHEDULES = ("uniform", "srfmp")


def num_steps(nfe: int, method: str) -> int:
    """Number of steps a method takes with a budget of ``nfe`` evaluations (exact or refused)."""
    if method not in EVALS_PER_STEP:
        raise ValueError(f"unknown ODE method {method!r}; choose from {sorted(EVALS_PER_STEP)}")
    if int(nfe) != nfe or nfe < 1:
        raise ValueError(f"NFE must be a positive integer, got {nfe!r}")
    per = EVALS_PER_STEP[method]
    if nfe % per:
        raise ValueError(
            f"method {method!r} uses {per} function evaluations per step, so NFE={nfe} cannot be "
            f"met exactly; use a multiple of {per}"
        )
    return int(nfe) // per


def step_sizes(
    nfe: int,
    method: str = "euler",
    t_end: float = 1.0,
    schedule: str = "uniform",
    lambda_x: float | None = None,
    refine_dt: float | None = None,
) -> list[float]:
    """The step sizes used for a budget of ``nfe`` evaluations.

    Example:
        >>> step_sizes(4, "euler", t_end=1.0)
        [0.25, 0.25, 0.25, 0.25]
        >>> step_sizes(3, "euler", schedule="srfmp", lambda_x=2.5)
        [0.4, 0.3, 0.3]
    """
    n = num_steps(nfe, method)
    if t_end <= 0:
        raise ValueError(f"t_end must be > 0, got {t_end}")
    if schedule == "uniform":
        return [float(t_end) / n] * n
    if schedule != "srfmp":
        raise ValueError(f"unknown schedule {schedule!r}; choose from {SCHEDULES}")
    if lambda_x is None or lambda_x <= 0:
        raise ValueError(f"the 'srfmp' schedule needs lambda_x > 0, got {lambda_x!r}")
    first = 1.0 / lambda_x
    if n == 1:
        return [first]
    if refine_dt is None:
        refine_dt = min(first, max(float(t_end) - first, 0.0) / (n - 1))
    if not 0 < refine_dt <= first + 1e-12:
        raise ValueError(
            f"refine_dt must lie in (0, 1/lambda_x = {first:g}] (the paper's epsilon), got "
            f"{refine_dt!r}; increase t_end or NFE, or pass refine_dt"
        )
    return [first] + [float(refine_dt)] * (n - 1)


def _time_column(t: float, x: torch.Tensor) -> torch.Tensor:
    return torch.full_like(x[..., :1], t)


def _step(
    method: str, field: VectorFieldFn, manifold: Manifold, t: float, dt: float, x: torch.Tensor
) -> torch.Tensor:
    def f(tt: float, xx: torch.Tensor) -> torch.Tensor:
        return manifold.proju(x, field(_time_column(tt, xx), xx))

    if method == "euler":
        return manifold.expmap(x, dt * f(t, x))
    if method == "euler_projx":
        return manifold.projx(x + dt * field(_time_column(t, x), x))
    if method == "midpoint":
        k1 = f(t, x)
        k2 = f(t + 0.5 * dt, manifold.expmap(x, 0.5 * dt * k1))
        return manifold.expmap(x, dt * k2)

    # rk4: classical stages in ambient coordinates, each stage point retracted with projx and each
    # slope projected onto the tangent space at its own stage point; fourth order on embedded
    # manifolds (projecting every slope onto T_x instead would cost two orders on curved ones).
    def g(tt: float, y: torch.Tensor) -> torch.Tensor:
        return manifold.proju(y, field(_time_column(tt, y), y))

    k1 = g(t, x)
    k2 = g(t + 0.5 * dt, manifold.projx(x + 0.5 * dt * k1))
    k3 = g(t + 0.5 * dt, manifold.projx(x + 0.5 * dt * k2))
    k4 = g(t + dt, manifold.projx(x + dt * k3))
    return manifold.projx(x + (dt / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4))


def integrate(
    field: VectorFieldFn,
    x0: torch.Tensor,
    manifold: Manifold,
    nfe: int,
    method: str = "euler",
    t_end: float = 1.0,
    schedule: str = "uniform",
    lambda_x: float | None = None,
    refine_dt: float | None = None,
    t_start: float = 0.0,
    return_intermediates: bool = False,
) -> torch.Tensor | tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Integrate ``dx/dt = field(t, x)`` on ``manifold`` from ``x0`` with exactly ``nfe`` calls.

    Args:
        field: the vector field ``field(t (..., 1), x (..., dim)) -> (..., dim)``.
        x0: start points ``(..., dim)`` on the manifold.
        manifold: where the state lives.
        nfe: number of field evaluations.
        method: ``euler``, ``euler_projx``, ``midpoint`` or ``rk4``.
        t_end: end time T (may exceed 1) for the ``uniform`` schedule and the default SRFMP
            refinement.
        schedule: ``uniform`` or ``srfmp`` (see module docstring).
        lambda_x: SRFMP spatial rate, required by the ``srfmp`` schedule.
        refine_dt: SRFMP refinement step after the first one.
        t_start: initial time.
        return_intermediates: also return the visited times ``(n + 1,)`` and states
            ``(n + 1, ..., dim)``.

    Returns:
        The final state, or ``(x_T, times, states)``.

    Example:
        >>> from rfmp_rl.manifolds import Euclidean
        >>> x1 = integrate(lambda t, x: torch.ones_like(x), torch.zeros(2), Euclidean(2), nfe=4)
        >>> x1
        tensor([1., 1.])
    """
    dts = step_sizes(nfe, method, t_end, schedule, lambda_x, refine_dt)
    x, t = x0, float(t_start)
    times, states = [t], [x0]
    for dt in dts:
        x = _step(method, field, manifold, t, dt, x)
        t += dt
        if return_intermediates:
            times.append(t)
            states.append(x)
    if return_intermediates:
        return x, torch.tensor(times, dtype=x0.dtype, device=x0.device), torch.stack(states, dim=0)
    return x


@dataclass
class ODESolver:
    """A fixed integration configuration, callable on ``(field, x0)``.

    Example:
        >>> from rfmp_rl.manifolds import Sphere
        >>> solver = ODESolver(Sphere(2), nfe=1, schedule="srfmp", lambda_x=2.5)
        >>> solver.step_sizes()
        [0.4]
    """

    manifold: Manifold
    nfe: int = 1
    method: str = "euler"
    t_end: float = 1.0
    schedule: str = "uniform"
    lambda_x: float | None = None
    refine_dt: float | None = None

    def __post_init__(self) -> None:
        self.step_sizes()  # validate eagerly: a bad NFE or schedule fails at construction

    def step_sizes(self) -> list[float]:
        return step_sizes(
            self.nfe, self.method, self.t_end, self.schedule, self.lambda_x, self.refine_dt
        )

    def __call__(
        self, field: VectorFieldFn, x0: torch.Tensor, return_intermediates: bool = False
    ) -> torch.Tensor | tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        return integrate(
            field,
            x0,
            self.manifold,
            self.nfe,
            self.method,
            self.t_end,
            self.schedule,
            self.lambda_x,
            self.refine_dt,
            return_intermediates=return_intermediates,
        )
