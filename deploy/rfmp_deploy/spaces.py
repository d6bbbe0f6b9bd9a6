"""The action manifold of one action step, read from the model's ``action_manifold`` metadata.

A step is a concatenation of Euclidean blocks (positions, gripper width, ...) and spheres
(S^n in R^(n+1); S^3 holds a unit quaternion in xyzw order). `ActionSpace` knows where each
block sits in the action vector, keeps actions inside the limits the policy was trained on,
proposes a default safe action and measures errors between actions — all in numpy.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = ["ActionSpace", "Segment", "Projection"]


@dataclass(frozen=True)
class Segment:
    """One leaf of the action manifold: coordinates ``start:stop`` of an action step.

    Attributes:
        kind: ``"euclidean"`` or ``"sphere"``.
        start: first coordinate.
        stop: one past the last coordinate.
        n: intrinsic dimension (``stop - start`` for Euclidean, ``stop - start - 1`` for S^n).

    Example:
        >>> ActionSpace({"type": "sphere", "n": 3}, [-1] * 4, [1] * 4).segments
        (Segment(kind='sphere', start=0, stop=4, n=3),)
    """

    kind: str
    start: int
    stop: int
    n: int

    @property
    def slice(self) -> slice:
        return slice(self.start, self.stop)

    def __str__(self) -> str:
        return f"R{self.n}" if self.kind == "euclidean" else f"S{self.n}"


@dataclass(frozen=True)
class Projection:
    """What `ActionSpace.project` did to an action.

    Attributes:
        action: the projected action, float32.
        clipped: indices of Euclidean coordinates that were outside ``[low, high]``.
        renormalised: ``(segment, norm before)`` for sphere components whose norm differed from
            1 by more than the tolerance.

    Example:
        >>> space = ActionSpace({"type": "sphere", "n": 1}, [-1, -1], [1, 1])
        >>> p = space.project(np.array([3.0, 4.0]))
        >>> p.action, p.changed, p.describe(space.low, space.high)
        (array([0.6, 0.8], dtype=float32), True, 'renormalised S1 at 0:2 (norm was 5)')
    """

    action: np.ndarray
    clipped: tuple[int, ...]
    renormalised: tuple[tuple[Segment, float], ...]

    @property
    def changed(self) -> bool:
        return bool(self.clipped or self.renormalised)

    def describe(self, low: np.ndarray, high: np.ndarray) -> str:
        parts = []
        if self.clipped:
            ranges = ", ".join(f"{i} to [{low[i]:.4g}, {high[i]:.4g}]" for i in self.clipped)
            parts.append(f"clipped coordinate(s) {ranges}")
        for seg, norm in self.renormalised:
            parts.append(f"renormalised {seg} at {seg.start}:{seg.stop} (norm was {norm:.4g})")
        return "; ".join(parts)


def _segments(spec: Any, start: int = 0) -> list[Segment]:
    if not isinstance(spec, dict) or "type" not in spec:
        raise ValueError(f"expected an object with a 'type', got {spec!r}")
    kind = spec["type"]
    if kind == "euclidean":
        dim = spec.get("dim")
        if not isinstance(dim, int) or isinstance(dim, bool) or dim < 1:
            raise ValueError(f"euclidean 'dim' must be an integer >= 1, got {dim!r}")
        return [Segment("euclidean", start, start + dim, dim)]
    if kind == "sphere":
        n = spec.get("n")
        if not isinstance(n, int) or isinstance(n, bool) or n < 1:
            raise ValueError(f"sphere 'n' must be an integer >= 1, got {n!r}")
        return [Segment("sphere", start, start + n + 1, n)]
    if kind == "product":
        components = spec.get("components")
        if not isinstance(components, list) or not components:
            raise ValueError(f"product 'components' must be a non-empty list, got {components!r}")
        out: list[Segment] = []
        for component in components:
            out.extend(_segments(component, start))
            start = out[-1].stop
        return out
    raise ValueError(f"unknown manifold type {kind!r} (expected euclidean, sphere or product)")


class ActionSpace:
    """Layout, limits and geometry of one action step.

    Args:
        spec: the ``action_manifold`` JSON object, e.g.
            ``{"type": "product", "components": [{"type": "euclidean", "dim": 3},
            {"type": "sphere", "n": 3}]}``.
        low: per-coordinate lower limits (length ``dim``); ``None`` entries mean unbounded.
        high: per-coordinate upper limits.
        norm_tolerance: a sphere component whose norm differs from 1 by more than this is
            reported as renormalised by `project` (it is always renormalised).

    Raises:
        ValueError: on a malformed spec or limits of the wrong length or with ``low > high``.

    Example:
        >>> spec = {"type": "product", "components": [
        ...     {"type": "euclidean", "dim": 2}, {"type": "sphere", "n": 3}]}
        >>> space = ActionSpace(spec, low=[-1, 0, -1, -1, -1, -1], high=[1, 2, 1, 1, 1, 1])
        >>> str(space), space.dim
        ('R2 x S3', 6)
        >>> space.default_action()
        array([0., 1., 0., 0., 0., 1.], dtype=float32)
        >>> p = space.project(np.array([3.0, 1.0, 0.0, 0.0, 0.0, 2.0]))
        >>> p.action, p.clipped
        (array([1., 1., 0., 0., 0., 1.], dtype=float32), (0,))
    """

    def __init__(
        self,
        spec: dict[str, Any],
        low: Sequence[float | None],
        high: Sequence[float | None],
        norm_tolerance: float = 1e-3,
    ) -> None:
        self.spec = spec
        self.segments = tuple(_segments(spec))
        self.dim = self.segments[-1].stop
        self.low = self._limits(low, -math.inf, "action_low")
        self.high = self._limits(high, math.inf, "action_high")
        bad = np.flatnonzero(self.low > self.high)
        if bad.size:
            raise ValueError(f"action_low > action_high at coordinate(s) {bad.tolist()}")
        self.euclidean = np.zeros(self.dim, dtype=bool)
        for seg in self.segments:
            if seg.kind == "euclidean":
                self.euclidean[seg.slice] = True
        self.spheres = tuple(seg for seg in self.segments if seg.kind == "sphere")
        self.norm_tolerance = float(norm_tolerance)

    def _limits(self, values: Sequence[float | None], fill: float, name: str) -> np.ndarray:
        if not isinstance(values, Sequence) or isinstance(values, str):
            raise ValueError(f"{name} must be a list of numbers, got {values!r}")
        if len(values) != self.dim:
            raise ValueError(f"{name} has {len(values)} entries, the action manifold {self} "
                             f"has {self.dim} coordinates")
        out = np.empty(self.dim, dtype=np.float64)
        for i, v in enumerate(values):
            if v is None:
                out[i] = fill
            elif isinstance(v, int | float) and not isinstance(v, bool) and not math.isnan(v):
                out[i] = float(v)
            else:
                raise ValueError(f"{name}[{i}] must be a number or null, got {v!r}")
        return out

    def __str__(self) -> str:
        return " x ".join(str(seg) for seg in self.segments)

    def __repr__(self) -> str:
        return f"ActionSpace({self})"

    def default_action(self) -> np.ndarray | None:
        """The metadata's safe action, or ``None`` when the limits cannot give one.

        Euclidean coordinates take the midpoint of ``[low, high]``; each sphere takes its pole
        ``(0, ..., 0, 1)`` (the identity quaternion for S^3 in xyzw order). ``None`` when a
        Euclidean coordinate is unbounded on either side.
        """
        with np.errstate(invalid="ignore"):  # -inf + inf
            mid = 0.5 * (self.low + self.high)
        if not np.all(np.isfinite(mid[self.euclidean])):
            return None
        action = np.where(self.euclidean, mid, 0.0)
        for seg in self.spheres:
            action[seg.stop - 1] = 1.0
        return action.astype(np.float32)

    def project(self, action: np.ndarray) -> Projection:
        """Clip Euclidean coordinates to the limits and renormalise every sphere component.

        Args:
            action: shape ``(dim,)``, finite.

        Raises:
            ValueError: when the shape is wrong, a coordinate is not finite or a sphere
                component has (near) zero norm, so no direction can be recovered.
        """
        x = np.asarray(action, dtype=np.float64)
        if x.shape != (self.dim,):
            raise ValueError(f"action has shape {x.shape}, expected ({self.dim},)")
        if not np.all(np.isfinite(x)):
            bad = np.flatnonzero(~np.isfinite(x)).tolist()
            raise ValueError(f"action has non-finite coordinate(s) {bad}")
        y = x.copy()
        mask = self.euclidean
        y[mask] = np.clip(x[mask], self.low[mask], self.high[mask])
        clipped = tuple(int(i) for i in np.flatnonzero(y != x))
        renormalised = []
        for seg in self.spheres:
            norm = float(np.linalg.norm(x[seg.slice]))
            if norm < 1e-6:
                raise ValueError(f"sphere component {seg} at {seg.start}:{seg.stop} has norm "
                                 f"{norm:.3g}: no direction to renormalise")
            y[seg.slice] = x[seg.slice] / norm
            if abs(norm - 1.0) > self.norm_tolerance:
                renormalised.append((seg, norm))
        return Projection(y.astype(np.float32), clipped, tuple(renormalised))

    def errors(self, a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Euclidean and geodesic errors between actions ``a`` and ``b``, shape ``(..., dim)``.

        Returns:
            ``(euclidean, angles)``: the Euclidean norm of the difference over all Euclidean
            coordinates, shape ``(...)``, and the great-circle angle in radians for each sphere
            component, shape ``(..., n_spheres)`` (both inputs are normalised first). For S^3 this
            is the angle between quaternions as points on S^3; the rotation angle between the
            orientations they encode is ``2 * min(angle, pi - angle)``.
        """
        a = np.asarray(a, dtype=np.float64)
        b = np.asarray(b, dtype=np.float64)
        euclidean = np.linalg.norm((a - b)[..., self.euclidean], axis=-1)
        angles = []
        for seg in self.spheres:
            x, y = a[..., seg.slice], b[..., seg.slice]
            x = x / np.maximum(np.linalg.norm(x, axis=-1, keepdims=True), 1e-12)
            y = y / np.maximum(np.linalg.norm(y, axis=-1, keepdims=True), 1e-12)
            c = np.clip(np.sum(x * y, axis=-1, keepdims=True), -1.0, 1.0)
            angles.append(np.arctan2(np.linalg.norm(y - c * x, axis=-1), c[..., 0]))
        shape = euclidean.shape + (len(angles),)
        return euclidean, (np.stack(angles, axis=-1) if angles else np.zeros(shape))
