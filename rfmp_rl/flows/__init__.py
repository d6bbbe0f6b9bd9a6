"""Flow-matching building blocks: priors p_0, conditional paths and time sampling."""

from rfmp_rl.flows.paths import (
    GeodesicPath,
    PathSample,
    StablePath,
    sample_time,
    sample_time_via_tau,
)
from rfmp_rl.flows.priors import (
    GaussianPrior,
    HorizonPrior,
    Prior,
    ProductPrior,
    UniformSpherePrior,
    WrappedGaussianPrior,
    make_prior,
    prior_from_spec,
)

__all__ = [
    "GeodesicPath",
    "StablePath",
    "PathSample",
    "sample_time",
    "sample_time_via_tau",
    "Prior",
    "GaussianPrior",
    "UniformSpherePrior",
    "WrappedGaussianPrior",
    "ProductPrior",
    "HorizonPrior",
    "make_prior",
    "prior_from_spec",
]
