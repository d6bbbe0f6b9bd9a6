"""Products of manifolds: a per-step action space such as R^3 x S^3 x R^1, and its horizon."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import torch

from rfmp_rl.manifolds.base import Manifold

__all__ = ["Product", "Horizon", "leaf_slices"]


class Product(Manifold):
    """Cartesian product M_1 x ... x M_k; the last tensor dimension is split in component order.

    The metric is the sum of the component metrics, so ``dist**2`` is the sum of squared
    component distances.

    Args:
        components: the factor manifolds, in the order their coordinates appear.

    Example:
        >>> from rfmp_rl.manifolds import Euclidean, Sphere
        >>> pose = Product([Euclidean(3), Sphere(3), Euclidean(1)])  # position, quaternion, gripper
        >>> pose.dim
        8
    """

    def __init__(self, components: Sequence[Manifold]) -> None:
        components = list(components)
        if not components:
            raise ValueError("Product: needs at least one component manifold")
        for c in components:
            if not isinstance(c, Manifold):
                raise TypeError(f"Product: components must be Manifolds, got {type(c).__name__}")
        self.components = components
        self.dims = [c.dim for c in components]
        self.dim = sum(self.dims)
        self.intrinsic_dim = sum(c.intrinsic_dim for c in components)

    def split(self, x: torch.Tensor) -> list[torch.Tensor]:
        """Split the last dimension into component parts."""
        return list(torch.split(x, self.dims, dim=-1))

    def _map(self, fn: str, *tensors: torch.Tensor) -> torch.Tensor:
        parts = zip(*(self.split(t) for t in tensors), strict=True)
        out = [getattr(c, fn)(*p) for c, p in zip(self.components, parts, strict=True)]
        return torch.cat(out, dim=-1)

    def expmap(self, x: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
        return self._map("expmap", x, u)

    def logmap(self, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
        return self._map("logmap", x, y)

    def projx(self, x: torch.Tensor) -> torch.Tensor:
        return self._map("projx", x)

    def proju(self, x: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
        return self._map("proju", x, u)

    def inner(self, x: torch.Tensor, u: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
        parts = zip(self.split(x), self.split(u), self.split(v), strict=True)
        terms = [c.inner(*p) for c, p in zip(self.components, parts, strict=True)]
        return torch.stack(terms, dim=0).sum(dim=0)

    def sqdist(self, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
        parts = zip(self.split(x), self.split(y), strict=True)
        terms = [c.sqdist(*p) for c, p in zip(self.components, parts, strict=True)]
        return torch.stack(terms, dim=0).sum(dim=0)

    def dist(self, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
        return torch.sqrt(torch.clamp(self.sqdist(x, y), min=0.0))

    def geodesic(
        self, x: torch.Tensor, u: torch.Tensor, s: torch.Tensor | float
    ) -> tuple[torch.Tensor, torch.Tensor]:
        points, velocities = [], []
        for c, xc, uc in zip(self.components, self.split(x), self.split(u), strict=True):
            p, v = c.geodesic(xc, uc, s)
            points.append(p)
            velocities.append(v)
        return torch.cat(points, dim=-1), torch.cat(velocities, dim=-1)

    def random_base(self, *shape, generator=None, dtype=None, device=None) -> torch.Tensor:
        parts = [
            c.random_base(*shape, generator=generator, dtype=dtype, device=device)
            for c in self.components
        ]
        return torch.cat(parts, dim=-1)

    def origin(self, *shape, dtype=None, device=None) -> torch.Tensor:
        parts = [c.origin(*shape, dtype=dtype, device=device) for c in self.components]
        return torch.cat(parts, dim=-1)

    def spec(self) -> dict[str, Any]:
        return {"type": "product", "components": [c.spec() for c in self.components]}

    def __repr__(self) -> str:
        return " x ".join(repr(c) for c in self.components)


class Horizon(Manifold):
    """A per-step manifold repeated over ``steps`` time steps (the action chunk of length T_p).

    Points are flat: the last dimension holds ``steps * step.dim`` coordinates, step-major
    (``x.reshape(..., steps, step.dim)`` recovers the chunk). Maps reshape and apply the step
    manifold to all steps at once, so the cost does not grow with the number of components.

    Args:
        step: the manifold of one action, e.g. ``parse_manifold("R3 x S3 x R1")``.
        steps: horizon length T_p.

    Example:
        >>> from rfmp_rl.manifolds import Sphere
        >>> chunk = Horizon(Sphere(2), steps=16)
        >>> x = chunk.random_base(4)                 # (4, 48)
        >>> chunk.unflatten(x).shape
        torch.Size([4, 16, 3])
    """

    def __init__(self, step: Manifold, steps: int) -> None:
        if int(steps) < 1:
            raise ValueError(f"Horizon: steps must be >= 1, got {steps}")
        self.step = step
        self.steps = int(steps)
        self.dim = self.steps * step.dim
        self.intrinsic_dim = self.steps * step.intrinsic_dim

    def unflatten(self, x: torch.Tensor) -> torch.Tensor:
        """``(..., steps * d)`` -> ``(..., steps, d)``."""
        return x.unflatten(-1, (self.steps, self.step.dim))

    def flatten(self, x: torch.Tensor) -> torch.Tensor:
        """``(..., steps, d)`` -> ``(..., steps * d)``."""
        return x.flatten(-2, -1)

    def _map(self, fn: str, *tensors: torch.Tensor) -> torch.Tensor:
        return self.flatten(getattr(self.step, fn)(*(self.unflatten(t) for t in tensors)))

    def expmap(self, x: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
        return self._map("expmap", x, u)

    def logmap(self, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
        return self._map("logmap", x, y)

    def projx(self, x: torch.Tensor) -> torch.Tensor:
        return self._map("projx", x)

    def proju(self, x: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
        return self._map("proju", x, u)

    def inner(self, x: torch.Tensor, u: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
        per_step = self.step.inner(self.unflatten(x), self.unflatten(u), self.unflatten(v))
        return per_step.sum(dim=-2)  # (..., steps, 1) -> (..., 1)

    def sqdist(self, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
        return self.step.sqdist(self.unflatten(x), self.unflatten(y)).sum(dim=-2)

    def dist(self, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
        return torch.sqrt(torch.clamp(self.sqdist(x, y), min=0.0))

    def geodesic(
        self, x: torch.Tensor, u: torch.Tensor, s: torch.Tensor | float
    ) -> tuple[torch.Tensor, torch.Tensor]:
        if isinstance(s, torch.Tensor) and s.dim() > 0:
            s = s.unsqueeze(-1)  # (..., 1) -> (..., 1, 1): broadcast over the steps
        p, v = self.step.geodesic(self.unflatten(x), self.unflatten(u), s)
        return self.flatten(p), self.flatten(v)

    def random_base(self, *shape, generator=None, dtype=None, device=None) -> torch.Tensor:
        x = self.step.random_base(
            *shape, self.steps, generator=generator, dtype=dtype, device=device
        )
        return self.flatten(x)

    def origin(self, *shape, dtype=None, device=None) -> torch.Tensor:
        return self.flatten(self.step.origin(*shape, self.steps, dtype=dtype, device=device))

    def spec(self) -> dict[str, Any]:
        return {"type": "horizon", "steps": self.steps, "step": self.step.spec()}

    def __repr__(self) -> str:
        return f"Horizon({self.step!r}, steps={self.steps})"


def leaf_slices(manifold: Manifold) -> list[tuple[slice, Manifold]]:
    """The non-product factors of a (possibly nested) product and their coordinate slices.

    Example:
        >>> from rfmp_rl.manifolds import parse_manifold
        >>> [(s.start, s.stop, repr(m)) for s, m in leaf_slices(parse_manifold("R3 x S3 x R1"))]
        [(0, 3, 'Euclidean(3)'), (3, 7, 'Sphere(3)'), (7, 8, 'Euclidean(1)')]
    """
    if not isinstance(manifold, Product):
        return [(slice(0, manifold.dim), manifold)]
    out, start = [], 0
    for component in manifold.components:
        for inner, leaf in leaf_slices(component):
            out.append((slice(start + inner.start, start + inner.stop), leaf))
        start += component.dim
    return out
