"""Min-max normalisation whose statistics are buffers (they travel with the weights and into ONNX).

Euclidean coordinates are mapped affinely to [-1, 1]; coordinates that belong to a sphere (unit
quaternions, points of S^2) are left untouched, because rescaling them would move them off the
manifold. The map is ``y = (x - offset) / scale`` with ``offset = 0, scale = 1`` on untouched
coordinates, so it is a single branch-free affine op.
"""

from __future__ import annotations

import torch
from torch import nn

from rfmp_rl.manifolds import Euclidean, Horizon, Manifold, Product, Sphere

__all__ = ["Normalizer", "euclidean_mask"]


def euclidean_mask(manifold: Manifold) -> torch.Tensor:
    """Boolean mask over ``manifold.dim`` coordinates: True where the coordinate is Euclidean."""
    if isinstance(manifold, Euclidean):
        return torch.ones(manifold.dim, dtype=torch.bool)
    if isinstance(manifold, Sphere):
        return torch.zeros(manifold.dim, dtype=torch.bool)
    if isinstance(manifold, Product):
        return torch.cat([euclidean_mask(c) for c in manifold.components])
    if isinstance(manifold, Horizon):
        return euclidean_mask(manifold.step).repeat(manifold.steps)
    raise TypeError(f"euclidean_mask: unsupported manifold {manifold!r}")


class Normalizer(nn.Module):
    """Affine per-coordinate normaliser over the last dimension.

    Args:
        dim: number of coordinates.
        mask: which coordinates to normalise (default: all).
        range_eps: a coordinate whose range is below this is only centred, not scaled.

    Example:
        >>> norm = Normalizer(2)
        >>> norm.fit(torch.tensor([[0.0, 10.0], [4.0, 30.0]]))
        >>> norm(torch.tensor([[2.0, 30.0]]))
        tensor([[0., 1.]])
        >>> norm.unnormalize(norm(torch.tensor([[1.0, 12.0]])))
        tensor([[ 1., 12.]])
    """

    def __init__(self, dim: int, mask: torch.Tensor | None = None, range_eps: float = 1e-4):
        super().__init__()
        mask = torch.ones(dim, dtype=torch.bool) if mask is None else mask.to(torch.bool)
        if mask.shape != (dim,):
            raise ValueError(f"Normalizer: mask must have shape ({dim},), got {tuple(mask.shape)}")
        self.dim, self.range_eps = int(dim), float(range_eps)
        self.register_buffer("mask", mask)
        self.register_buffer("offset", torch.zeros(dim))
        self.register_buffer("scale", torch.ones(dim))
        self.register_buffer("data_min", torch.zeros(dim))
        self.register_buffer("data_max", torch.zeros(dim))
        self.register_buffer("fitted", torch.tensor(False))

    @torch.no_grad()
    def fit(self, data: torch.Tensor) -> None:
        """Set the statistics from data ``(..., dim)`` (every leading dimension is pooled)."""
        if data.shape[-1] != self.dim:
            raise ValueError(
                f"Normalizer.fit: expected data with last dimension {self.dim}, "
                f"got shape {tuple(data.shape)}"
            )
        flat = data.reshape(-1, self.dim).to(torch.float64)
        if not torch.isfinite(flat).all():
            bad = (~torch.isfinite(flat)).any(0).nonzero().flatten().tolist()
            raise ValueError(f"Normalizer.fit: non-finite values in coordinates {bad}")
        self.set_stats(flat.min(0).values, flat.max(0).values)

    @torch.no_grad()
    def set_stats(self, data_min: torch.Tensor, data_max: torch.Tensor) -> None:
        """Set min/max statistics directly (e.g. computed by a demonstration store)."""
        data_min = torch.as_tensor(data_min, dtype=torch.float64).reshape(self.dim)
        data_max = torch.as_tensor(data_max, dtype=torch.float64).reshape(self.dim)
        half = (data_max - data_min) / 2
        centre = (data_max + data_min) / 2
        degenerate = half < self.range_eps
        scale = torch.where(degenerate, torch.ones_like(half), half)
        scale = torch.where(self.mask, scale, torch.ones_like(scale))
        offset = torch.where(self.mask, centre, torch.zeros_like(centre))
        self.offset.copy_(offset)
        self.scale.copy_(scale)
        self.data_min.copy_(data_min)
        self.data_max.copy_(data_max)
        self.fitted.fill_(True)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return (x - self.offset) / self.scale

    normalize = forward

    def unnormalize(self, y: torch.Tensor) -> torch.Tensor:
        return y * self.scale + self.offset

    def extra_repr(self) -> str:
        return f"dim={self.dim}, normalised={int(self.mask.sum())}"
