"""Checking and preprocessing one robot observation (sensor readings and camera frames).

The robot hands the controller a dict: each low-dimensional field named in the model's
``observation_keys`` maps to an array of its ``dim`` numbers, each camera name maps to an
``H x W x 3`` uint8 RGB frame of any size. `ObservationProcessor` validates all of it (missing
keys, shapes, dtypes, NaN/inf) and produces a `Frame`: the concatenated ``observation`` vector
and the camera images resized with OpenCV's ``INTER_AREA`` to the training image size, in CHW
order — exactly what the exported graph expects (it centre-crops by itself).

Quaternion signs: when the metadata lists ``observation_quaternions``, the processor makes those
columns of the ``observation`` vector canonical frame by frame, as the training data held them:
each takes the sign closest to the previous frame's, the first frame after `reset` the
hemisphere of its reference (`canonical_quaternion_signs`, the numpy twin of
``rfmp_rl.data.quaternions.canonical_quaternion_signs``, which documents why). Robots report
either sign of the same rotation (``q`` and ``-q``), so the processor keeps one quaternion of
state per field; `Controller.reset` resets it. Metadata without the key: the observation is fed
as given.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from types import ModuleType
from typing import Any

import numpy as np

from rfmp_deploy.metadata import PolicyMeta

__all__ = ["Frame", "ObservationError", "ObservationProcessor", "canonical_quaternion_signs",
           "stack_window"]


class ObservationError(ValueError):
    """An observation the controller refuses to act on; the message lists every problem.

    Example:
        >>> from rfmp_deploy.metadata import example_metadata, parse_metadata
        >>> try:
        ...     ObservationProcessor(parse_metadata(example_metadata()))({"gripper": [0.1]})
        ... except ObservationError as e:
        ...     print(e)
        missing key 'eef_pos' (3 value(s)); missing key 'eef_quat' (4 value(s));
        missing camera 'wrist'
    """


def canonical_quaternion_signs(
    q: np.ndarray,
    reference: Sequence[float] | np.ndarray = (0.0, 0.0, 0.0, 1.0),
    *,
    previous: np.ndarray | None = None,
) -> np.ndarray:
    """The sign rule along a stream ``(..., T, 4)``: ``p_{-1} = reference`` (or ``previous``,
    the stream's last canonical sample), ``p_k = q_k`` if ``<q_k, p_{k-1}> >= 0`` else
    ``-q_k``. The numpy twin of ``rfmp_rl.data.quaternions.canonical_quaternion_signs`` (this
    package does not import rfmp_rl; a test checks that the two agree).

    Example:
        >>> hand = np.array([[-1.0, 0, 0, 0.01], [1.0, 0, 0, 0.01], [-1.0, 0, 0, -0.01]])
        >>> canonical_quaternion_signs(hand, (1.0, 0, 0, 0))[:, 0].tolist()
        [1.0, 1.0, 1.0]
    """
    q = np.asarray(q)
    if q.ndim < 2 or q.shape[-1] != 4:
        raise ValueError(f"canonical_quaternion_signs: expected shape (..., T, 4), got {q.shape}")
    if q.shape[-2] == 0:
        return q.copy()
    start = np.asarray(reference if previous is None else previous, dtype=q.dtype)
    first = (q[..., :1, :] * start[..., None, :]).sum(-1)  # (..., 1)
    dots = np.concatenate([first, (q[..., 1:, :] * q[..., :-1, :]).sum(-1)], axis=-1)
    # s_k = s_{k-1} * sign(d_k), and s_k = +1 where d_k == 0 (k >= 1)
    running = np.cumprod(np.where(dots < 0, -1.0, 1.0), axis=-1)
    steps = np.broadcast_to(np.arange(dots.shape[-1]), dots.shape)
    restart = (dots == 0) & (steps > 0)
    last = np.maximum.accumulate(np.where(restart, steps, 0), axis=-1)
    base = np.where(last > 0, np.take_along_axis(running, last, axis=-1), 1.0)
    return (q * (running * base)[..., None]).astype(q.dtype, copy=False)


@dataclass(frozen=True)
class Frame:
    """One preprocessed time step.

    Attributes:
        lowdim: ``(D_obs,)`` float32, the fields concatenated in ``observation_keys`` order, or
            ``None`` when the model has no low-dimensional input.
        images: camera name -> ``(C, H, W)`` uint8 at the model's image size.

    Example:
        >>> frame = Frame(np.zeros(3, np.float32), {"wrist": np.zeros((3, 84, 84), np.uint8)})
        >>> frame.lowdim.shape, frame.images["wrist"].shape
        ((3,), (3, 84, 84))
    """

    lowdim: np.ndarray | None
    images: dict[str, np.ndarray]


def _cv2() -> ModuleType:
    try:
        import cv2
    except ImportError as e:  # pragma: no cover - depends on the robot PC
        raise ImportError(
            "this policy has cameras, and resizing frames needs OpenCV: "
            "pip install opencv-python-headless (see deploy/requirements.txt)"
        ) from e
    return cv2


def _describe(value: Any) -> str:
    if isinstance(value, np.ndarray):
        return f"array of shape {value.shape} and dtype {value.dtype}"
    return type(value).__name__


class ObservationProcessor:
    """Validates observation dicts against a model's metadata and turns them into `Frame` s.

    Low-dim values may be any real integer or floating array (or list) of shape ``(dim,)``
    (a scalar is accepted for ``dim == 1``); they are cast to float32 and must be finite after
    the cast. Camera frames must be ``np.ndarray`` uint8 ``(H, W, C)`` with the model's channel
    count (RGB order; convert OpenCV's BGR captures with ``cv2.cvtColor``); ``(H, W)`` is
    accepted for single-channel models. Keys the model does not use are ignored.

    Args:
        meta: the policy's metadata.

    Example:
        >>> from rfmp_deploy.metadata import example_metadata, parse_metadata
        >>> process = ObservationProcessor(parse_metadata(example_metadata()))
        >>> frame = process({"eef_pos": [0.1, 0.2, 0.3], "eef_quat": [0, 0, 0, 1],
        ...                  "gripper": 0.04, "wrist": np.zeros((480, 640, 3), np.uint8)})
        >>> frame.lowdim.shape, frame.images["wrist"].shape
        ((8,), (3, 84, 84))
        >>> process({"eef_pos": [0.1, float("nan"), 0.3], "eef_quat": [0, 0, 0, 1]})
        Traceback (most recent call last):
        ...
        rfmp_deploy.observation.ObservationError: 'eef_pos': non-finite value(s) ...
    """

    def __init__(self, meta: PolicyMeta) -> None:
        self.meta = meta
        self.fields = meta.observation_keys
        self.cameras = meta.image_inputs
        self.quaternions = meta.observation_quaternions
        self._cv2 = _cv2() if self.cameras else None
        self._previous: list[np.ndarray] | None = None  # last canonical quaternion per field

    def reset(self) -> None:
        """Start new quaternion streams: the next frame's quaternions take their references'
        hemispheres (`Controller.reset` calls it)."""
        self._previous = None

    def __call__(self, observation: Mapping[str, Any]) -> Frame:
        """Validate and preprocess one observation.

        Raises:
            ObservationError: listing every missing key, wrong shape or dtype and non-finite
                value at once.
        """
        if not isinstance(observation, Mapping):
            raise ObservationError(f"observation must be a dict, got {_describe(observation)}")
        problems: list[str] = []
        parts = []
        for f in self.fields:
            if f.key not in observation:
                problems.append(f"missing key '{f.key}' ({f.dim} value(s))")
                continue
            value = self._lowdim(f.key, f.dim, observation[f.key], problems)
            if value is not None:
                parts.append(value)
        images = {}
        for spec in self.cameras:
            if spec.name not in observation:
                problems.append(f"missing camera '{spec.name}'")
                continue
            image = self._image(spec.name, spec.shape[1:], observation[spec.name], problems)
            if image is not None:
                images[spec.name] = image
        if problems:
            raise ObservationError("; ".join(problems))
        lowdim = np.concatenate(parts).astype(np.float32) if self.fields else None
        if lowdim is not None and self.quaternions:
            lowdim = self._canonical(lowdim)
        return Frame(lowdim, images)

    def _canonical(self, lowdim: np.ndarray) -> np.ndarray:
        """Canonical signs of the quaternion columns (one frame of each stream); only a frame
        that passed every check gets here, so a rejected one leaves the streams as they were."""
        previous = []
        for i, q in enumerate(self.quaternions):
            start = (np.asarray(q.reference, np.float32) if self._previous is None
                     else self._previous[i])
            value = canonical_quaternion_signs(lowdim[None, q.columns], previous=start)[0]
            lowdim[q.columns] = value
            previous.append(value.copy())
        self._previous = previous
        return lowdim

    def _lowdim(self, key: str, dim: int, value: Any, problems: list[str]) -> np.ndarray | None:
        try:
            array = np.asarray(value)
        except Exception as e:  # anything unconvertible is a bad reading
            problems.append(f"'{key}': cannot convert to an array ({e})")
            return None
        if array.dtype == np.bool_ or array.dtype.kind not in "iuf":
            problems.append(f"'{key}': expected real numbers, got dtype {array.dtype}")
            return None
        if array.shape != (dim,) and not (dim == 1 and array.shape == ()):
            problems.append(f"'{key}': expected shape ({dim},), got {array.shape}")
            return None
        with np.errstate(over="ignore"):
            out = array.reshape(dim).astype(np.float32)
        bad = ~np.isfinite(out)
        if bad.any():
            problems.append(f"'{key}': non-finite value(s) at {np.flatnonzero(bad).tolist()} "
                            f"(NaN, inf or beyond float32)")
            return None
        return out

    def _image(
        self, name: str, chw: Sequence[int], frame: Any, problems: list[str]
    ) -> np.ndarray | None:
        c, h, w = chw
        if not isinstance(frame, np.ndarray):
            problems.append(f"camera '{name}': expected a uint8 numpy array, got "
                            f"{_describe(frame)}")
            return None
        if frame.dtype != np.uint8:
            problems.append(f"camera '{name}': expected dtype uint8, got {frame.dtype}")
            return None
        if c == 1 and frame.ndim == 2:
            frame = frame[:, :, None]
        if frame.ndim != 3 or frame.shape[2] != c or frame.shape[0] < 1 or frame.shape[1] < 1:
            problems.append(f"camera '{name}': expected an (H, W, {c}) frame, got shape "
                            f"{frame.shape}")
            return None
        if frame.shape[:2] != (h, w):
            try:
                frame = self._cv2.resize(
                    np.ascontiguousarray(frame), (w, h), interpolation=self._cv2.INTER_AREA
                )
            except Exception as e:  # cv2.error on frames OpenCV cannot handle
                problems.append(f"camera '{name}': resizing {frame.shape} failed ({e})")
                return None
            frame = frame.reshape(h, w, c)  # OpenCV drops a trailing channel axis of 1
        # always a copy: the robot's driver may overwrite its buffer before the next step, and
        # a view (a frame already at size, a grayscale frame, an HWC view of a CHW buffer)
        # would turn the window's earlier frames into the latest one
        return np.array(frame.transpose(2, 0, 1), dtype=np.uint8, order="C", copy=True)


def stack_window(
    frames: Sequence[Frame], meta: PolicyMeta
) -> tuple[np.ndarray | None, dict[str, np.ndarray]]:
    """The graph's observation inputs from the window's frames ordered in time (oldest first:
    ``[context, latest]``).

    Returns:
        ``(observation, images)``: ``(1, len(frames), D_obs)`` float32 or ``None``, and camera
        name -> ``(1, len(frames), C, H, W)`` uint8.
    """
    observation = None
    if meta.lowdim_input is not None:
        observation = np.stack([f.lowdim for f in frames])[None]  # (1, 2, D_obs)
    images = {
        name: np.stack([f.images[name] for f in frames])[None]  # (1, 2, C, H, W)
        for name in meta.cameras
    }
    return observation, images
