"""Manifold identities on S^n (n in 1, 2, 3, 7), R^3 x S^3 x R^1 and its 16-step horizon."""

from __future__ import annotations

import math

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from rfmp_rl.manifolds import Euclidean, Horizon, Sphere, parse_manifold

from .helpers import TOL, random_pair, sphere_parts

POSE = parse_manifold("R3 x S3 x R1")
MANIFOLDS = {
    "S1": Sphere(1),
    "S2": Sphere(2),
    "S3": Sphere(3),
    "S7": Sphere(7),
    "R3xS3xR1": POSE,
    "R3xS3xR1^16": Horizon(POSE, 16),
    "R4": Euclidean(4),
}
DTYPES = [torch.float32, torch.float64]
MAX_ANGLE = math.pi - 1e-3
PROPERTY = settings(max_examples=25, deadline=None)


def pair(name: str, dtype: torch.dtype, seed: int, max_angle: float = MAX_ANGLE, batch: int = 64):
    m = MANIFOLDS[name]
    g = torch.Generator().manual_seed(seed)
    x, y = random_pair(m, batch, g, max_angle)
    return m, x.to(dtype), y.to(dtype)


@pytest.mark.parametrize("name", list(MANIFOLDS))
@pytest.mark.parametrize("dtype", DTYPES)
@PROPERTY
@given(seed=st.integers(0, 2**31 - 1), frac=st.floats(0.0, 1.0))
def test_expmap_inverts_logmap(name, dtype, seed, frac):
    m, x, y = pair(name, dtype, seed, max_angle=max(frac * MAX_ANGLE, 1e-6))
    torch.testing.assert_close(m.expmap(x, m.logmap(x, y)), y, atol=TOL[dtype], rtol=0)


@pytest.mark.parametrize("name", list(MANIFOLDS))
@pytest.mark.parametrize("dtype", DTYPES)
def test_logmap_of_identical_points_is_zero_with_finite_gradients(name, dtype):
    m, x, _ = pair(name, dtype, seed=0)
    x = x.clone().requires_grad_(True)
    y = x.detach().clone().requires_grad_(True)
    log = m.logmap(x, y)
    torch.testing.assert_close(log, torch.zeros_like(log), atol=TOL[dtype], rtol=0)
    (log.sum() + m.sqdist(x, y).sum()).backward()
    assert torch.isfinite(x.grad).all() and torch.isfinite(y.grad).all()


@pytest.mark.parametrize("name", list(MANIFOLDS))
@pytest.mark.parametrize("dtype", DTYPES)
@PROPERTY
@given(seed=st.integers(0, 2**31 - 1))
def test_projx_is_idempotent_and_proju_is_tangent(name, dtype, seed):
    m, x, _ = pair(name, dtype, seed)
    g = torch.Generator().manual_seed(seed)
    ambient = (torch.randn(x.shape, generator=g, dtype=torch.float64) * 3).to(dtype)
    p = m.projx(ambient)
    torch.testing.assert_close(m.projx(p), p, atol=TOL[dtype], rtol=0)
    torch.testing.assert_close(m.projx(x), x, atol=TOL[dtype], rtol=0)
    u = m.proju(x, ambient)
    for xs, us in zip(sphere_parts(m, x), sphere_parts(m, u), strict=True):
        dot = (xs * us).sum(-1)
        torch.testing.assert_close(dot, torch.zeros_like(dot), atol=10 * TOL[dtype], rtol=0)
    torch.testing.assert_close(m.proju(x, u), u, atol=10 * TOL[dtype], rtol=0)


@pytest.mark.parametrize("name", list(MANIFOLDS))
@pytest.mark.parametrize("dtype", DTYPES)
@PROPERTY
@given(seed=st.integers(0, 2**31 - 1))
def test_dist_is_symmetric_and_equals_norm_of_logmap(name, dtype, seed):
    m, x, y = pair(name, dtype, seed)
    d = m.dist(x, y)
    assert d.shape == (*x.shape[:-1], 1)
    tol = 100 * TOL[dtype]  # distances up to ~pi * sqrt(16) sum many terms
    torch.testing.assert_close(d, m.dist(y, x), atol=tol, rtol=0)
    torch.testing.assert_close(d, m.norm(x, m.logmap(x, y)), atol=tol, rtol=0)
    torch.testing.assert_close(m.dist(x, x), torch.zeros_like(d), atol=tol, rtol=0)
    assert (d >= 0).all()


@pytest.mark.parametrize("name", list(MANIFOLDS))
@pytest.mark.parametrize("dtype", DTYPES)
@PROPERTY
@given(seed=st.integers(0, 2**31 - 1), scale=st.floats(0.0, 100.0))
def test_expmap_stays_on_the_manifold_for_large_tangent_vectors(name, dtype, seed, scale):
    m, x, _ = pair(name, dtype, seed)
    g = torch.Generator().manual_seed(seed + 1)
    u = m.proju(x, torch.randn(x.shape, generator=g, dtype=torch.float64).to(dtype))
    # every sphere component gets tangent norm `scale` (up to 100)
    for us in sphere_parts(m, u):
        us.mul_(scale / us.norm(dim=-1, keepdim=True).clamp_min(1e-12))
    y = m.expmap(x, u)
    assert torch.isfinite(y).all()
    for ys in sphere_parts(m, y):
        assert ((ys.norm(dim=-1) - 1).abs() <= 1e-6).all()


@pytest.mark.parametrize("name", ["S2", "S3", "R3xS3xR1", "R3xS3xR1^16"])
def test_expmap_moves_by_exactly_the_tangent_norm(name):
    m, x, y = pair(name, torch.float64, seed=3, max_angle=2.0)
    u = m.logmap(x, y)
    torch.testing.assert_close(m.dist(x, m.expmap(x, u)), m.norm(x, u), atol=1e-9, rtol=0)


@pytest.mark.parametrize("dtype", DTYPES)
def test_sphere_logmap_is_finite_at_antipodal_points(dtype):
    s = Sphere(3)
    x = s.random_base(32, generator=torch.Generator().manual_seed(0), dtype=dtype)
    log = s.logmap(x, -x)
    assert torch.isfinite(log).all()
    torch.testing.assert_close(log.norm(dim=-1), torch.full((32,), math.pi, dtype=dtype))
    torch.testing.assert_close((log * x).sum(-1), torch.zeros(32, dtype=dtype), atol=1e-5, rtol=0)
    torch.testing.assert_close(s.expmap(x, log), -x, atol=1e-5, rtol=0)


def test_geodesic_matches_expmap_and_has_the_transported_velocity():
    s = Sphere(2)
    g = torch.Generator().manual_seed(1)
    x, y = random_pair(s, 16, g, 2.5)
    u = s.logmap(x, y)
    for step in (0.0, 0.3, 1.0, 1.7):
        point, velocity = s.geodesic(x, u, step)
        torch.testing.assert_close(point, s.expmap(x, step * u))
        h = 1e-6
        fd = (s.expmap(x, (step + h) * u) - s.expmap(x, (step - h) * u)) / (2 * h)
        torch.testing.assert_close(velocity, fd, atol=1e-6, rtol=0)
        torch.testing.assert_close(s.norm(point, velocity), s.norm(x, u))


def test_euclidean_maps_are_flat():
    r = Euclidean(3)
    x, y = torch.randn(4, 3), torch.randn(4, 3)
    torch.testing.assert_close(r.logmap(x, y), y - x)
    torch.testing.assert_close(r.expmap(x, y - x), y)
    torch.testing.assert_close(r.dist(x, y), (y - x).norm(dim=-1, keepdim=True))
