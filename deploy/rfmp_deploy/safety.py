"""Safety pieces of the controller: events, the safe (hold) action, and the action guard.

Event kinds the controller records:

====================  ===============================================================
``rejected``          the observation was not usable (missing key/camera, wrong shape or
                      dtype, NaN/inf); the controller held and dropped its queued plan
``clamped``           an executed action had Euclidean coordinates outside
                      ``[action_low, action_high]`` (clipped) or a sphere component off
                      unit norm (renormalised)
``invalid_action``    the policy produced a non-finite action or a zero-norm sphere
                      component; the controller held and dropped its queued plan
``inference_error``   onnxruntime raised; the controller held
``overrun``           synchronous mode: inference took longer than the control period
``underrun``          asynchronous mode: the action queue was empty, the controller held
====================  ===============================================================
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from rfmp_deploy.spaces import ActionSpace

__all__ = ["Event", "EVENT_KINDS", "resolve_safe_action", "guard_action"]

logger = logging.getLogger("rfmp_deploy")

EVENT_KINDS = (
    "rejected",
    "clamped",
    "invalid_action",
    "inference_error",
    "overrun",
    "underrun",
    "resync",
    "model_error",
)


@dataclass(frozen=True)
class Event:
    """Something the operator should know about, recorded by the controller.

    Attributes:
        time: the controller clock's reading (seconds; ``time.monotonic`` by default).
        step: index of the ``Controller.step`` call (0 = first step after construction).
        kind: one of `EVENT_KINDS`.
        message: what happened, in words.

    Example:
        >>> Event(12.5, 3, "underrun", "action queue empty: holding")
        Event(time=12.5, step=3, kind='underrun', message='action queue empty: holding')
    """

    time: float
    step: int
    kind: str
    message: str


def resolve_safe_action(space: ActionSpace, safe_action: np.ndarray | None) -> np.ndarray:
    """The action the controller holds before it has executed anything.

    Args:
        space: the action manifold with its limits.
        safe_action: an explicit ``(D,)`` action, or ``None`` to derive one from the metadata
            (`ActionSpace.default_action`: midpoint of ``[low, high]`` for Euclidean
            coordinates, the pole ``(0, ..., 0, 1)`` — the identity quaternion — for spheres).

    Returns:
        ``(D,)`` float32, inside the limits and on the manifold.

    Raises:
        ValueError: when ``safe_action`` has the wrong shape, is not finite or lies outside the
            limits, or when it is ``None`` and the limits are unbounded.
    """
    if safe_action is None:
        action = space.default_action()
        if action is None:
            raise ValueError(
                "the model's action limits are unbounded, so no default safe action exists: "
                "pass Controller(..., safe_action=...) with a (D,) action the robot may hold"
            )
        return action
    action = np.asarray(safe_action, dtype=np.float64)
    if action.shape != (space.dim,):
        raise ValueError(f"safe_action has shape {action.shape}, expected ({space.dim},) for "
                         f"the action space {space}")
    if not np.all(np.isfinite(action)):
        raise ValueError(f"safe_action has non-finite coordinate(s) "
                         f"{np.flatnonzero(~np.isfinite(action)).tolist()}")
    mask = space.euclidean
    outside = np.flatnonzero(mask & ((action < space.low) | (action > space.high))).tolist()
    if outside:
        ranges = ", ".join(f"{i} ({action[i]:.4g} not in [{space.low[i]:.4g}, "
                           f"{space.high[i]:.4g}])" for i in outside)
        raise ValueError(f"safe_action is outside the action limits: coordinate(s) {ranges}")
    for seg in space.spheres:  # the robot holds it as given: it must lie on the manifold
        norm = float(np.linalg.norm(action[seg.slice]))
        if abs(norm - 1.0) > space.norm_tolerance:
            raise ValueError(f"safe_action is off the manifold: its {seg} component at "
                             f"{seg.start}:{seg.stop} has norm {norm:.4g}, not 1")
    return space.project(action).action


def guard_action(space: ActionSpace, action: np.ndarray) -> tuple[np.ndarray | None, str | None]:
    """Make a policy action safe to send.

    Returns:
        ``(action, message)``: the projected action and ``None``, or the projected action and a
        description of what was clipped/renormalised, or ``(None, reason)`` when the action
        cannot be made safe (non-finite, zero-norm sphere component).
    """
    try:
        projection = space.project(action)
    except ValueError as e:
        return None, str(e)
    if projection.changed:
        return projection.action, projection.describe(space.low, space.high)
    return projection.action, None
