"""The unit hypersphere S^n embedded in R^(n+1) (unit quaternions are `Sphere(3)`)."""

from __future__ import annotations

import math
from typing import Any

import torch

from rfmp_rl.manifolds.base import Manifold, eps_for, safe_norm

__all__ = ["Sphere"]


class Sphere(Manifold):
    """The unit sphere S^n = {x in R^(n+1) : |x| = 1} with the round metric.

    Closed-form maps (Absil et al., 2008): with ``theta = |u|``,
    ``Exp_x(u) = cos(theta) x + sin(theta) u / theta``; with ``c = <x, y>`` and
    ``v = y - c x``, ``Log_x(y) = atan2(|v|, c) v / |v|``. Division by zero norms is guarded with
    per-dtype epsilons, so ``logmap(x, x) = 0`` with finite gradients. At exactly antipodal
    points (where every direction is a shortest geodesic) ``logmap`` returns a deterministic
    tangent vector of length pi instead of a NaN.

    Args:
        n: intrinsic dimension; points have ``n + 1`` coordinates.

    Example:
        >>> s3 = Sphere(3)  # unit quaternions
        >>> q = s3.random_base(5)
        >>> torch.allclose(q.norm(dim=-1), torch.ones(5))
        True
    """

    def __init__(self, n: int) -> None:
        if int(n) < 1:
            raise ValueError(f"Sphere: n must be >= 1 (S^n lives in R^(n+1)), got {n}")
        self.n = int(n)
        self.dim = self.n + 1
        self.intrinsic_dim = self.n

    # ----- projections -------------------------------------------------------------------------
    def projx(self, x: torch.Tensor) -> torch.Tensor:
        # A zero vector has no closest point; map it to the origin rather than to NaN.
        norm = safe_norm(x)
        tiny = norm <= 2 * eps_for(x.dtype)
        return torch.where(tiny, self.origin(dtype=x.dtype, device=x.device), x / norm)

    def proju(self, x: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
        return u - (x * u).sum(dim=-1, keepdim=True) * x

    def inner(self, x: torch.Tensor, u: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
        return (u * v).sum(dim=-1, keepdim=True)

    # ----- geodesics ---------------------------------------------------------------------------
    def expmap(self, x: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
        theta = safe_norm(u)
        y = torch.cos(theta) * x + (torch.sin(theta) / theta) * u
        return self.projx(y)

    def logmap(self, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
        c = torch.clamp((x * y).sum(dim=-1, keepdim=True), -1.0, 1.0)
        v = y - c * x
        vn = safe_norm(v)
        theta = torch.atan2(vn, c)
        log = v * (theta / vn)
        # Exactly antipodal: v is rounding noise. Return a fixed tangent direction of length pi.
        antipodal = (vn <= 16 * eps_for(x.dtype)) & (c < 0)
        return torch.where(antipodal, math.pi * self._fallback_direction(x), log)

    def dist(self, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
        c = torch.clamp((x * y).sum(dim=-1, keepdim=True), -1.0, 1.0)
        return torch.atan2(safe_norm(y - c * x), c)

    def sqdist(self, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
        return self.dist(x, y) ** 2

    def geodesic(
        self, x: torch.Tensor, u: torch.Tensor, s: torch.Tensor | float
    ) -> tuple[torch.Tensor, torch.Tensor]:
        theta = safe_norm(u)
        angle = s * theta
        cos, sin = torch.cos(angle), torch.sin(angle)
        point = self.projx(cos * x + (sin / theta) * u)
        velocity = cos * u - (theta * sin) * x
        return point, velocity

    def _fallback_direction(self, x: torch.Tensor) -> torch.Tensor:
        # Of e_0 and e_1 projected onto T_x, at least one has squared norm >= 1/2.
        eye = torch.eye(self.dim, dtype=x.dtype, device=x.device)
        e0, e1 = eye[0].expand_as(x), eye[1].expand_as(x)
        f0, f1 = self.proju(x, e0), self.proju(x, e1)
        n0, n1 = safe_norm(f0), safe_norm(f1)
        return torch.where(n0 >= n1, f0 / n0, f1 / n1)

    # ----- sampling ----------------------------------------------------------------------------
    def random_base(self, *shape, generator=None, dtype=None, device=None) -> torch.Tensor:
        """Uniform samples on S^n (normalised standard normals)."""
        z = torch.randn(*shape, self.dim, generator=generator, dtype=dtype, device=device)
        return self.projx(z)

    def origin(self, *shape, dtype=None, device=None) -> torch.Tensor:
        """The pole e_n = (0, ..., 0, 1): the north pole of S^2, the identity xyzw quaternion."""
        zeros = torch.zeros(*shape, self.dim - 1, dtype=dtype, device=device)
        ones = torch.ones(*shape, 1, dtype=dtype, device=device)
        return torch.cat([zeros, ones], dim=-1)

    def spec(self) -> dict[str, Any]:
        return {"type": "sphere", "n": self.n}

    def __repr__(self) -> str:
        return f"Sphere({self.n})"
