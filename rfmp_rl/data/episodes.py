"""The episode structure every reader returns, its manifest, and input validation.

A reader turns one source (a zarr store, an HDF5 file, a folder of bags) into a list of episodes
and a `Manifest`. An episode is a ``TensorDict`` with batch size ``[T]`` (T >= 1 steps); its
leaves are per-step arrays: float32/float64 vectors ``(T, D)``, images ``uint8 (T, H, W, C)`` as
the source stores them, integer or bool flags. Keys keep the source's names (nested keys for
nested sources, e.g. robomimic's ``("obs", "robot0_eef_pos")``) except that every reader names
the commanded action ``action``.

Per-step time: an episode may carry ``timestamp`` (`rfmp_rl.keys.TIMESTAMP`), float64 ``(T,)``,
seconds since the episode's first step (first value 0.0, strictly increasing). It is step
metadata: no sampler or policy reads it as an observation or action, and the store keeps it
float64. Readers derive it from the source's own time column where there is one (LeRobot's
``timestamp``) and otherwise as ``step / rate`` when the control rate is known
(`step_timestamps`); with no known rate they write none rather than invent one.

Nothing is dropped silently: `make_episode` refuses an empty episode, arrays of different
lengths and NaN/inf values with a `DataError` naming the file, key, episode and step, and the
manifest counts every episode and step that was read.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
import torch
from tensordict import TensorDict
from tensordict.utils import NestedKey

from rfmp_rl.keys import TIMESTAMP

__all__ = ["DataError", "Manifest", "make_episode", "key_name", "parse_key", "check_finite",
           "step_timestamps", "check_timestamps"]


class DataError(ValueError):
    """Bad demonstration input. The message names the file, and where known the key (or topic),
    the episode and the step.

    Example:
        >>> str(DataError("NaN value", file="d.zarr", key="action", episode=3, step=17))
        'd.zarr: key action, episode 3, step 17: NaN value'
    """

    def __init__(
        self,
        message: str,
        *,
        file: str | None = None,
        key: str | None = None,
        episode: int | str | None = None,
        step: int | None = None,
        topic: str | None = None,
    ) -> None:
        self.file, self.key, self.episode, self.step, self.topic = file, key, episode, step, topic
        where = []
        if topic is not None:
            where.append(f"topic {topic}")
        if key is not None:
            where.append(f"key {key}")
        if episode is not None:
            where.append(f"episode {episode}")
        if step is not None:
            where.append(f"step {step}")
        prefix = f"{file}: " if file is not None else ""
        prefix += ", ".join(where) + (": " if where else "")
        super().__init__(prefix + message)


def key_name(key: NestedKey) -> str:
    """``("obs", "eef_pos")`` -> ``"obs/eef_pos"``; strings unchanged."""
    return key if isinstance(key, str) else "/".join(key)


def parse_key(key: NestedKey) -> NestedKey:
    """The inverse of `key_name`: ``"obs/eef_pos"`` -> ``("obs", "eef_pos")`` (the form the
    manifest prints is accepted wherever a key is taken); other keys unchanged."""
    if isinstance(key, str) and "/" in key:
        return tuple(part for part in key.split("/") if part)
    return tuple(key) if isinstance(key, list) else key


def check_finite(
    values: np.ndarray | torch.Tensor,
    *,
    file: str,
    key: str,
    episode: int | str,
    step_offset: int = 0,
) -> None:
    """Raise `DataError` at the first step of ``values`` (steps on axis 0) holding NaN or inf.

    Example:
        >>> check_finite(np.array([[0.0], [np.inf]]), file="f.h5", key="action", episode=0)
        Traceback (most recent call last):
        ...
        rfmp_rl.data.episodes.DataError: f.h5: key action, episode 0, step 1: non-finite value inf
    """
    arr = values.numpy() if isinstance(values, torch.Tensor) else np.asarray(values)
    if not np.issubdtype(arr.dtype, np.floating) or arr.size == 0:
        return
    bad = ~np.isfinite(arr.reshape(arr.shape[0], -1)).all(axis=1)
    if bad.any():
        step = int(np.argmax(bad))
        row = arr[step].reshape(-1)
        value = row[~np.isfinite(row)][0]
        raise DataError(
            f"non-finite value {value}", file=file, key=key, episode=episode,
            step=step + step_offset,
        )


def step_timestamps(length: int, rate_hz: float) -> np.ndarray:
    """Timestamps of ``length`` steps at a fixed control rate: ``float64 (T,)`` = ``i / rate_hz``.

    Example:
        >>> step_timestamps(4, 10.0).tolist()
        [0.0, 0.1, 0.2, 0.3]
    """
    if not rate_hz > 0:
        raise ValueError(f"step_timestamps: rate_hz must be > 0, got {rate_hz}")
    return np.arange(int(length), dtype=np.float64) / float(rate_hz)


def check_timestamps(
    values: np.ndarray | torch.Tensor, *, file: str, key: str, episode: int | str
) -> None:
    """Raise `DataError` unless ``values`` is a ``(T,)`` float array starting at 0.0 and strictly
    increasing (naming the first step that is not later than the one before).

    Example:
        >>> check_timestamps(np.array([0.0, 0.1, 0.1]), file="d", key="timestamp", episode=0)
        Traceback (most recent call last):
        ...
        rfmp_rl.data.episodes.DataError: d: key timestamp, episode 0, step 2: timestamps not incr...
    """
    arr = values.numpy() if isinstance(values, torch.Tensor) else np.asarray(values)
    if arr.ndim != 1 or not np.issubdtype(arr.dtype, np.floating):
        raise DataError(f"timestamps must be a float (T,) array, got {arr.dtype} {arr.shape}",
                        file=file, key=key, episode=episode)
    if arr.size and arr[0] != 0.0:
        raise DataError(f"the first timestamp must be 0.0, got {arr[0]!r}", file=file, key=key,
                        episode=episode, step=0)
    bad = np.flatnonzero(~(np.diff(arr) > 0))
    if bad.size:
        step = int(bad[0]) + 1
        raise DataError(f"timestamps not increasing ({arr[step]:g} after {arr[step - 1]:g})",
                        file=file, key=key, episode=episode, step=step)


def make_episode(
    arrays: Mapping[NestedKey, np.ndarray | torch.Tensor],
    *,
    file: str,
    episode: int | str,
) -> TensorDict:
    """Validate per-step arrays and stack them into one episode ``TensorDict`` of batch ``[T]``.

    Args:
        arrays: key -> array with steps on axis 0. All must have the same length T >= 1.
        file: the source file (for error messages).
        episode: the episode's index or name in the source (for error messages).

    Raises:
        DataError: no arrays, an empty episode, arrays of different lengths (naming the first
            key whose length differs from the one most arrays share, and a key with that
            length), a NaN/inf value (naming key and step), or
            a ``timestamp`` that is not float64 ``(T,)`` from 0.0, strictly increasing.

    Example:
        >>> ep = make_episode({"action": np.zeros((5, 2)), ("obs", "pos"): np.ones((5, 3))},
        ...                   file="demo.h5", episode="demo_0")
        >>> ep.batch_size, ep["obs", "pos"].dtype
        (torch.Size([5]), torch.float64)
        >>> make_episode({"act": np.zeros((5, 2)), "obs": np.ones((4, 3))}, file="d.h5", episode=1)
        Traceback (most recent call last):
        ...
        rfmp_rl.data.episodes.DataError: d.h5: key obs, episode 1, step 4: 4 steps, but act has 5...
    """
    if not arrays:
        raise DataError("no arrays to build an episode from", file=file, episode=episode)
    lengths = {key: int(value.shape[0]) if value.ndim > 0 else 0 for key, value in arrays.items()}
    counts = list(lengths.values())
    # The length most arrays share is the episode's (ties: the first key's), so the array that
    # disagrees is the one named, whichever comes first.
    length = max(counts, key=lambda n: (counts.count(n), -counts.index(n)))
    ref_key = next(key for key, n in lengths.items() if n == length)
    for key, n in lengths.items():
        if n != length:
            raise DataError(  # the step is the first one the shorter array lacks
                f"{n} steps, but {key_name(ref_key)} has {length} steps",
                file=file, key=key_name(key), episode=episode, step=min(n, length),
            )
    if not length:
        raise DataError(
            "empty episode (0 steps)", file=file, key=key_name(ref_key), episode=episode
        )
    out = TensorDict({}, batch_size=[length])
    for key, value in arrays.items():
        check_finite(value, file=file, key=key_name(key), episode=episode)
        if key == TIMESTAMP:
            if value.dtype not in (np.float64, torch.float64):
                raise DataError(f"timestamps must be float64, got {value.dtype}", file=file,
                                key=TIMESTAMP, episode=episode)
            check_timestamps(value, file=file, key=TIMESTAMP, episode=episode)
        if not isinstance(value, torch.Tensor):
            value = torch.from_numpy(np.ascontiguousarray(value))
        out.set(key, value)
    return out


@dataclass
class Manifest:
    """What a reader read: every episode and step counted, each key's per-step shape and dtype.

    Attributes:
        source: the file or folder read.
        format: ``"zarr"``, ``"robomimic"``, ``"lasa"``, ``"ros2"``, ``"ros1"``, ...
        rate_hz: the control rate of the steps, when known.
        episodes, steps: counts of what was read (and returned).
        episode_names: the source's name for each episode, in order.
        episode_lengths: steps per episode, in order.
        keys: ``"a/b"`` -> ``{"shape": [per-step shape], "dtype": "float32"}``.
        gaps: streams that went without data for longer than the reader allows, each
            ``{"file", "episode", "topic", "kind", "start_s", "end_s", "length_s"}`` (``kind``:
            ``"gap"``, ``"late start"`` or ``"early end"``; times in seconds from the start of
            the recording the episode was cut from).
        skipped: what was read but not returned, each ``{"file", "reason"}`` (and
            ``"episode"`` for a part of a file): unreadable files, slivers between gaps.
        extra: source metadata (env arguments, topics, split filters, ...); a reader that
            leaves source entries out lists them in ``extra["skipped_keys"]`` (key -> reason),
            printed with the manifest.

    Example:
        >>> m = Manifest(source="demo.h5", format="robomimic", rate_hz=20.0)
        >>> m.add(make_episode({"action": np.zeros((4, 7), np.float32)}, file="demo.h5",
        ...                    episode=0), name="demo_0")
        >>> m.episodes, m.steps, m.keys["action"]
        (1, 4, {'shape': [7], 'dtype': 'float32'})
    """

    source: str
    format: str
    rate_hz: float | None = None
    episodes: int = 0
    steps: int = 0
    episode_names: list[str] = field(default_factory=list)
    episode_lengths: list[int] = field(default_factory=list)
    keys: dict[str, dict[str, Any]] = field(default_factory=dict)
    gaps: list[dict[str, Any]] = field(default_factory=list)
    skipped: list[dict[str, Any]] = field(default_factory=list)
    extra: dict[str, Any] = field(default_factory=dict)

    def add(self, episode: TensorDict, name: str | int) -> None:
        """Count one episode and record (or check) its keys' shapes and dtypes."""
        self.episodes += 1
        self.steps += int(episode.batch_size[0])
        self.episode_names.append(str(name))
        self.episode_lengths.append(int(episode.batch_size[0]))
        for key, value in episode.items(include_nested=True, leaves_only=True):
            dtype = str(value.dtype).removeprefix("torch.")
            entry = {"shape": list(value.shape[1:]), "dtype": dtype}
            name_ = key_name(key)
            if name_ in self.keys and self.keys[name_] != entry:
                raise DataError(
                    f"per-step shape/dtype {entry} differs from earlier episodes' "
                    f"{self.keys[name_]}",
                    file=self.source, key=name_, episode=name,
                )
            self.keys.setdefault(name_, entry)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), indent=2, default=str)

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> Manifest:
        return cls(**dict(data))

    def __str__(self) -> str:
        rate = f"{self.rate_hz:g} Hz" if self.rate_hz else "unknown rate"
        lines = [
            f"{self.format} source {self.source}",
            f"  {self.episodes} episodes, {self.steps} steps, {rate}",
        ]
        if self.episode_lengths:
            lens = np.asarray(self.episode_lengths)
            lines.append(
                f"  episode length min/mean/max {lens.min()}/{lens.mean():.1f}/{lens.max()}"
            )
        width = max((len(k) for k in self.keys), default=0)
        for name, entry in self.keys.items():
            shape = "x".join(str(s) for s in entry["shape"]) or "scalar"
            lines.append(f"  {name:<{width}}  {shape:<12} {entry['dtype']}")
        quats = self.extra.get("quaternions")
        for f in (quats or {}).get("fields", []):
            cols = "" if f["columns"] is None else f"[{f['columns'][0]}:{f['columns'][1]}]"
            what = ("raw signs kept" if quats["raw_signs"] else "w >= 0 first, continuous")
            lines.append(f"  quaternions {f['key']}{cols}:{f['order']} ({what}): "
                         f"{f['first_flipped']} episodes with w < 0 first, "
                         f"{f['continuity_flipped']} with sign switches")
        if self.gaps:
            lines.append(f"  {len(self.gaps)} gaps (episodes cut there):")
        for gap in self.gaps:
            lines.append(
                f"    {gap['episode']} {gap['topic']}: {gap['kind']}, {gap['start_s']:.3f} s to "
                f"{gap['end_s']:.3f} s ({gap['length_s']:.3f} s)"
            )
        for name, reason in (self.extra.get("skipped_keys") or {}).items():
            lines.append(f"  {name}: not stored ({reason})")
        if self.skipped:
            lines.append(f"  {len(self.skipped)} skipped:")
        for item in self.skipped:
            lines.append(f"    {item.get('episode', item['file'])}: {item['reason']}")
        return "\n".join(lines)
