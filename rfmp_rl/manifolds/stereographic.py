"""The plane <-> sphere map of the paper's Sphere Push-T task (stereographic projection).

A planar point ``(x, y)`` (after dividing by ``scale``) is placed on the plane ``z = 1`` that
touches the unit sphere S^2 at the north pole and is projected onto the sphere along the line
through the south pole ``(0, 0, -1)``. With ``r^2 = x^2 + y^2``,

    p = (4 x, 4 y, 4 - r^2) / (r^2 + 4),            (x, y) = 2 (X, Y) / (1 + Z).

The plane origin goes to the north pole, the circle ``r = 2`` to the equator, and the whole
plane covers the sphere except the south pole. Both maps are branch-free tensor code (they trace
and export to ONNX) and are exact inverses of each other away from the south pole.
"""

from __future__ import annotations

import torch

from rfmp_rl.manifolds.base import eps_for

__all__ = ["plane_to_sphere", "sphere_to_plane"]


def plane_to_sphere(xy: torch.Tensor, scale: float = 1.0) -> torch.Tensor:
    """Project plane points onto S^2 from the south pole (Sphere Push-T map).

    Args:
        xy: plane points, shape ``(..., 2)``.
        scale: plane units per unit of the tangent plane ``z = 1``; points are divided by it
            first (e.g. the normalisation that maps a workspace to ``[-1.5, 1.5]``).

    Returns:
        Unit vectors, shape ``(..., 3)``; ``(0, 0)`` maps to the north pole ``(0, 0, 1)``.

    Example:
        >>> plane_to_sphere(torch.tensor([[0.0, 0.0], [2.0, 0.0]]))
        tensor([[0., 0., 1.],
                [1., 0., 0.]])
    """
    if xy.shape[-1] != 2:
        raise ValueError(f"plane_to_sphere: expected shape (..., 2), got {tuple(xy.shape)}")
    xy = xy / scale
    r2 = (xy * xy).sum(dim=-1, keepdim=True)  # (..., 1)
    denom = r2 + 4.0
    return torch.cat([4.0 * xy / denom, (4.0 - r2) / denom], dim=-1)  # (..., 3)


def sphere_to_plane(p: torch.Tensor, scale: float = 1.0) -> torch.Tensor:
    """Inverse of `plane_to_sphere`: ``(x, y) = 2 (X, Y) / (1 + Z) * scale``.

    The south pole ``(0, 0, -1)`` has no image (it lies at infinity); ``1 + Z`` is clamped
    from below by a per-dtype epsilon so the result stays finite there.

    Args:
        p: points on S^2, shape ``(..., 3)``.
        scale: the same ``scale`` that was given to `plane_to_sphere`.

    Returns:
        Plane points, shape ``(..., 2)``.

    Example:
        >>> xy = torch.tensor([[0.3, -1.2], [1.5, 1.5]])
        >>> torch.allclose(sphere_to_plane(plane_to_sphere(xy, 2.0), 2.0), xy, atol=1e-6)
        True
    """
    if p.shape[-1] != 3:
        raise ValueError(f"sphere_to_plane: expected shape (..., 3), got {tuple(p.shape)}")
    denom = torch.clamp(1.0 + p[..., 2:], min=eps_for(p.dtype))  # (..., 1)
    return 2.0 * p[..., :2] / denom * scale
