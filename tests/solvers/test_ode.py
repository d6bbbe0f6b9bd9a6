"""Tests for `rfmp_rl.solvers.ode`: fixed-NFE integration on manifolds and the SRFMP schedule."""

from __future__ import annotations

import math

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from torch.testing import assert_close

from rfmp_rl.manifolds import Euclidean, Sphere, parse_manifold
from rfmp_rl.solvers import EVALS_PER_STEP, ODESolver, integrate, num_steps, step_sizes

F64 = torch.float64
METHODS = ["euler", "euler_projx", "midpoint", "rk4"]
TOL = {
    torch.float32: {"rtol": 1e-6, "atol": 1e-6},
    torch.float64: {"rtol": 1e-12, "atol": 1e-12},
}

# ----- a rotation field on S^2 with a known flow -----------------------------------------------
AXIS = torch.tensor([1.0, 2.0, 2.0], dtype=F64) / 3.0
OMEGA = 1.0


def rotation_field(_t: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
    """u(x) = omega (k x x): tangent to S^2, its flow rotates about k by omega t."""
    return OMEGA * torch.linalg.cross(AXIS.to(x.dtype).expand_as(x), x)


def rotated(x: torch.Tensor, angle: float) -> torch.Tensor:
    """Rodrigues' rotation of x about AXIS by ``angle``."""
    k = AXIS.to(x.dtype).expand_as(x)
    k_dot_x = (k * x).sum(dim=-1, keepdim=True)
    return (
        math.cos(angle) * x
        + math.sin(angle) * torch.linalg.cross(k, x)
        + (1.0 - math.cos(angle)) * k_dot_x * k
    )


def _sphere_starts(batch: int = 8) -> torch.Tensor:
    # random points, none on the great circle orthogonal to the axis (latitude circles too)
    return Sphere(2).random_base(batch, generator=torch.Generator().manual_seed(0), dtype=F64)


@pytest.mark.parametrize(
    ("method", "nfe", "atol"),
    [
        ("euler", 4000, 1e-3),
        ("euler_projx", 4000, 1e-3),
        ("midpoint", 200, 1e-4),
        ("rk4", 40, 1e-6),
    ],
)
def test_rotation_field_reaches_the_analytic_point(method: str, nfe: int, atol: float) -> None:
    x0 = _sphere_starts()
    t_end = 1.0
    x_end = integrate(rotation_field, x0, Sphere(2), nfe=nfe, method=method, t_end=t_end)
    assert_close(x_end, rotated(x0, OMEGA * t_end), rtol=0.0, atol=atol)


@pytest.mark.parametrize(
    ("method", "order"), [("euler", 1), ("euler_projx", 1), ("midpoint", 2), ("rk4", 4)]
)
def test_convergence_order_on_the_sphere(method: str, order: int) -> None:
    # Halving the step divides the global error by 2^order.
    x0 = _sphere_starts()
    exact = rotated(x0, OMEGA)
    nfe = 10 * EVALS_PER_STEP[method]
    errors = [
        float(
            (integrate(rotation_field, x0, Sphere(2), nfe=k * nfe, method=method) - exact)
            .norm(dim=-1)
            .max()
        )
        for k in (1, 2)
    ]
    observed = math.log2(errors[0] / errors[1])
    assert observed == pytest.approx(order, abs=0.3)


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("spec", ["S2", "R3 x S3 x R1"])
def test_every_method_stays_on_the_manifold(method: str, spec: str) -> None:
    manifold = parse_manifold(spec)
    g = torch.Generator().manual_seed(1)
    weights = 10.0 * torch.randn(manifold.dim, manifold.dim, generator=g)
    offset = 10.0 * torch.randn(manifold.dim, generator=g)

    def field(t: torch.Tensor, x: torch.Tensor) -> torch.Tensor:  # large, not tangent
        return x @ weights.T + offset * (1.0 + t)

    x0 = manifold.random_base(32, generator=g)  # float32
    x_end = integrate(field, x0, manifold, nfe=100 * EVALS_PER_STEP[method], method=method)
    assert x_end.dtype == torch.float32
    assert torch.isfinite(x_end).all()
    sphere_part = x_end[..., :3] if spec == "S2" else x_end[..., 3:7]
    assert float((sphere_part.norm(dim=-1) - 1.0).abs().max()) <= 1e-6


# ----- the NFE budget --------------------------------------------------------------------------
class CountingField:
    """Wraps a field and records the times it was called at."""

    def __init__(self, field=None) -> None:
        self.field = field
        self.times: list[float] = []

    def __call__(self, t: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
        assert t.shape == (*x.shape[:-1], 1)
        self.times.append(float(t.flatten()[0]))
        return torch.zeros_like(x) if self.field is None else self.field(t, x)


@pytest.mark.parametrize(
    ("method", "nfe", "steps"),
    [("euler", 5, 5), ("euler_projx", 3, 3), ("midpoint", 6, 3), ("rk4", 8, 2)],
)
def test_field_is_called_exactly_nfe_times(method: str, nfe: int, steps: int) -> None:
    field = CountingField(rotation_field)
    integrate(field, _sphere_starts(), Sphere(2), nfe=nfe, method=method)
    assert len(field.times) == nfe
    assert num_steps(nfe, method) == steps
    assert len(step_sizes(nfe, method)) == steps


def test_stage_times_of_rk4_and_midpoint() -> None:
    field = CountingField()
    integrate(field, torch.zeros(2, 3), Euclidean(3), nfe=8, method="rk4")
    assert field.times == [0.0, 0.25, 0.25, 0.5, 0.5, 0.75, 0.75, 1.0]
    field = CountingField()
    integrate(field, torch.zeros(2, 3), Euclidean(3), nfe=4, method="midpoint")
    assert field.times == [0.0, 0.25, 0.5, 0.75]


@pytest.mark.parametrize(
    ("method", "nfe", "pattern"),
    [
        ("midpoint", 3, r"'midpoint'.*NFE=3"),
        ("rk4", 6, r"'rk4'.*NFE=6"),
        ("rk4", 2, r"'rk4'.*NFE=2"),
        ("euler", 0, r"NFE.*0"),
        ("euler", -4, r"NFE.*-4"),
        ("euler", 1.5, r"NFE.*1\.5"),
        ("rk4", 1.5, r"NFE.*1\.5"),
    ],
)
def test_unmeetable_nfe_raises(method: str, nfe: float, pattern: str) -> None:
    field = CountingField()
    with pytest.raises(ValueError, match=pattern):
        integrate(field, torch.zeros(3), Euclidean(3), nfe=nfe, method=method)
    assert field.times == []  # refused before any evaluation


def test_unknown_method_or_schedule_raises() -> None:
    with pytest.raises(ValueError, match="heun"):
        integrate(CountingField(), torch.zeros(3), Euclidean(3), nfe=4, method="heun")
    with pytest.raises(ValueError, match="cosine"):
        integrate(CountingField(), torch.zeros(3), Euclidean(3), nfe=4, schedule="cosine")
    with pytest.raises(ValueError, match="t_end"):
        step_sizes(4, t_end=0.0)


@settings(max_examples=50, deadline=None)
@given(
    method=st.sampled_from(METHODS),
    steps=st.integers(1, 64),
    t_end=st.floats(0.05, 5.0),
)
def test_uniform_steps_cover_the_interval(method: str, steps: int, t_end: float) -> None:
    nfe = steps * EVALS_PER_STEP[method]
    dts = step_sizes(nfe, method, t_end=t_end)
    assert len(dts) == steps
    assert dts == [t_end / steps] * steps
    assert math.fsum(dts) == pytest.approx(t_end, rel=1e-12)


# ----- the SRFMP schedule ----------------------------------------------------------------------
def test_srfmp_schedule_first_step_is_one_over_lambda() -> None:
    assert step_sizes(1, schedule="srfmp", lambda_x=2.5) == [0.4]
    assert step_sizes(1, "euler", schedule="srfmp", lambda_x=4.0) == [0.25]
    # later steps split the rest of [0, t_end] evenly ...
    assert_close(
        torch.tensor(step_sizes(5, "euler", schedule="srfmp", lambda_x=2.5), dtype=F64),
        torch.tensor([0.4, 0.15, 0.15, 0.15, 0.15], dtype=F64),
        **TOL[F64],
    )
    # ... capped at 1 / lambda_x
    assert step_sizes(3, "euler", t_end=3.0, schedule="srfmp", lambda_x=2.5) == [0.4, 0.4, 0.4]
    # an explicit refinement step is used as given, for every method
    assert step_sizes(12, "rk4", schedule="srfmp", lambda_x=2.5, refine_dt=0.05) == [
        0.4,
        0.05,
        0.05,
    ]


@pytest.mark.parametrize(
    ("kwargs", "pattern"),
    [
        ({}, "lambda_x"),
        ({"lambda_x": 0.0}, "lambda_x"),
        ({"lambda_x": -2.5}, "lambda_x"),
        ({"lambda_x": 2.5, "refine_dt": 0.5}, "refine_dt"),
        ({"lambda_x": 2.5, "refine_dt": 0.0}, "refine_dt"),
        ({"lambda_x": 2.5, "t_end": 0.4}, "refine_dt"),  # nothing left to refine
    ],
)
def test_srfmp_schedule_rejects_bad_parameters(kwargs: dict[str, float], pattern: str) -> None:
    with pytest.raises(ValueError, match=pattern):
        step_sizes(3, "euler", schedule="srfmp", **kwargs)


def test_return_intermediates_follows_the_step_sizes() -> None:
    # On R^n a constant field is integrated exactly, so x(t) = x0 + t c at every visited time.
    c = torch.tensor([1.0, -2.0, 0.5], dtype=F64)
    x0 = torch.randn(4, 3, generator=torch.Generator().manual_seed(2), dtype=F64)
    nfe, kwargs = 5, {"schedule": "srfmp", "lambda_x": 2.5, "t_end": 1.0}
    x_end, times, states = integrate(
        lambda t, x: c.expand_as(x),
        x0,
        Euclidean(3),
        nfe=nfe,
        return_intermediates=True,
        **kwargs,
    )
    dts = torch.tensor(step_sizes(nfe, "euler", **kwargs), dtype=F64)
    assert times.shape == (nfe + 1,)
    assert states.shape == (nfe + 1, 4, 3)
    assert_close(times[0], torch.tensor(0.0, dtype=F64))
    assert_close(times.diff(), dts, **TOL[F64])
    assert torch.equal(states[0], x0)
    assert torch.equal(states[-1], x_end)
    assert_close(states, x0 + times[:, None, None] * c, **TOL[F64])


def test_srfmp_first_step_lands_on_the_target_then_stays() -> None:
    sphere = Sphere(2)
    g = torch.Generator().manual_seed(3)
    x0, x1 = (
        sphere.random_base(16, generator=g, dtype=F64),
        sphere.random_base(16, generator=g, dtype=F64),
    )

    def stable_field(_t: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
        return 2.5 * sphere.logmap(x, x1)

    _, times, states = integrate(
        stable_field,
        x0,
        sphere,
        nfe=4,
        schedule="srfmp",
        lambda_x=2.5,
        t_end=2.0,
        return_intermediates=True,
    )
    assert_close(times, torch.tensor([0.0, 0.4, 0.8, 1.2, 1.6], dtype=F64), **TOL[F64])
    assert_close(states[1:], x1.expand(4, 16, 3), rtol=0.0, atol=1e-10)


def test_ode_solver_validates_at_construction_and_matches_integrate() -> None:
    with pytest.raises(ValueError, match="midpoint"):
        ODESolver(Sphere(2), nfe=3, method="midpoint")
    with pytest.raises(ValueError, match="lambda_x"):
        ODESolver(Sphere(2), nfe=2, schedule="srfmp")
    with pytest.raises(ValueError, match="heun"):
        ODESolver(Sphere(2), nfe=2, method="heun")

    solver = ODESolver(Sphere(2), nfe=8, method="rk4", t_end=1.5)
    assert solver.step_sizes() == [0.75, 0.75]
    x0 = _sphere_starts()
    expected = integrate(rotation_field, x0, Sphere(2), nfe=8, method="rk4", t_end=1.5)
    assert torch.equal(solver(rotation_field, x0), expected)
    _, times, states = solver(rotation_field, x0, return_intermediates=True)
    assert times.shape == (3,)
    assert states.shape == (3, *x0.shape)


# ----- end times beyond 1 ----------------------------------------------------------------------
@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("t_end", [1.0, 2.5])
def test_uniform_schedule_covers_zero_to_t_end(method: str, t_end: float) -> None:
    # dx/dt = t on R^2: x(T) = x0 + T^2 / 2. Every stage sees the right time, so every method is
    # exact up to its order in t (Euler: error T^2 / (2 n)).
    nfe = 8 * EVALS_PER_STEP[method]
    x0 = torch.ones(3, 2, dtype=F64)
    x_end, times, _ = integrate(
        lambda t, x: t.expand_as(x),
        x0,
        Euclidean(2),
        nfe=nfe,
        method=method,
        t_end=t_end,
        return_intermediates=True,
    )
    assert_close(times, torch.linspace(0.0, t_end, 9, dtype=F64), **TOL[F64])
    expected = x0 + t_end**2 / 2
    if method.startswith("euler"):
        expected = expected - t_end**2 / (2 * 8)
    assert_close(x_end, expected, **TOL[F64])


def test_rotation_beyond_t_equals_one() -> None:
    x0 = _sphere_starts()
    x_end = integrate(rotation_field, x0, Sphere(2), nfe=600, method="midpoint", t_end=3.0)
    assert_close(x_end, rotated(x0, 3.0 * OMEGA), rtol=0.0, atol=1e-4)
