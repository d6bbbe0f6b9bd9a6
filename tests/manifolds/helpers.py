"""Random points and pairs on any manifold, with control over sphere angles."""

from __future__ import annotations

import torch

from rfmp_rl.manifolds import Euclidean, Horizon, Manifold, Product, Sphere

TOL = {torch.float32: 1e-5, torch.float64: 1e-10}


def random_pair(
    manifold: Manifold, batch: int, generator: torch.Generator, max_angle: float
) -> tuple[torch.Tensor, torch.Tensor]:
    """Pairs (x, y) in float64; sphere components are at most ``max_angle`` apart.

    Angles are drawn uniformly in [0, max_angle] and the first pair of each sphere component is
    set to exactly ``max_angle`` so the hardest case is always covered.
    """
    if isinstance(manifold, Euclidean):
        x = torch.randn(batch, manifold.dim, generator=generator, dtype=torch.float64)
        y = torch.randn(batch, manifold.dim, generator=generator, dtype=torch.float64) * 3
        return x, y
    if isinstance(manifold, Sphere):
        x = manifold.random_base(batch, generator=generator, dtype=torch.float64)
        e = manifold.proju(
            x, torch.randn(batch, manifold.dim, generator=generator, dtype=torch.float64)
        )
        e = e / e.norm(dim=-1, keepdim=True)
        angle = torch.rand(batch, 1, generator=generator, dtype=torch.float64) * max_angle
        angle[0] = max_angle
        y = torch.cos(angle) * x + torch.sin(angle) * e
        return x, y / y.norm(dim=-1, keepdim=True)
    if isinstance(manifold, Product):
        pairs = [random_pair(c, batch, generator, max_angle) for c in manifold.components]
        return torch.cat([p[0] for p in pairs], -1), torch.cat([p[1] for p in pairs], -1)
    if isinstance(manifold, Horizon):
        pairs = [
            random_pair(manifold.step, batch, generator, max_angle) for _ in range(manifold.steps)
        ]
        return torch.cat([p[0] for p in pairs], -1), torch.cat([p[1] for p in pairs], -1)
    raise TypeError(manifold)


def sphere_parts(manifold: Manifold, x: torch.Tensor) -> list[torch.Tensor]:
    """The coordinates of every sphere component of x."""
    if isinstance(manifold, Sphere):
        return [x]
    if isinstance(manifold, Product):
        return [
            p
            for c, xc in zip(manifold.components, manifold.split(x), strict=True)
            for p in sphere_parts(c, xc)
        ]
    if isinstance(manifold, Horizon):
        return sphere_parts(manifold.step, manifold.unflatten(x))
    return []
