"""Riemannian manifolds as plain tensor maps: R^n, S^n, products and action horizons."""

from __future__ import annotations

import re
from typing import Any

from rfmp_rl.manifolds.base import Manifold, eps_for, safe_norm
from rfmp_rl.manifolds.euclidean import Euclidean
from rfmp_rl.manifolds.product import Horizon, Product, leaf_slices
from rfmp_rl.manifolds.quaternion import canonicalize_quaternion, hemisphere_continuous
from rfmp_rl.manifolds.sphere import Sphere
from rfmp_rl.manifolds.stereographic import plane_to_sphere, sphere_to_plane

__all__ = [
    "Manifold",
    "Euclidean",
    "Sphere",
    "Product",
    "Horizon",
    "leaf_slices",
    "from_spec",
    "parse_manifold",
    "canonicalize_quaternion",
    "hemisphere_continuous",
    "eps_for",
    "safe_norm",
    "plane_to_sphere",
    "sphere_to_plane",
]


def from_spec(spec: dict[str, Any] | str | Manifold) -> Manifold:
    """Rebuild a manifold from `Manifold.spec()` output (or parse a string, see `parse_manifold`).

    Example:
        >>> from_spec({"type": "sphere", "n": 2})
        Sphere(2)
    """
    if isinstance(spec, Manifold):
        return spec
    if isinstance(spec, str):
        return parse_manifold(spec)
    if not isinstance(spec, dict) or "type" not in spec:
        raise ValueError(f"from_spec: expected a dict with a 'type' field, got {spec!r}")
    kind = spec["type"]
    if kind == "euclidean":
        return Euclidean(spec["dim"])
    if kind == "sphere":
        return Sphere(spec["n"])
    if kind == "product":
        return Product([from_spec(c) for c in spec["components"]])
    if kind == "horizon":
        return Horizon(from_spec(spec["step"]), spec["steps"])
    raise ValueError(
        f"from_spec: unknown manifold type {kind!r} (expected euclidean, sphere, product, horizon)"
    )


_FACTOR = re.compile(r"^(R|S)(\d+)$")


def parse_manifold(text: str) -> Manifold:
    """Parse a product written as in the paper, e.g. ``"R3 x S3 x R1"`` or ``"S2"``.

    ``Rn`` is `Euclidean(n)`, ``Sn`` is `Sphere(n)` (n + 1 coordinates). A single factor returns
    that manifold itself, not a one-element product.

    Example:
        >>> parse_manifold("R3 x S3 x R1").dim
        8
    """
    factors = [f.strip() for f in re.split(r"[x×*]", text) if f.strip()]
    if not factors:
        raise ValueError(f"parse_manifold: empty manifold string {text!r}")
    out: list[Manifold] = []
    for f in factors:
        m = _FACTOR.match(f.replace("^", ""))
        if m is None:
            raise ValueError(
                f"parse_manifold: cannot read factor {f!r} in {text!r}; use Rn or Sn ('R3 x S3')"
            )
        kind, n = m.group(1), int(m.group(2))
        out.append(Euclidean(n) if kind == "R" else Sphere(n))
    return out[0] if len(out) == 1 else Product(out)
