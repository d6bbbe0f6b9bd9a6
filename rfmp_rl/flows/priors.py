"""Prior (base) distributions p_0 on manifolds.

Every prior is a deterministic, branch-free map ``from_noise`` applied to standard-normal noise
of shape ``(..., noise_dim)``. Training draws the noise with torch; an exported ONNX policy takes
it as a graph input, so a robot controller reproduces a PyTorch run by feeding the same noise.
"""

from __future__ import annotations

import abc
from collections.abc import Sequence
from typing import Any

import torch

from rfmp_rl.manifolds import Euclidean, Horizon, Manifold, Product, Sphere, from_spec

__all__ = [
    "Prior",
    "GaussianPrior",
    "UniformSpherePrior",
    "WrappedGaussianPrior",
    "ProductPrior",
    "HorizonPrior",
    "make_prior",
    "prior_from_spec",
]


class Prior(abc.ABC):
    """A distribution on ``self.manifold`` sampled by transforming standard-normal noise."""

    manifold: Manifold
    #: size of the last dimension of the noise consumed by `from_noise`
    noise_dim: int

    @abc.abstractmethod
    def from_noise(self, eps: torch.Tensor) -> torch.Tensor:
        """Map standard-normal noise ``(..., noise_dim)`` to points ``(..., manifold.dim)``."""

    @abc.abstractmethod
    def mode(self, *shape: int, dtype=None, device=None) -> torch.Tensor:
        """A fixed point on the manifold (used for deterministic sampling), ``(*shape, dim)``."""

    @abc.abstractmethod
    def spec(self) -> dict[str, Any]:
        """A JSON-serialisable description; `prior_from_spec` rebuilds the prior."""

    def noise(self, *shape: int, generator=None, dtype=None, device=None) -> torch.Tensor:
        """Standard-normal noise ``(*shape, noise_dim)`` for `from_noise`."""
        return torch.randn(*shape, self.noise_dim, generator=generator, dtype=dtype, device=device)

    def sample(self, *shape: int, generator=None, dtype=None, device=None) -> torch.Tensor:
        """Samples ``(*shape, manifold.dim)``."""
        eps = self.noise(*shape, generator=generator, dtype=dtype, device=device)
        return self.from_noise(eps)


class GaussianPrior(Prior):
    """N(mean, std^2 I) on R^n.

    Example:
        >>> p = GaussianPrior(Euclidean(2), std=1.0)
        >>> p.sample(3).shape
        torch.Size([3, 2])
    """

    def __init__(self, manifold: Euclidean, std: float = 1.0, mean: float = 0.0) -> None:
        if not isinstance(manifold, Euclidean):
            raise TypeError(f"GaussianPrior needs a Euclidean manifold, got {manifold!r}")
        if std <= 0:
            raise ValueError(f"GaussianPrior: std must be > 0, got {std}")
        self.manifold, self.noise_dim = manifold, manifold.dim
        self.std, self.mean = float(std), float(mean)

    def from_noise(self, eps: torch.Tensor) -> torch.Tensor:
        return self.mean + self.std * eps

    def mode(self, *shape, dtype=None, device=None) -> torch.Tensor:
        return self.manifold.origin(*shape, dtype=dtype, device=device) + self.mean

    def spec(self) -> dict[str, Any]:
        return {
            "type": "gaussian",
            "manifold": self.manifold.spec(),
            "std": self.std,
            "mean": self.mean,
        }


class UniformSpherePrior(Prior):
    """The uniform distribution on S^n: normalised standard normals (the paper's Fig. 8, right).

    Example:
        >>> p = UniformSpherePrior(Sphere(2))
        >>> torch.allclose(p.sample(4).norm(dim=-1), torch.ones(4))
        True
    """

    def __init__(self, manifold: Sphere) -> None:
        if not isinstance(manifold, Sphere):
            raise TypeError(f"UniformSpherePrior needs a Sphere, got {manifold!r}")
        self.manifold, self.noise_dim = manifold, manifold.dim

    def from_noise(self, eps: torch.Tensor) -> torch.Tensor:
        return self.manifold.projx(eps)  # projx maps the (measure-zero) zero vector to the origin

    def mode(self, *shape, dtype=None, device=None) -> torch.Tensor:
        return self.manifold.origin(*shape, dtype=dtype, device=device)

    def spec(self) -> dict[str, Any]:
        return {"type": "uniform_sphere", "manifold": self.manifold.spec()}


class WrappedGaussianPrior(Prior):
    """Wrapped Gaussian: ``Exp_b(scale * proju(b, eps))`` with ``eps ~ N(0, I)`` (Fig. 8, left).

    Args:
        manifold: any manifold.
        scale: standard deviation in the tangent space at the base point.
        base: base point ``(dim,)``; defaults to ``manifold.origin()``.

    Example:
        >>> p = WrappedGaussianPrior(Sphere(2), scale=0.1)
        >>> bool((p.sample(100) - Sphere(2).origin()).norm(dim=-1).max() < 1.0)
        True
    """

    def __init__(
        self,
        manifold: Manifold,
        scale: float = 1.0,
        base: torch.Tensor | Sequence[float] | None = None,
    ) -> None:
        if scale <= 0:
            raise ValueError(f"WrappedGaussianPrior: scale must be > 0, got {scale}")
        self.manifold, self.noise_dim, self.scale = manifold, manifold.dim, float(scale)
        if base is None:
            base_t = manifold.origin(dtype=torch.float64)
        else:
            base_t = torch.as_tensor(base).to(torch.float64)
        if base_t.shape != (manifold.dim,):
            raise ValueError(
                f"WrappedGaussianPrior: base must have shape ({manifold.dim},), "
                f"got {tuple(base_t.shape)}"
            )
        self.base_raw = base_t  # as given; the spec stores it, so a rebuilt prior is identical
        self.base = manifold.projx(base_t)  # float64, cast to the noise's dtype when sampling

    def from_noise(self, eps: torch.Tensor) -> torch.Tensor:
        base = self.base.to(dtype=eps.dtype, device=eps.device).expand_as(eps)
        return self.manifold.expmap(base, self.scale * self.manifold.proju(base, eps))

    def mode(self, *shape, dtype=None, device=None) -> torch.Tensor:
        base = self.base.to(dtype=dtype or torch.get_default_dtype(), device=device)
        return base.expand(*shape, -1).clone()

    def spec(self) -> dict[str, Any]:
        return {
            "type": "wrapped_gaussian",
            "manifold": self.manifold.spec(),
            "scale": self.scale,
            "base": self.base_raw.tolist(),
        }


class ProductPrior(Prior):
    """Independent priors per component of a `Product` (e.g. Gaussian x wrapped x Gaussian).

    Example:
        >>> pose = ProductPrior([GaussianPrior(Euclidean(3)), WrappedGaussianPrior(Sphere(3), 0.5)])
        >>> pose.sample(2).shape
        torch.Size([2, 7])
    """

    def __init__(self, priors: Sequence[Prior]) -> None:
        self.priors = list(priors)
        self.manifold = Product([p.manifold for p in self.priors])
        self.noise_dims = [p.noise_dim for p in self.priors]
        self.noise_dim = sum(self.noise_dims)

    def from_noise(self, eps: torch.Tensor) -> torch.Tensor:
        parts = torch.split(eps, self.noise_dims, dim=-1)
        return torch.cat([p.from_noise(e) for p, e in zip(self.priors, parts, strict=True)], dim=-1)

    def mode(self, *shape, dtype=None, device=None) -> torch.Tensor:
        return torch.cat([p.mode(*shape, dtype=dtype, device=device) for p in self.priors], dim=-1)

    def spec(self) -> dict[str, Any]:
        return {"type": "product", "priors": [p.spec() for p in self.priors]}


class HorizonPrior(Prior):
    """A per-step prior over an action chunk of ``steps`` actions (a `Horizon` manifold).

    With ``repeat=True`` (the paper's construction, Sec. III-A) one base action ``a_b ~ b`` is
    drawn and repeated, ``a_0 = [a_b, ..., a_b]``, so every action of the chunk flows from the
    same start; the noise is then one step's worth, ``(..., step_noise_dim)``. With
    ``repeat=False`` each step is drawn independently.

    Example:
        >>> p = HorizonPrior(UniformSpherePrior(Sphere(2)), steps=16)
        >>> x = p.sample(5)                     # (5, 48)
        >>> bool((x.view(5, 16, 3) == x.view(5, 16, 3)[:, :1]).all())
        True
    """

    def __init__(self, prior: Prior, steps: int, repeat: bool = True) -> None:
        self.prior, self.steps, self.repeat = prior, int(steps), bool(repeat)
        self.manifold = Horizon(prior.manifold, self.steps)
        self.noise_dim = prior.noise_dim if self.repeat else prior.noise_dim * self.steps

    def from_noise(self, eps: torch.Tensor) -> torch.Tensor:
        if self.repeat:
            step = self.prior.from_noise(eps)  # (..., d)
            return (
                step.unsqueeze(-2).expand(*step.shape[:-1], self.steps, step.shape[-1]).flatten(-2)
            )
        steps = self.prior.from_noise(eps.unflatten(-1, (self.steps, self.prior.noise_dim)))
        return steps.flatten(-2)

    def mode(self, *shape, dtype=None, device=None) -> torch.Tensor:
        return self.prior.mode(*shape, self.steps, dtype=dtype, device=device).flatten(-2)

    def spec(self) -> dict[str, Any]:
        return {
            "type": "horizon",
            "prior": self.prior.spec(),
            "steps": self.steps,
            "repeat": self.repeat,
        }


def make_prior(
    manifold: Manifold | str, sphere: str = "uniform", scale: float = 1.0, std: float = 1.0
) -> Prior:
    """Default prior per component: Gaussian on R^n parts, uniform or wrapped Gaussian on spheres.

    Args:
        manifold: a per-step manifold (or a string such as ``"R3 x S3 x R1"``); a `Horizon` is
            handled by building the per-step prior and repeating it.
        sphere: ``"uniform"`` or ``"wrapped"`` for sphere components.
        scale: tangent standard deviation of wrapped Gaussians.
        std: standard deviation of Euclidean Gaussians.

    Example:
        >>> make_prior("R3 x S3 x R1", sphere="wrapped", scale=0.5).manifold.dim
        8
    """
    manifold = from_spec(manifold)
    if isinstance(manifold, Horizon):
        return HorizonPrior(make_prior(manifold.step, sphere, scale, std), manifold.steps)
    if isinstance(manifold, Product):
        return ProductPrior([make_prior(c, sphere, scale, std) for c in manifold.components])
    if isinstance(manifold, Euclidean):
        return GaussianPrior(manifold, std=std)
    if isinstance(manifold, Sphere):
        if sphere == "uniform":
            return UniformSpherePrior(manifold)
        if sphere == "wrapped":
            return WrappedGaussianPrior(manifold, scale=scale)
        raise ValueError(f"make_prior: sphere prior must be 'uniform' or 'wrapped', got {sphere!r}")
    raise TypeError(f"make_prior: no default prior for {manifold!r}")


def prior_from_spec(spec: dict[str, Any]) -> Prior:
    """Rebuild a prior from `Prior.spec()` output."""
    kind = spec.get("type")
    if kind == "gaussian":
        return GaussianPrior(from_spec(spec["manifold"]), spec["std"], spec.get("mean", 0.0))
    if kind == "uniform_sphere":
        return UniformSpherePrior(from_spec(spec["manifold"]))
    if kind == "wrapped_gaussian":
        return WrappedGaussianPrior(from_spec(spec["manifold"]), spec["scale"], spec.get("base"))
    if kind == "product":
        return ProductPrior([prior_from_spec(p) for p in spec["priors"]])
    if kind == "horizon":
        return HorizonPrior(prior_from_spec(spec["prior"]), spec["steps"], spec.get("repeat", True))
    raise ValueError(f"prior_from_spec: unknown prior type {kind!r} in {spec!r}")
