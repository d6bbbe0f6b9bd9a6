"""Tests for `rfmp_rl.flows.paths`: RFMP's geodesic path, SRFMP's stable path, time sampling."""

from __future__ import annotations

import math

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from torch.testing import assert_close

from rfmp_rl.flows import GeodesicPath, StablePath, sample_time, sample_time_via_tau
from rfmp_rl.manifolds import Euclidean, Horizon, Manifold, Sphere, parse_manifold
from rfmp_rl.solvers import integrate

F64 = torch.float64
# Tolerances for quantities computed in closed form (no integration, no finite differences).
TOL = {
    torch.float32: {"rtol": 1e-5, "atol": 1e-5},
    torch.float64: {"rtol": 1e-10, "atol": 1e-10},
}

MANIFOLDS = {
    "R3": Euclidean(3),
    "S2": Sphere(2),
    "S3": Sphere(3),
    "R3xS3xR1": parse_manifold("R3 x S3 x R1"),
    "R3xS3xR1-horizon16": Horizon(parse_manifold("R3 x S3 x R1"), steps=16),
}
STABLE_MANIFOLDS = {
    "R5": Euclidean(5),
    "S2": Sphere(2),
    "S3": Sphere(3),
    "R3xS3xR1": parse_manifold("R3 x S3 x R1"),
}


def _pair(
    manifold: Manifold, batch: int, seed: int, dtype: torch.dtype = F64
) -> tuple[torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    x0 = manifold.random_base(batch, generator=g, dtype=dtype)
    x1 = manifold.random_base(batch, generator=g, dtype=dtype)
    return x0, x1


def _off_manifold(manifold: Manifold, x: torch.Tensor) -> torch.Tensor:
    return manifold.check_point(x).max()


# ----- RFMP: GeodesicPath ----------------------------------------------------------------------
@pytest.mark.parametrize("dtype", [torch.float32, F64])
@pytest.mark.parametrize("name", list(MANIFOLDS))
def test_geodesic_path_endpoints(name: str, dtype: torch.dtype) -> None:
    manifold = MANIFOLDS[name]
    path = GeodesicPath(manifold)
    x0, x1 = _pair(manifold, 64, seed=0, dtype=dtype)
    assert_close(path.sample(x0, x1, 0.0).x_t, x0, **TOL[dtype])
    assert_close(path.sample(x0, x1, 1.0).x_t, x1, **TOL[dtype])
    # a per-sample time column works the same as a scalar
    assert_close(path.sample(x0, x1, torch.zeros(64, 1, dtype=dtype)).x_t, x0, **TOL[dtype])


@pytest.mark.parametrize("name", list(MANIFOLDS))
def test_geodesic_path_velocity_is_time_derivative(name: str) -> None:
    manifold = MANIFOLDS[name]
    path = GeodesicPath(manifold)
    x0, x1 = _pair(manifold, 64, seed=1)
    t = torch.rand(64, generator=torch.Generator().manual_seed(2), dtype=F64)
    h = 1e-5
    s = path.sample(x0, x1, t)
    finite_diff = (path.sample(x0, x1, t + h).x_t - path.sample(x0, x1, t - h).x_t) / (2 * h)

    assert s.x_t.shape == s.u_t.shape == (64, manifold.dim)
    assert s.t.shape == (64, 1)
    assert_close(s.u_t, finite_diff, rtol=0.0, atol=1e-3)
    # x_t stays on the manifold and u_t is tangent there
    assert _off_manifold(manifold, s.x_t) <= 1e-12
    assert_close(manifold.proju(s.x_t, s.u_t), s.u_t, **TOL[F64])


def test_geodesic_path_on_euclidean_space_is_the_straight_line() -> None:
    path = GeodesicPath(Euclidean(3))
    x0, x1 = _pair(Euclidean(3), 32, seed=3)
    t = torch.rand(32, 1, generator=torch.Generator().manual_seed(4), dtype=F64)
    s = path.sample(x0, x1, t)
    assert_close(s.x_t, (1 - t) * x0 + t * x1, **TOL[F64])
    assert_close(s.u_t, x1 - x0, **TOL[F64])


# ----- SRFMP: StablePath -----------------------------------------------------------------------
def _rk4_scalar(f, y0: torch.Tensor, t_end: float, steps: int) -> torch.Tensor:
    """Classical RK4 for an autonomous ODE dy/dt = f(y), independent of `rfmp_rl.solvers`."""
    y, h = y0, t_end / steps
    for _ in range(steps):
        k1 = f(y)
        k2 = f(y + 0.5 * h * k1)
        k3 = f(y + 0.5 * h * k2)
        k4 = f(y + h * k3)
        y = y + (h / 6.0) * (k1 + 2 * k2 + 2 * k3 + k4)
    return y


@pytest.mark.parametrize("t", [0.4, 1.5])
@pytest.mark.parametrize("name", list(STABLE_MANIFOLDS))
def test_stable_path_closed_form_solves_its_target_ode(name: str, t: float) -> None:
    manifold = STABLE_MANIFOLDS[name]
    path = StablePath(manifold, lambda_x=2.5, lambda_tau=2.0, tau0=0.0, tau1=1.0)
    x0, x1 = _pair(manifold, 16, seed=5)

    def field(_t: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
        return path.target_field(x, x1)

    x_ode = integrate(field, x0, manifold, nfe=4000, method="rk4", t_end=t)
    s = path.sample(x0, x1, t)
    assert_close(s.x_t, x_ode, rtol=0.0, atol=1e-4)
    assert _off_manifold(manifold, s.x_t) <= 1e-12

    tau0 = torch.full((16, 1), path.tau0, dtype=F64)
    tau_ode = _rk4_scalar(path.tau_field, tau0, t, steps=1000)
    assert_close(s.tau_t, tau_ode, rtol=0.0, atol=1e-4)
    tau_exact = path.tau1 + math.exp(-path.lambda_tau * t) * (path.tau0 - path.tau1)
    assert_close(s.tau_t, torch.full_like(tau_ode, tau_exact), **TOL[F64])


@pytest.mark.parametrize("name", list(STABLE_MANIFOLDS))
def test_stable_path_starts_at_x0_and_tau0(name: str) -> None:
    manifold = STABLE_MANIFOLDS[name]
    path = StablePath(manifold, tau0=-0.5, tau1=2.0)
    x0, x1 = _pair(manifold, 16, seed=6)
    s = path.sample(x0, x1, 0.0)
    assert_close(s.x_t, x0, **TOL[F64])
    assert_close(s.tau_t, torch.full((16, 1), -0.5, dtype=F64), **TOL[F64])


@pytest.mark.parametrize("name", list(STABLE_MANIFOLDS))
def test_one_euler_exp_step_of_one_over_lambda_lands_on_x1(name: str) -> None:
    manifold = STABLE_MANIFOLDS[name]
    path = StablePath(manifold, lambda_x=2.5)
    x0, x1 = _pair(manifold, 32, seed=7)

    def field(_t: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
        return path.target_field(x, x1)

    x_end = integrate(field, x0, manifold, nfe=1, method="euler", schedule="srfmp", lambda_x=2.5)
    assert_close(x_end, x1, rtol=0.0, atol=1e-5)


@pytest.mark.parametrize("name", list(STABLE_MANIFOLDS))
def test_stable_path_velocity_equals_target_field_at_x_t(name: str) -> None:
    manifold = STABLE_MANIFOLDS[name]
    path = StablePath(manifold, lambda_x=2.5, lambda_tau=1.5, tau0=0.0, tau1=1.0)
    x0, x1 = _pair(manifold, 64, seed=8)
    t = 2.0 * torch.rand(64, generator=torch.Generator().manual_seed(9), dtype=F64)
    s = path.sample(x0, x1, t)

    assert_close(s.u_t, path.target_field(s.x_t, x1), **TOL[F64])
    assert_close(s.u_tau, -path.lambda_tau * (s.tau_t - path.tau1), **TOL[F64])
    # and both are the time derivatives of the closed-form path
    h = 1e-5
    plus, minus = path.sample(x0, x1, t + h), path.sample(x0, x1, t - h)
    assert_close(s.u_t, (plus.x_t - minus.x_t) / (2 * h), rtol=0.0, atol=1e-6)
    assert_close(s.u_tau, (plus.tau_t - minus.tau_t) / (2 * h), rtol=0.0, atol=1e-6)


def test_stable_path_on_euclidean_space_matches_the_paper() -> None:
    # Eqs. for the Euclidean SFM: x_t = x1 + exp(-lambda_x t) (x0 - x1), u = -lambda_x (x_t - x1)
    path = StablePath(Euclidean(4), lambda_x=3.0)
    x0, x1 = _pair(Euclidean(4), 8, seed=10)
    t = torch.rand(8, 1, generator=torch.Generator().manual_seed(11), dtype=F64)
    s = path.sample(x0, x1, t)
    assert_close(s.x_t, x1 + torch.exp(-3.0 * t) * (x0 - x1), **TOL[F64])
    assert_close(s.u_t, -3.0 * (s.x_t - x1), **TOL[F64])


@settings(max_examples=50, deadline=None)
@given(
    t=st.floats(0.0, 4.0),
    lambda_tau=st.floats(0.5, 5.0),
    tau0=st.floats(-2.0, 2.0),
    gap=st.floats(0.1, 3.0),
    sign=st.sampled_from([-1.0, 1.0]),
)
def test_time_of_tau_inverts_tau_at(
    t: float, lambda_tau: float, tau0: float, gap: float, sign: float
) -> None:
    path = StablePath(Euclidean(1), lambda_tau=lambda_tau, tau0=tau0, tau1=tau0 + sign * gap)
    t_ = torch.tensor([t], dtype=F64)
    assert_close(path.time_of_tau(path.tau_at(t_)), t_, rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize(
    "kwargs", [{"lambda_x": 0.0}, {"lambda_tau": -1.0}, {"tau0": 1.0, "tau1": 1.0}]
)
def test_stable_path_rejects_bad_parameters(kwargs: dict[str, float]) -> None:
    with pytest.raises(ValueError, match="StablePath"):
        StablePath(Sphere(2), **kwargs)


# ----- time sampling ---------------------------------------------------------------------------
def test_sample_time_shape_range_and_seed() -> None:
    t = sample_time(5, 3, generator=torch.Generator().manual_seed(0), dtype=F64)
    assert t.shape == (5, 3, 1)
    assert t.dtype == F64
    assert bool(((t >= 0) & (t <= 1)).all())
    assert torch.equal(t, sample_time(5, 3, generator=torch.Generator().manual_seed(0), dtype=F64))


@pytest.mark.parametrize("t_max", [1.0, 1.6])
def test_sample_time_via_tau_makes_tau_uniform(t_max: float) -> None:
    n = 20_000
    path = StablePath(Sphere(2), lambda_tau=2.5, tau0=0.0, tau1=1.0)
    t = sample_time_via_tau(
        path, n, t_max=t_max, generator=torch.Generator().manual_seed(12), dtype=F64
    )
    assert t.shape == (n, 1)
    assert bool(((t >= 0) & (t <= t_max)).all())

    tau_max = path.tau_at(torch.tensor(t_max, dtype=F64))
    v = ((path.tau_at(t) - path.tau0) / (tau_max - path.tau0)).flatten().sort().values
    # v ~ U[0, 1]: its mean has standard error sqrt(1/12 / n) ~ 0.002; allow 5 of them.
    assert abs(float(v.mean()) - 0.5) <= 5 * math.sqrt(1 / 12 / n)
    # Kolmogorov-Smirnov statistic below the 0.1% critical value 1.95 / sqrt(n).
    ecdf_hi = torch.arange(1, n + 1, dtype=F64) / n
    ks = torch.maximum(ecdf_hi - v, v - (ecdf_hi - 1.0 / n)).max()
    assert float(ks) <= 1.95 / math.sqrt(n)

    # ...so t itself is skewed towards early times: E[t] = E[-log r] / lambda_tau with
    # r ~ U[r_min, 1], E[-log r] = (1 - r_min + r_min log r_min) / (1 - r_min).
    r_min = math.exp(-2.5 * t_max)
    mean_t = (1 - r_min + r_min * math.log(r_min)) / (1 - r_min) / 2.5
    assert mean_t < t_max / 2
    assert abs(float(t.mean()) - mean_t) <= 5 * float(t.std()) / math.sqrt(n)
