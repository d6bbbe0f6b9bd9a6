"""Construction, parsing, specs and quaternion helpers."""

from __future__ import annotations

import pytest
import torch

from rfmp_rl.manifolds import (
    Euclidean,
    Horizon,
    Product,
    Sphere,
    canonicalize_quaternion,
    from_spec,
    hemisphere_continuous,
    parse_manifold,
)


def test_parse_product_and_dimensions():
    m = parse_manifold("R3 x S3 x R1")
    assert isinstance(m, Product)
    assert m.dims == [3, 4, 1] and m.dim == 8 and m.intrinsic_dim == 7
    assert parse_manifold("S2") == Sphere(2)
    h = Horizon(m, 16)
    assert h.dim == 128 and h.intrinsic_dim == 112  # the paper's Table III: dim(a) = 112


@pytest.mark.parametrize("bad", ["", "Q3", "R", "S2 x T1"])
def test_parse_rejects_bad_strings_with_the_offending_factor(bad):
    with pytest.raises(ValueError, match="parse_manifold"):
        parse_manifold(bad)


def test_invalid_constructor_arguments_are_refused():
    with pytest.raises(ValueError, match="Sphere"):
        Sphere(0)
    with pytest.raises(ValueError, match="Euclidean"):
        Euclidean(0)
    with pytest.raises(ValueError, match="Horizon"):
        Horizon(Sphere(2), 0)
    with pytest.raises(TypeError, match="Product"):
        Product([Sphere(2), "R3"])
    with pytest.raises(ValueError, match="unknown manifold type"):
        from_spec({"type": "torus"})


@pytest.mark.parametrize(
    "m",
    [
        Sphere(2),
        Euclidean(5),
        parse_manifold("R3 x S3 x R1"),
        Horizon(parse_manifold("R3 x S3 x R1"), 16),
    ],
)
def test_spec_round_trip(m):
    assert from_spec(m.spec()) == m
    assert from_spec(m.spec()).dim == m.dim


def test_origin_is_on_the_manifold_and_is_the_identity_quaternion():
    torch.testing.assert_close(Sphere(3).origin(), torch.tensor([0.0, 0.0, 0.0, 1.0]))
    h = Horizon(parse_manifold("R3 x S3 x R1"), 4)
    o = h.origin(2)
    assert o.shape == (2, 32)
    torch.testing.assert_close(h.projx(o), o)


def test_horizon_applies_the_step_manifold_per_step():
    step = parse_manifold("R3 x S3 x R1")
    h = Horizon(step, 5)
    g = torch.Generator().manual_seed(0)
    x, y = h.random_base(3, generator=g), h.random_base(3, generator=g)
    per_step = step.logmap(h.unflatten(x), h.unflatten(y))
    torch.testing.assert_close(h.unflatten(h.logmap(x, y)), per_step)
    sq = step.sqdist(h.unflatten(x), h.unflatten(y)).sum(-2)
    torch.testing.assert_close(h.dist(x, y) ** 2, sq)


def test_canonicalize_quaternion_keeps_rotation_and_makes_w_nonnegative():
    q = Sphere(3).random_base(100, generator=torch.Generator().manual_seed(0))
    c = canonicalize_quaternion(q)
    assert (c[:, -1] >= 0).all()
    torch.testing.assert_close(c.abs(), q.abs())
    cw = canonicalize_quaternion(q, w_index=0)
    assert (cw[:, 0] >= 0).all()
    with pytest.raises(ValueError, match=r"\(\.\.\., 4\)"):
        canonicalize_quaternion(torch.zeros(3, 3))


def test_hemisphere_continuity_removes_sign_flips_along_a_trajectory():
    # A smooth rotation about z, with random sign flips injected.
    angles = torch.linspace(0, 3.0, 50)
    q = torch.stack(
        [torch.zeros(50), torch.zeros(50), torch.sin(angles / 2), torch.cos(angles / 2)], -1
    )
    flips = torch.where(torch.rand(50, generator=torch.Generator().manual_seed(0)) < 0.4, -1.0, 1.0)
    noisy = (q * flips[:, None]).unsqueeze(0).repeat(2, 1, 1)  # (B=2, T=50, 4)
    fixed = hemisphere_continuous(noisy)
    dots = (fixed[:, 1:] * fixed[:, :-1]).sum(-1)
    assert (dots > 0).all()
    torch.testing.assert_close(fixed[0], q * flips[0])  # first sample kept, the rest follow it
    # time on another axis
    fixed_t0 = hemisphere_continuous(noisy.transpose(0, 1), dim=0)
    torch.testing.assert_close(fixed_t0.transpose(0, 1), fixed)
