"""Flat space R^n."""

from __future__ import annotations

from typing import Any

import torch

from rfmp_rl.manifolds.base import Manifold

__all__ = ["Euclidean"]


class Euclidean(Manifold):
    """Euclidean space R^dim with the standard metric.

    Args:
        dim: number of coordinates.

    Example:
        >>> r3 = Euclidean(3)
        >>> r3.logmap(torch.zeros(3), torch.ones(3))
        tensor([1., 1., 1.])
    """

    def __init__(self, dim: int) -> None:
        if int(dim) < 1:
            raise ValueError(f"Euclidean: dim must be >= 1, got {dim}")
        self.dim = int(dim)
        self.intrinsic_dim = self.dim

    def expmap(self, x: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
        return x + u

    def logmap(self, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
        return y - x

    def projx(self, x: torch.Tensor) -> torch.Tensor:
        return x

    def proju(self, x: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
        return u

    def inner(self, x: torch.Tensor, u: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
        return (u * v).sum(dim=-1, keepdim=True)

    def geodesic(
        self, x: torch.Tensor, u: torch.Tensor, s: torch.Tensor | float
    ) -> tuple[torch.Tensor, torch.Tensor]:
        return x + s * u, u + 0.0 * s

    def random_base(self, *shape, generator=None, dtype=None, device=None) -> torch.Tensor:
        return torch.randn(*shape, self.dim, generator=generator, dtype=dtype, device=device)

    def origin(self, *shape, dtype=None, device=None) -> torch.Tensor:
        return torch.zeros(*shape, self.dim, dtype=dtype, device=device)

    def spec(self) -> dict[str, Any]:
        return {"type": "euclidean", "dim": self.dim}

    def __repr__(self) -> str:
        return f"Euclidean({self.dim})"
