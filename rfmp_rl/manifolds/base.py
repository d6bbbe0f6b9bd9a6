"""The `Manifold` interface: a handful of branch-free tensor maps.

Points and tangent vectors are plain tensors whose **last dimension** holds the ambient
coordinates (``manifold.dim`` of them); every leading dimension is a batch dimension. All maps
are written with ``torch.where`` and clamps instead of data-dependent Python branches, so they
trace and export to ONNX unchanged.
"""

from __future__ import annotations

import abc
from typing import Any

import torch

__all__ = ["Manifold", "eps_for", "safe_norm"]

_EPS = {torch.float16: 1e-3, torch.bfloat16: 1e-2, torch.float32: 1e-7, torch.float64: 1e-15}


def eps_for(dtype: torch.dtype) -> float:
    """Return the small constant used to guard divisions and square roots for ``dtype``."""
    return _EPS.get(dtype, 1e-7)


def safe_norm(x: torch.Tensor, dim: int = -1, keepdim: bool = True) -> torch.Tensor:
    """Euclidean norm whose value and gradient stay finite at zero.

    The squared norm is clamped from below by ``eps**2`` before the square root, so the norm of
    a zero vector is ``eps`` (not 0) and its gradient is 0 (not NaN).
    """
    eps = eps_for(x.dtype)
    return torch.sqrt(torch.clamp((x * x).sum(dim=dim, keepdim=keepdim), min=eps * eps))


class Manifold(abc.ABC):
    """A Riemannian manifold embedded in R^dim.

    Subclasses implement the maps below on tensors of shape ``(..., dim)``.

    Example:
        >>> from rfmp_rl.manifolds import Sphere
        >>> s2 = Sphere(2)
        >>> x = s2.origin()
        >>> y = s2.expmap(x, torch.tensor([0.5, 0.0, 0.0]))
        >>> float(s2.dist(x, y))
        0.5
    """

    #: number of ambient coordinates (size of the last tensor dimension)
    dim: int
    #: dimension of the manifold itself (``dim - 1`` for a sphere)
    intrinsic_dim: int

    @abc.abstractmethod
    def expmap(self, x: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
        """Exponential map: the geodesic from ``x`` with initial velocity ``u``, at time 1."""

    @abc.abstractmethod
    def logmap(self, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
        """Logarithmic map: the tangent vector at ``x`` whose exponential is ``y``."""

    @abc.abstractmethod
    def projx(self, x: torch.Tensor) -> torch.Tensor:
        """Closest point on the manifold to an ambient point."""

    @abc.abstractmethod
    def proju(self, x: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
        """Orthogonal projection of an ambient vector onto the tangent space at ``x``."""

    @abc.abstractmethod
    def inner(self, x: torch.Tensor, u: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
        """Riemannian inner product <u, v>_x, shape ``(..., 1)``."""

    @abc.abstractmethod
    def geodesic(
        self, x: torch.Tensor, u: torch.Tensor, s: torch.Tensor | float
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Point and velocity of the geodesic ``c(s) = Exp_x(s u)`` at ``s``.

        Returns ``(c(s), dc/ds)``; ``dc/ds`` is ``u`` parallel-transported to ``c(s)``.
        ``s`` broadcasts against ``x[..., :1]``. Computed without dividing by ``s`` so it is
        exact at ``s = 0``.
        """

    @abc.abstractmethod
    def random_base(
        self,
        *shape: int,
        generator: torch.Generator | None = None,
        dtype: torch.dtype | None = None,
        device: torch.device | str | None = None,
    ) -> torch.Tensor:
        """Sample the manifold's reference distribution, shape ``(*shape, dim)``.

        Standard normal on Euclidean spaces, uniform on spheres, componentwise on products.
        """

    @abc.abstractmethod
    def origin(
        self,
        *shape: int,
        dtype: torch.dtype | None = None,
        device: torch.device | str | None = None,
    ) -> torch.Tensor:
        """A fixed reference point on the manifold, shape ``(*shape, dim)``."""

    @abc.abstractmethod
    def spec(self) -> dict[str, Any]:
        """A JSON-serialisable description; `rfmp_rl.manifolds.from_spec` rebuilds the manifold."""

    # ----- derived maps ------------------------------------------------------------------------
    def norm(self, x: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
        """Riemannian norm ||u||_x, shape ``(..., 1)``."""
        return torch.sqrt(torch.clamp(self.inner(x, u, u), min=0.0))

    def dist(self, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
        """Geodesic distance, shape ``(..., 1)``; equals ``norm(x, logmap(x, y))``."""
        return self.norm(x, self.logmap(x, y))

    def sqdist(self, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
        """Squared geodesic distance, shape ``(..., 1)`` (smooth at ``x == y``)."""
        u = self.logmap(x, y)
        return self.inner(x, u, u)

    def check_point(self, x: torch.Tensor) -> torch.Tensor:
        """Distance of ``x`` from the manifold in the ambient space, shape ``(..., 1)``."""
        return (x - self.projx(x)).norm(dim=-1, keepdim=True)

    def _check_last_dim(self, x: torch.Tensor, name: str = "x") -> None:
        if x.shape[-1] != self.dim:
            raise ValueError(
                f"{type(self).__name__}: expected {name} with last dimension {self.dim}, "
                f"got shape {tuple(x.shape)}"
            )

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Manifold) and self.spec() == other.spec()

    def __hash__(self) -> int:
        return hash(repr(self.spec()))
