"""Tests for `rfmp_rl.flows.priors`: base distributions p_0 as maps of standard-normal noise."""

from __future__ import annotations

import json
import math
from collections.abc import Callable

import pytest
import torch
from torch.testing import assert_close

from rfmp_rl.flows import (
    GaussianPrior,
    HorizonPrior,
    Prior,
    ProductPrior,
    UniformSpherePrior,
    WrappedGaussianPrior,
    make_prior,
    prior_from_spec,
)
from rfmp_rl.manifolds import Euclidean, Horizon, Product, Sphere, parse_manifold

F64 = torch.float64
# Largest allowed distance of a sample from the manifold, per dtype.
ON_MANIFOLD = {torch.float32: 1e-6, torch.float64: 1e-12}
TOL = {
    torch.float32: {"rtol": 1e-6, "atol": 1e-6},
    torch.float64: {"rtol": 1e-12, "atol": 1e-12},
}

PRIORS: dict[str, Callable[[], Prior]] = {
    "gaussian-R2": lambda: GaussianPrior(Euclidean(2), std=0.5, mean=1.0),
    "uniform-S2": lambda: UniformSpherePrior(Sphere(2)),
    "uniform-S3": lambda: UniformSpherePrior(Sphere(3)),
    "wrapped-S2": lambda: WrappedGaussianPrior(Sphere(2), scale=0.7),
    "wrapped-S3-base": lambda: WrappedGaussianPrior(
        Sphere(3), scale=0.3, base=[0.0, 0.6, 0.0, 0.8]
    ),
    "wrapped-R3xS3xR1": lambda: WrappedGaussianPrior(parse_manifold("R3 x S3 x R1"), scale=0.5),
    "product": lambda: ProductPrior(
        [
            GaussianPrior(Euclidean(3)),
            WrappedGaussianPrior(Sphere(3), 0.5),
            GaussianPrior(Euclidean(1)),
        ]
    ),
    "horizon-repeat": lambda: HorizonPrior(make_prior("R3 x S3 x R1"), steps=4, repeat=True),
    "horizon-independent": lambda: HorizonPrior(
        UniformSpherePrior(Sphere(2)), steps=4, repeat=False
    ),
    "make-R2": lambda: make_prior("R2"),
    "make-S2-uniform": lambda: make_prior("S2", sphere="uniform"),
    "make-S2-wrapped": lambda: make_prior("S2", sphere="wrapped", scale=0.2),
    "make-R3xS3xR1": lambda: make_prior("R3 x S3 x R1"),
    "make-R3xS3xR1-wrapped": lambda: make_prior("R3 x S3 x R1", sphere="wrapped", scale=0.5),
    "make-horizon": lambda: make_prior(Horizon(parse_manifold("R3 x S3 x R1"), steps=3)),
}


def _chi_mean(n: int) -> float:
    """E|z| for z ~ N(0, I_n)."""
    return math.sqrt(2.0) * math.exp(math.lgamma((n + 1) / 2) - math.lgamma(n / 2))


# ----- samples and modes lie on the manifold ---------------------------------------------------
@pytest.mark.parametrize("dtype", [torch.float32, F64])
@pytest.mark.parametrize("name", list(PRIORS))
def test_samples_lie_on_the_manifold(name: str, dtype: torch.dtype) -> None:
    prior = PRIORS[name]()
    x = prior.sample(7, 5, generator=torch.Generator().manual_seed(0), dtype=dtype)
    assert x.shape == (7, 5, prior.manifold.dim)
    assert x.dtype == dtype
    assert torch.isfinite(x).all()
    assert float(prior.manifold.check_point(x).max()) <= ON_MANIFOLD[dtype]


@pytest.mark.parametrize("name", list(PRIORS))
def test_mode_lies_on_the_manifold(name: str) -> None:
    prior = PRIORS[name]()
    mode = prior.mode(2, 3)
    assert mode.shape == (2, 3, prior.manifold.dim)
    assert float(prior.manifold.check_point(mode).max()) <= ON_MANIFOLD[mode.dtype]
    # the mode is one fixed point, repeated over the batch
    assert torch.equal(mode, mode[:1, :1].expand_as(mode))


def test_make_prior_builds_the_documented_defaults() -> None:
    assert isinstance(make_prior("R2"), GaussianPrior)
    assert isinstance(make_prior("S2"), UniformSpherePrior)
    wrapped = make_prior("S2", sphere="wrapped", scale=0.2)
    assert isinstance(wrapped, WrappedGaussianPrior)
    assert wrapped.scale == 0.2
    pose = make_prior("R3 x S3 x R1")
    assert isinstance(pose, ProductPrior)
    assert [type(p) for p in pose.priors] == [GaussianPrior, UniformSpherePrior, GaussianPrior]
    assert pose.manifold == parse_manifold("R3 x S3 x R1")
    chunk = make_prior(Horizon(Sphere(2), steps=5))
    assert isinstance(chunk, HorizonPrior)
    assert chunk.repeat
    assert chunk.manifold == Horizon(Sphere(2), steps=5)


def test_gaussian_and_uniform_modes_are_the_documented_points() -> None:
    assert_close(GaussianPrior(Euclidean(2), mean=1.5).mode(), torch.full((2,), 1.5))
    assert_close(UniformSpherePrior(Sphere(3)).mode(), torch.tensor([0.0, 0.0, 0.0, 1.0]))
    base = torch.tensor([0.0, 0.6, 0.8])
    assert_close(WrappedGaussianPrior(Sphere(2), base=base).mode(4), base.expand(4, 3))


# ----- distributions ---------------------------------------------------------------------------
@pytest.mark.parametrize("n", [2, 3])
def test_uniform_sphere_prior_moments(n: int) -> None:
    d, samples = n + 1, 200_000
    x = UniformSpherePrior(Sphere(n)).sample(
        samples, generator=torch.Generator().manual_seed(1), dtype=F64
    )
    # Uniform on S^n in R^d: E[x] = 0, E[x x^T] = I / d.
    # Standard errors: Var[x_i] = 1/d; Var[x_i^2] = 3/(d(d+2)) - 1/d^2;
    # Var[x_i x_j] = E[x_i^2 x_j^2] = 1/(d(d+2)) for i != j. Allow 5 standard errors.
    se_mean = math.sqrt(1 / d / samples)
    se_diag = math.sqrt(3 / (d * (d + 2)) - 1 / d**2) / math.sqrt(samples)
    se_off = math.sqrt(1 / (d * (d + 2))) / math.sqrt(samples)
    second = x.T @ x / samples
    eye = torch.eye(d, dtype=F64)

    assert_close(x.mean(dim=0), torch.zeros(d, dtype=F64), rtol=0.0, atol=5 * se_mean)
    assert_close(
        torch.diagonal(second), torch.full((d,), 1 / d, dtype=F64), rtol=0.0, atol=5 * se_diag
    )
    assert_close(second * (1 - eye), torch.zeros(d, d, dtype=F64), rtol=0.0, atol=5 * se_off)


@pytest.mark.parametrize("n", [2, 3])
def test_wrapped_gaussian_concentrates_at_its_base(n: int) -> None:
    sphere, samples = Sphere(n), 20_000
    base = sphere.projx(torch.arange(1.0, n + 2.0, dtype=F64))
    mean_dist, rms_dist = [], []
    for scale in (1.0, 0.3, 0.1, 0.03):
        prior = WrappedGaussianPrior(sphere, scale=scale, base=base)
        x = prior.sample(samples, generator=torch.Generator().manual_seed(2), dtype=F64)
        dist = sphere.dist(prior.base.to(F64).expand_as(x), x)
        mean_dist.append(float(dist.mean()))
        rms_dist.append(float(dist.pow(2).mean().sqrt()))
    assert mean_dist == sorted(mean_dist, reverse=True)
    assert len(set(mean_dist)) == 4
    # For small scales the distance is scale * |z| with z ~ N(0, I_n) in the tangent space:
    # E[dist] = scale * E[chi_n], E[dist^2] = scale^2 n (RMS = scale sqrt(n)).
    # Relative standard errors: std(chi_n)/E[chi_n]/sqrt(N) < 0.006 and sqrt(2/n/N)/2 < 0.004.
    for i, scale in ((2, 0.1), (3, 0.03)):
        assert mean_dist[i] == pytest.approx(scale * _chi_mean(n), rel=0.03)
        assert rms_dist[i] == pytest.approx(scale * math.sqrt(n), rel=0.02)


def test_wrapped_gaussian_on_euclidean_space_is_a_gaussian() -> None:
    prior = WrappedGaussianPrior(Euclidean(2), scale=0.5, base=[1.0, -2.0])
    eps = torch.randn(4, 2, generator=torch.Generator().manual_seed(3))
    assert_close(prior.from_noise(eps), torch.tensor([1.0, -2.0]) + 0.5 * eps)


# ----- action-chunk priors ---------------------------------------------------------------------
def test_horizon_prior_repeat_uses_one_base_sample_for_all_steps() -> None:
    step = make_prior("R3 x S3 x R1")
    prior = HorizonPrior(step, steps=16, repeat=True)
    assert prior.noise_dim == step.noise_dim
    eps = prior.noise(5, generator=torch.Generator().manual_seed(4), dtype=F64)
    chunk = prior.manifold.unflatten(prior.from_noise(eps))  # (5, 16, 8)
    assert chunk.shape == (5, 16, 8)
    assert torch.equal(chunk, chunk[:, :1].expand_as(chunk))
    assert torch.equal(chunk[:, 0], step.from_noise(eps))


def test_horizon_prior_without_repeat_draws_each_step() -> None:
    step = make_prior("R3 x S3 x R1")
    prior = HorizonPrior(step, steps=16, repeat=False)
    assert prior.noise_dim == 16 * step.noise_dim
    eps = prior.noise(5, generator=torch.Generator().manual_seed(5), dtype=F64)
    chunk = prior.manifold.unflatten(prior.from_noise(eps))  # (5, 16, 8)
    assert chunk.shape == (5, 16, 8)
    # no two steps of a chunk coincide
    gaps = (chunk.unsqueeze(1) - chunk.unsqueeze(2)).norm(dim=-1)  # (5, 16, 16)
    gaps = gaps + torch.eye(16, dtype=F64)
    assert float(gaps.min()) > 0
    # each step is the per-step prior applied to its own slice of the noise
    assert torch.equal(chunk, step.from_noise(eps.unflatten(-1, (16, step.noise_dim))))


def test_horizon_prior_with_tiled_noise_equals_the_repeated_prior() -> None:
    step = UniformSpherePrior(Sphere(2))
    eps = step.noise(3, generator=torch.Generator().manual_seed(6))
    repeated = HorizonPrior(step, steps=4, repeat=True).from_noise(eps)
    independent = HorizonPrior(step, steps=4, repeat=False).from_noise(eps.repeat(1, 4))
    assert torch.equal(repeated, independent)


# ----- reproducibility -------------------------------------------------------------------------
@pytest.mark.parametrize("name", list(PRIORS))
def test_prior_from_spec_reproduces_samples(name: str) -> None:
    prior = PRIORS[name]()
    spec = json.loads(json.dumps(prior.spec()))  # the spec is JSON-serialisable
    rebuilt = prior_from_spec(spec)
    assert rebuilt.spec() == prior.spec()
    assert rebuilt.noise_dim == prior.noise_dim
    eps = prior.noise(32, generator=torch.Generator().manual_seed(7))
    assert torch.equal(rebuilt.from_noise(eps), prior.from_noise(eps))


def test_prior_from_spec_reproduces_a_wrapped_gaussian_with_unnormalised_base() -> None:
    # The constructor normalises the base; rebuilding from the (already normalised) stored base
    # must give the very same base, hence identical samples.
    prior = WrappedGaussianPrior(Sphere(3), scale=0.5, base=[1.0, 2.0, 3.0, 4.0])
    rebuilt = prior_from_spec(prior.spec())
    assert torch.equal(rebuilt.base, prior.base)
    eps = prior.noise(32, generator=torch.Generator().manual_seed(8))
    assert torch.equal(rebuilt.from_noise(eps), prior.from_noise(eps))


def test_wrapped_gaussian_keeps_a_float64_base_on_the_manifold() -> None:
    base = Sphere(3).projx(torch.tensor([1.0, 2.0, 3.0, 4.0], dtype=F64))
    prior = WrappedGaussianPrior(Sphere(3), scale=0.5, base=base)
    mode = prior.mode(dtype=F64)
    assert float(Sphere(3).check_point(mode)) <= ON_MANIFOLD[F64]
    assert_close(mode, base, **TOL[F64])


@pytest.mark.parametrize("dtype", [torch.float32, F64])
@pytest.mark.parametrize("n", [1, 2, 3])
def test_uniform_sphere_prior_maps_zero_noise_to_a_point(n: int, dtype: torch.dtype) -> None:
    x = UniformSpherePrior(Sphere(n)).from_noise(torch.zeros(4, n + 1, dtype=dtype))
    assert torch.isfinite(x).all()
    assert_close(x.norm(dim=-1), torch.ones(4, dtype=dtype), **TOL[dtype])


# ----- argument checking -----------------------------------------------------------------------
@pytest.mark.parametrize(
    ("build", "error"),
    [
        (lambda: GaussianPrior(Sphere(2)), TypeError),
        (lambda: GaussianPrior(Euclidean(2), std=0.0), ValueError),
        (lambda: GaussianPrior(Euclidean(2), std=-1.0), ValueError),
        (lambda: UniformSpherePrior(Euclidean(3)), TypeError),
        (lambda: WrappedGaussianPrior(Sphere(2), scale=0.0), ValueError),
        (lambda: WrappedGaussianPrior(Sphere(2), base=[0.0, 1.0]), ValueError),
        (lambda: HorizonPrior(UniformSpherePrior(Sphere(2)), steps=0), ValueError),
        (lambda: ProductPrior([]), ValueError),
        (lambda: make_prior("S2", sphere="gaussian"), ValueError),
        (lambda: make_prior("Q3"), ValueError),
        (lambda: prior_from_spec({"type": "laplace"}), ValueError),
    ],
)
def test_bad_arguments_raise(build: Callable[[], Prior], error: type[Exception]) -> None:
    with pytest.raises(error):
        build()


def test_product_prior_manifold_is_the_product_of_its_parts() -> None:
    prior = ProductPrior([GaussianPrior(Euclidean(3)), UniformSpherePrior(Sphere(3))])
    assert prior.manifold == Product([Euclidean(3), Sphere(3)])
    assert prior.noise_dim == 7
