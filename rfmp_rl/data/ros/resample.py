"""Resampling onto the episode grid: linear for vectors, slerp (the geodesic of S^3 from
`rfmp_rl.manifolds.Sphere`) for unit quaternions, nearest sample for images and flags."""

from __future__ import annotations

import torch

from rfmp_rl.manifolds import Sphere
from rfmp_rl.manifolds.quaternion import hemisphere_continuous

__all__ = ["slerp", "resample_linear", "resample_slerp", "nearest_indices"]

_S3 = Sphere(3)



def slerp(q0: torch.Tensor, q1: torch.Tensor, w: torch.Tensor | float) -> torch.Tensor:
    """Spherical linear interpolation between unit quaternions along the great circle of S^3.

    ``q0`` and ``q1`` are interpolated as given (no sign flip): for the shorter rotation make
    them hemisphere-continuous first. The path is the geodesic of `rfmp_rl.manifolds.Sphere`,
    ``Exp_q0(w Log_q0(q1))``, whose per-dtype guards keep nearly equal quaternions finite and
    unit; exactly antipodal ones (no unique shortest path) take the sphere's fixed direction.

    Args:
        q0, q1: unit quaternions, shape ``(..., 4)`` (any component order).
        w: interpolation weights in ``[0, 1]``, shape ``(...)`` or a float: 0 gives ``q0``.

    Returns:
        Unit quaternions, shape ``(..., 4)``.

    Example:
        >>> import math
        >>> h = math.sqrt(0.5)
        >>> q = slerp(torch.tensor([0.0, 0, 0, 1]), torch.tensor([0.0, 0, h, h]), 0.5)
        >>> q  # half of a 90 degree rotation about z: 45 degrees
        tensor([0.0000, 0.0000, 0.3827, 0.9239])
        >>> round(float(2 * torch.atan2(q[2], q[3]).rad2deg()), 4)
        45.0
    """
    q0, q1 = torch.broadcast_tensors(q0, q1)
    w = torch.as_tensor(w, dtype=q0.dtype, device=q0.device)[..., None]
    point, _ = _S3.geodesic(q0, _S3.logmap(q0, q1), w)
    return point


def _brackets(times: torch.Tensor, grid: torch.Tensor) -> tuple[torch.Tensor, ...]:
    """Indices ``i, j = i + 1`` of the samples around each grid time and the weight of ``j``,
    clamped so that grid times outside ``[times[0], times[-1]]`` hold the end values."""
    n = times.shape[0]
    if n == 0:
        raise ValueError("cannot resample a stream without samples")
    if n > 1 and not bool((times[1:] > times[:-1]).all()):
        raise ValueError("sample times must be strictly increasing")
    i = (torch.searchsorted(times, grid, right=True) - 1).clamp(0, max(n - 2, 0))
    j = (i + 1).clamp(max=n - 1)
    span = times[j] - times[i]
    w = torch.where(span > 0, (grid - times[i]) / torch.where(span > 0, span, 1), 0)
    return i, j, w.clamp(0, 1)


def resample_linear(times: torch.Tensor, values: torch.Tensor, grid: torch.Tensor) -> torch.Tensor:
    """Linear interpolation of ``values`` sampled at ``times`` onto ``grid``; grid times outside
    the samples' span take the first/last value.

    Args:
        times: strictly increasing sample times, shape ``(N,)``.
        values: samples, shape ``(N, ...)``.
        grid: query times, shape ``(T,)``.

    Returns:
        Shape ``(T, ...)``, in the dtype of ``values``.

    Example:
        >>> resample_linear(torch.tensor([0.0, 1.0, 3.0]), torch.tensor([[0.0], [2.0], [0.0]]),
        ...                 torch.tensor([-1.0, 0.5, 2.0, 4.0]))
        tensor([[0.],
                [1.],
                [1.],
                [0.]])
    """
    i, j, w = _brackets(times, grid)
    w = w.to(values.dtype).reshape(-1, *([1] * (values.ndim - 1)))
    return values[i] + w * (values[j] - values[i])


def resample_slerp(times: torch.Tensor, quats: torch.Tensor, grid: torch.Tensor) -> torch.Tensor:
    """Slerp of a quaternion trajectory onto ``grid`` after removing its sign flips.

    The samples are made hemisphere-continuous (``q_k -> -q_k`` when ``<q_k, q_{k-1}> < 0``),
    then each grid time is interpolated between the samples around it; outside the samples'
    span the first/last sample is held. The result keeps the sign of the first sample and is
    itself hemisphere-continuous.

    Args:
        times: strictly increasing sample times, shape ``(N,)``.
        quats: unit quaternions, shape ``(N, 4)``.
        grid: query times, shape ``(T,)``.

    Returns:
        Unit quaternions, shape ``(T, 4)``.

    Example:
        >>> import math
        >>> h = math.sqrt(0.5)
        >>> q = torch.tensor([[0.0, 0, 0, 1], [0.0, 0, -h, -h]])  # 90 deg about z, stored as -q
        >>> resample_slerp(torch.tensor([0.0, 1.0]), q, torch.tensor([0.0, 0.5, 1.0]))
        tensor([[0.0000, 0.0000, 0.0000, 1.0000],
                [0.0000, 0.0000, 0.3827, 0.9239],
                [0.0000, 0.0000, 0.7071, 0.7071]])
    """
    quats = hemisphere_continuous(quats, dim=-2)
    i, j, w = _brackets(times, grid)
    out = slerp(quats[i], quats[j], w.to(quats.dtype))
    return hemisphere_continuous(out, dim=-2)


def nearest_indices(times: torch.Tensor, grid: torch.Tensor) -> torch.Tensor:
    """For each grid time, the index of the sample nearest in time (ties: the earlier sample).

    Args:
        times: increasing sample times, shape ``(N,)``, N >= 1.
        grid: query times, shape ``(T,)``.

    Returns:
        int64 indices into ``times``, shape ``(T,)``.

    Example:
        >>> nearest_indices(torch.tensor([0.0, 1.0, 2.0]), torch.tensor([-5.0, 0.4, 0.5, 1.6, 9.0]))
        tensor([0, 0, 0, 2, 2])
    """
    n = times.shape[0]
    if n == 0:
        raise ValueError("cannot pick from a stream without samples")
    hi = torch.searchsorted(times, grid).clamp(0, n - 1)
    lo = (hi - 1).clamp(min=0)
    take_lo = (grid - times[lo]).abs() <= (times[hi] - grid).abs()
    return torch.where(take_lo, lo, hi)
