"""The Sphere Push-T plane <-> sphere map: known points, exact inverses, unit norm, gradients."""

from __future__ import annotations

import math

import pytest
import torch

from rfmp_rl.manifolds import Sphere, plane_to_sphere, sphere_to_plane

TOL = {torch.float32: 1e-6, torch.float64: 1e-12}


def disc_points(n: int, radius: float, dtype: torch.dtype, seed: int = 0) -> torch.Tensor:
    """``n`` points in the disc |xy| <= radius, including the origin and points on the rim."""
    g = torch.Generator().manual_seed(seed)
    r = radius * torch.rand(n, 1, generator=g, dtype=torch.float64).sqrt()
    a = 2 * math.pi * torch.rand(n, 1, generator=g, dtype=torch.float64)
    xy = torch.cat([r * torch.cos(a), r * torch.sin(a)], -1)
    xy[0] = 0.0
    xy[1] = torch.tensor([radius, 0.0])
    xy[2] = torch.tensor([-radius, radius]) / math.sqrt(2)
    return xy.to(dtype)


def test_known_points():
    xy = torch.tensor([[0.0, 0.0], [2.0, 0.0], [0.0, -2.0], [1.0, 0.0]], dtype=torch.float64)
    expected = torch.tensor(
        [[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.8, 0.0, 0.6]], dtype=torch.float64
    )
    torch.testing.assert_close(plane_to_sphere(xy), expected)
    torch.testing.assert_close(sphere_to_plane(expected), xy)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("scale", [1.0, 0.37, 25.0])
def test_round_trip_and_unit_norm(dtype, scale):
    xy = disc_points(2000, 3.0, dtype) * scale
    p = plane_to_sphere(xy, scale)
    assert p.shape == (2000, 3) and p.dtype == dtype
    ones = torch.ones(2000, dtype=dtype)
    torch.testing.assert_close(p.norm(dim=-1), ones, atol=TOL[dtype], rtol=0)
    back = sphere_to_plane(p, scale)
    torch.testing.assert_close(back, xy, atol=TOL[dtype] * scale, rtol=0)


def test_inverse_from_the_sphere():
    # Every point of the sphere away from the south pole comes from a plane point.
    g = torch.Generator().manual_seed(1)
    p = Sphere(2).random_base(4000, generator=g, dtype=torch.float64)
    p = p[p[:, 2] > -0.9]
    torch.testing.assert_close(plane_to_sphere(sphere_to_plane(p, 3.0), 3.0), p)


def test_scale_divides_first():
    xy = disc_points(50, 3.0, torch.float64) * 40.0
    torch.testing.assert_close(plane_to_sphere(xy, 40.0), plane_to_sphere(xy / 40.0))


def test_matches_the_geometric_construction():
    # p, the tangent-plane point (x, y, 1) and the south pole are collinear.
    xy = disc_points(100, 3.0, torch.float64)
    p = plane_to_sphere(xy)
    south = torch.tensor([0.0, 0.0, -1.0], dtype=torch.float64)
    q = torch.cat([xy, torch.ones(100, 1, dtype=torch.float64)], -1)
    cross = torch.linalg.cross(p - south, q - south)
    torch.testing.assert_close(cross, torch.zeros_like(cross))
    # The upper hemisphere is the disc of radius 2 (the equator is r = 2).
    inside = xy.norm(dim=-1) < 2
    assert torch.equal(p[:, 2] > 0, inside)


def test_batch_shapes_and_errors():
    xy = torch.zeros(4, 5, 2)
    assert plane_to_sphere(xy).shape == (4, 5, 3)
    assert sphere_to_plane(plane_to_sphere(xy)).shape == (4, 5, 2)
    with pytest.raises(ValueError, match=r"\(\.\.\., 2\)"):
        plane_to_sphere(torch.zeros(3))
    with pytest.raises(ValueError, match=r"\(\.\.\., 3\)"):
        sphere_to_plane(torch.zeros(4, 2))


def test_south_pole_stays_finite():
    out = sphere_to_plane(torch.tensor([0.0, 0.0, -1.0]))
    assert torch.isfinite(out).all()


def test_differentiable():
    xy = disc_points(6, 3.0, torch.float64).requires_grad_()
    assert torch.autograd.gradcheck(lambda v: plane_to_sphere(v, 1.5), (xy,))
    p = plane_to_sphere(disc_points(6, 3.0, torch.float64, seed=2)).detach().requires_grad_()
    assert torch.autograd.gradcheck(lambda v: sphere_to_plane(v, 1.5), (p,))
    # At the origin the map is an isometry to first order: d p / d xy = [I; 0].
    jac = torch.autograd.functional.jacobian(plane_to_sphere, torch.zeros(2, dtype=torch.float64))
    torch.testing.assert_close(jac, torch.eye(3, 2, dtype=torch.float64))
