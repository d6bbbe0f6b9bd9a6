"""Conditional probability paths and their target vector fields.

`GeodesicPath` is RFMP's path (paper Eq. 6); `StablePath` is SRFMP's stable path with the
pseudo-time tau (Eqs. 17-18). Both are evaluated in closed form through the manifold's
`geodesic` map, so the target velocity is exact at every t (no division by ``1 - t``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from rfmp_rl.manifolds import Manifold

__all__ = ["PathSample", "GeodesicPath", "StablePath", "sample_time", "sample_time_via_tau"]


@dataclass
class PathSample:
    """A point on a conditional path and the target velocity there.

    Attributes:
        x_t: points ``(..., dim)``.
        u_t: target velocities in ``T_{x_t} M``, ``(..., dim)``.
        t: flow times ``(..., 1)``.
        tau_t: SRFMP pseudo-time ``(..., 1)`` (None for RFMP).
        u_tau: SRFMP pseudo-time velocity ``(..., 1)`` (None for RFMP).
    """

    x_t: torch.Tensor
    u_t: torch.Tensor
    t: torch.Tensor
    tau_t: torch.Tensor | None = None
    u_tau: torch.Tensor | None = None


def _as_column(t: torch.Tensor | float, like: torch.Tensor) -> torch.Tensor:
    t = torch.as_tensor(t, dtype=like.dtype, device=like.device)
    if t.dim() == like.dim() - 1:
        t = t.unsqueeze(-1)
    return t.expand(*like.shape[:-1], 1)


class GeodesicPath:
    """RFMP's geodesic path from x_0 (t=0) to x_1 (t=1).

    ``x_t = Exp_{x1}((1 - t) Log_{x1}(x0))`` and ``u_t = d x_t / dt`` (Chen & Lipman, 2024; the
    paper's Eq. 6 written with the geodesic's parameter running from x_0 to x_1). On R^n this is
    ``x_t = (1 - t) x0 + t x1`` with ``u_t = x1 - x0``.

    Example:
        >>> from rfmp_rl.manifolds import Sphere
        >>> path = GeodesicPath(Sphere(2))
        >>> x0, x1 = Sphere(2).random_base(8), Sphere(2).random_base(8)
        >>> s = path.sample(x0, x1, torch.rand(8))
        >>> s.x_t.shape, s.u_t.shape
        (torch.Size([8, 3]), torch.Size([8, 3]))
    """

    def __init__(self, manifold: Manifold) -> None:
        self.manifold = manifold

    def sample(self, x0: torch.Tensor, x1: torch.Tensor, t: torch.Tensor | float) -> PathSample:
        t = _as_column(t, x1)
        w = self.manifold.logmap(x1, x0)
        x_t, velocity = self.manifold.geodesic(x1, w, 1.0 - t)
        return PathSample(x_t=x_t, u_t=-velocity, t=t)


class StablePath:
    """SRFMP's stable path on ``M x R`` (paper Eqs. 17-18).

    ``x_t = Exp_{x1}(exp(-lambda_x t) Log_{x1}(x0))``,
    ``tau_t = tau1 + exp(-lambda_tau t) (tau0 - tau1)``,
    with the autonomous target field ``u_x = lambda_x Log_{x_t}(x1)`` (the paper's
    ``-lambda_x Log_{x1}(x_t)`` expressed in the tangent space at x_t, where a velocity of x_t
    lives; the two agree on R^n) and ``u_tau = -lambda_tau (tau_t - tau1)``.

    Args:
        manifold: the action (chunk) manifold.
        lambda_x: spatial convergence rate (paper default 2.5).
        lambda_tau: pseudo-time convergence rate (paper default 2.5).
        tau0: pseudo-time at t=0.
        tau1: pseudo-time limit.

    Example:
        >>> from rfmp_rl.manifolds import Euclidean
        >>> path = StablePath(Euclidean(2))
        >>> s = path.sample(torch.zeros(1, 2), torch.ones(1, 2), 0.0)
        >>> s.u_t
        tensor([[2.5000, 2.5000]])
    """

    def __init__(
        self,
        manifold: Manifold,
        lambda_x: float = 2.5,
        lambda_tau: float = 2.5,
        tau0: float = 0.0,
        tau1: float = 1.0,
    ) -> None:
        if lambda_x <= 0 or lambda_tau <= 0:
            raise ValueError(
                f"StablePath: lambda_x and lambda_tau must be > 0, got {lambda_x}, {lambda_tau}"
            )
        if tau0 == tau1:
            raise ValueError(f"StablePath: tau0 and tau1 must differ, both are {tau0}")
        self.manifold = manifold
        self.lambda_x, self.lambda_tau = float(lambda_x), float(lambda_tau)
        self.tau0, self.tau1 = float(tau0), float(tau1)

    def tau_at(self, t: torch.Tensor) -> torch.Tensor:
        """Pseudo-time at flow time t (Eq. 18, second row)."""
        return self.tau1 + torch.exp(-self.lambda_tau * t) * (self.tau0 - self.tau1)

    def time_of_tau(self, tau: torch.Tensor) -> torch.Tensor:
        """Inverse of `tau_at` for tau strictly between tau0 and tau1."""
        ratio = (tau - self.tau1) / (self.tau0 - self.tau1)
        return -torch.log(ratio) / self.lambda_tau

    def sample(self, x0: torch.Tensor, x1: torch.Tensor, t: torch.Tensor | float) -> PathSample:
        t = _as_column(t, x1)
        decay = torch.exp(-self.lambda_x * t)
        w = self.manifold.logmap(x1, x0)
        x_t, velocity = self.manifold.geodesic(x1, w, decay)
        u_x = -self.lambda_x * decay * velocity  # = lambda_x Log_{x_t}(x1), exactly
        tau_t = self.tau_at(t)
        return PathSample(x_t=x_t, u_t=u_x, t=t, tau_t=tau_t, u_tau=self.tau_field(tau_t))

    def target_field(self, x: torch.Tensor, x1: torch.Tensor) -> torch.Tensor:
        """The autonomous spatial target field ``lambda_x Log_x(x1)`` at arbitrary points x."""
        return self.lambda_x * self.manifold.logmap(x, x1)

    def tau_field(self, tau: torch.Tensor) -> torch.Tensor:
        """The pseudo-time target field ``-lambda_tau (tau - tau1)``."""
        return -self.lambda_tau * (tau - self.tau1)


def sample_time(
    *shape: int, generator: torch.Generator | None = None, dtype=None, device=None
) -> torch.Tensor:
    """Flow times t ~ U[0, 1], shape ``(*shape, 1)``."""
    return torch.rand(*shape, 1, generator=generator, dtype=dtype, device=device)


def sample_time_via_tau(
    path: StablePath,
    *shape: int,
    t_max: float = 1.0,
    generator: torch.Generator | None = None,
    dtype=None,
    device=None,
) -> torch.Tensor:
    """Flow times whose pseudo-time is uniform: tau ~ U[tau0, tau(t_max)], then t = t(tau).

    With lambda_tau = 2.5 this puts more training times early in the flow, where x_t moves
    fastest, than t ~ U[0, 1] does. Shape ``(*shape, 1)``, values in ``[0, t_max]``.
    """
    u = torch.rand(*shape, 1, generator=generator, dtype=dtype, device=device)
    # tau = tau1 + r (tau0 - tau1), r = exp(-lambda_tau t) uniform on [exp(-lambda_tau t_max), 1]
    r_min = math.exp(-path.lambda_tau * t_max)
    r = 1.0 - u * (1.0 - r_min)
    return -torch.log(r) / path.lambda_tau
