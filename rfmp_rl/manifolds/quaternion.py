"""Unit-quaternion helpers: sign canonicalisation and hemisphere continuity.

A rotation is represented by two antipodal unit quaternions q and -q. Demonstration data often
switches between them from one sample to the next (sensor drivers canonicalise independently),
which looks like a jump of length pi on S^3. These helpers remove that ambiguity. The scalar
part's position is a parameter: ``w_index=-1`` for the xyzw order (ROS, robosuite, scipy),
``w_index=0`` for wxyz.
"""

from __future__ import annotations

import torch

__all__ = ["canonicalize_quaternion", "hemisphere_continuous"]


def canonicalize_quaternion(q: torch.Tensor, w_index: int = -1) -> torch.Tensor:
    """Flip the sign of each quaternion so that its scalar part is non-negative.

    Args:
        q: quaternions, shape ``(..., 4)``.
        w_index: position of the scalar part in the last dimension.

    Returns:
        The same rotations with ``q[..., w_index] >= 0``.

    Example:
        >>> canonicalize_quaternion(torch.tensor([0.0, 0.0, 0.6, -0.8]))
        tensor([-0.0000, -0.0000, -0.6000,  0.8000])
    """
    if q.shape[-1] != 4:
        raise ValueError(f"canonicalize_quaternion: expected shape (..., 4), got {tuple(q.shape)}")
    w = q[..., w_index : w_index + 1] if w_index != -1 else q[..., -1:]
    return torch.where(w < 0, -q, q)


def hemisphere_continuous(q: torch.Tensor, dim: int = -2) -> torch.Tensor:
    """Flip signs along a trajectory so that consecutive quaternions are in the same hemisphere.

    The first quaternion is kept; every later one is negated when its dot product with the
    (already corrected) previous one is negative. Vectorised: the corrected sign of step k is the
    cumulative product of the raw pairwise signs.

    Args:
        q: quaternions along time, shape ``(..., T, 4)`` (time at ``dim``).
        dim: the time dimension.

    Returns:
        A trajectory of the same rotations with ``<q_k, q_{k-1}> >= 0`` for every k.
    """
    if q.shape[-1] != 4:
        raise ValueError(f"hemisphere_continuous: expected shape (..., T, 4), got {tuple(q.shape)}")
    q = q.movedim(dim, -2)
    dots = (q[..., 1:, :] * q[..., :-1, :]).sum(dim=-1, keepdim=True)  # (..., T-1, 1)
    flips = torch.where(dots < 0, -torch.ones_like(dots), torch.ones_like(dots))
    signs = torch.cat([torch.ones_like(flips[..., :1, :]), torch.cumprod(flips, dim=-2)], dim=-2)
    return (q * signs).movedim(-2, dim)
