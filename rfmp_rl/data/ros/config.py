"""The topic configuration of the ROS bag reader: which topics become which keys, at which
rate, how episodes are cut and what a gap does (the YAML layout is in `rfmp_rl.data.ros`)."""

from __future__ import annotations

import math
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from rfmp_rl.data.episodes import DataError
from rfmp_rl.keys import TIMESTAMP
from rfmp_rl.manifolds import parse_manifold

__all__ = [
    "TopicConfig", "VectorPart", "RosbagConfig", "load_rosbag_config", "CONFIG_FIELDS", "ON_GAP",
    "TIMESTAMP",
]

JOINT_FIELDS = ("position", "velocity", "effort")
# The per-step key of the grid times (float64 seconds since the episode's first step) is
# rfmp_rl.keys.TIMESTAMP, shared by every reader.



@dataclass(frozen=True)
class TopicConfig:
    """How one topic becomes an episode key.

    Attributes:
        key: the episode key; ``"a/b"`` becomes the nested key ``("a", "b")``. Poses add
            ``"position"`` and ``"orientation"`` below it.
        field: for ``sensor_msgs/JointState`` only: ``"position"`` (default), ``"velocity"``
            or ``"effort"``.
        joints: for ``sensor_msgs/JointState`` only: the joints to keep, in this order.

    Example:
        >>> TopicConfig.from_value({"key": "joints", "field": "velocity"})
        TopicConfig(key='joints', field='velocity', joints=None)
        >>> TopicConfig.from_value("gripper").key
        'gripper'
    """

    key: str
    field: str | None = None
    joints: tuple[str, ...] | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.key, str) or not self.key or "" in self.key.split("/"):
            raise DataError(
                f"topic key must be a non-empty name like 'a' or 'a/b', got {self.key!r}"
            )
        _check_joint_options(self.field, self.joints)
        if self.joints is not None:
            object.__setattr__(self, "joints", tuple(self.joints))

    @property
    def nested_key(self) -> str | tuple[str, ...]:
        parts = tuple(self.key.split("/"))
        return parts[0] if len(parts) == 1 else parts

    @classmethod
    def from_value(cls, value: str | Mapping[str, Any] | TopicConfig) -> TopicConfig:
        """Build from a key string or a mapping with ``key`` and optional ``field``, ``joints``."""
        if isinstance(value, TopicConfig):
            return value
        if isinstance(value, str):
            return cls(key=value)
        if not isinstance(value, Mapping):
            raise DataError(f"a topic entry must be a key name or a mapping, got {value!r}")
        unknown = set(value) - {"key", "field", "joints"}
        if unknown:
            raise DataError(
                f"unknown topic option(s) {sorted(unknown)}; allowed: key, field, joints"
            )
        if "key" not in value:
            raise DataError(f"topic entry {dict(value)} has no 'key'")
        joints = value.get("joints")
        return cls(
            key=value["key"],
            field=value.get("field"),
            joints=tuple(joints) if joints is not None else None,
        )

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {"key": self.key}
        if self.field is not None:
            out["field"] = self.field
        if self.joints is not None:
            out["joints"] = list(self.joints)
        return out


@dataclass(frozen=True)
class VectorPart:
    """One topic's share of a flat vector (``action: [...]``, ``observation: [...]``).

    Attributes:
        topic: the topic name.
        field: for ``sensor_msgs/JointState`` only: ``"position"`` (default), ``"velocity"``
            or ``"effort"``.
        joints: for ``sensor_msgs/JointState`` only: the joints to keep, in this order.

    Example:
        >>> VectorPart.from_value({"topic": "/joint_states", "field": "velocity"}).field
        'velocity'
        >>> VectorPart.from_value("/cmd_pose")
        VectorPart(topic='/cmd_pose', field=None, joints=None)
    """

    topic: str
    field: str | None = None
    joints: tuple[str, ...] | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.topic, str) or not self.topic:
            raise DataError(f"a vector entry needs a topic name, got {self.topic!r}")
        _check_joint_options(self.field, self.joints)
        if self.joints is not None:
            object.__setattr__(self, "joints", tuple(self.joints))

    @classmethod
    def from_value(cls, value: str | Mapping[str, Any] | VectorPart) -> VectorPart:
        """Build from a topic name or a mapping ``{topic, field, joints}``."""
        if isinstance(value, VectorPart):
            return value
        if isinstance(value, str):
            return cls(topic=value)
        if not isinstance(value, Mapping):
            raise DataError(f"a vector entry must be a topic name or a mapping, got {value!r}")
        unknown = set(value) - {"topic", "field", "joints"}
        if unknown or "topic" not in value:
            raise DataError(
                f"vector entry {dict(value)}: allowed fields are topic (required), field, joints"
            )
        joints = value.get("joints")
        return cls(topic=value["topic"], field=value.get("field"),
                   joints=tuple(joints) if joints is not None else None)

    def to_dict(self) -> str | dict[str, Any]:
        if self.field is None and self.joints is None:
            return self.topic
        out: dict[str, Any] = {"topic": self.topic}
        if self.field is not None:
            out["field"] = self.field
        if self.joints is not None:
            out["joints"] = list(self.joints)
        return out


def _check_joint_options(field_: str | None, joints: Sequence[str] | None) -> None:
    if field_ is not None and field_ not in JOINT_FIELDS:
        raise DataError(f"field must be one of {JOINT_FIELDS}, got {field_!r}")
    if joints is not None:
        joints = tuple(joints)
        if not joints or len(set(joints)) != len(joints):
            raise DataError(f"joints must be distinct names, got {list(joints)}")


def _number(value: Any) -> float:
    """A config number as a float; NaN for what is not one (so the caller's check names it)."""
    try:
        return float(value)
    except (TypeError, ValueError):
        return math.nan


#: The fields of a rosbag config file, in the order rfmp_rl/data/README.md documents them.
CONFIG_FIELDS = (
    "rate_hz", "topics", "action", "action_manifold", "observation", "observation_manifold",
    "time_reference", "segment", "max_gap_s", "on_gap",
)
ON_GAP = ("error", "split")


def _parse_vectors(
    data: Mapping[str, Any],
) -> tuple[dict[str, tuple[VectorPart, ...]], dict[str, str]]:
    """``action`` / ``observation`` (+ ``*_manifold``) -> vector key -> parts, key -> manifold."""
    vectors: dict[str, tuple[VectorPart, ...]] = {}
    manifolds: dict[str, str] = {}

    def parts(name: str, value: Any) -> tuple[VectorPart, ...]:
        if isinstance(value, str | Mapping) or not isinstance(value, Sequence) or not value:
            raise DataError(f"{name} must be a non-empty list of topics, got {value!r}")
        return tuple(VectorPart.from_value(v) for v in value)

    if "action" in data:
        vectors["action"] = parts("action", data["action"])
    if "action_manifold" in data:
        if "action" not in data:
            raise DataError("action_manifold is given without action: [topics]")
        manifolds["action"] = str(data["action_manifold"])
    obs = data.get("observation")
    obs_manifold = data.get("observation_manifold")
    if isinstance(obs, Mapping):
        if obs_manifold is not None and not isinstance(obs_manifold, Mapping):
            raise DataError(
                "observation is a mapping {name: [topics]}, so observation_manifold must be "
                f"one too ({{name: 'R3 x S3'}}), got {obs_manifold!r}"
            )
        for name, value in obs.items():
            vectors[f"observation/{name}"] = parts(f"observation/{name}", value)
        for name, spec in dict(obs_manifold or {}).items():
            if name not in obs:
                raise DataError(f"observation_manifold names {name!r}, not one of {list(obs)}")
            manifolds[f"observation/{name}"] = str(spec)
    elif obs is not None:
        vectors["observation"] = parts("observation", obs)
        if obs_manifold is not None:
            manifolds["observation"] = str(obs_manifold)
    elif obs_manifold is not None:
        raise DataError("observation_manifold is given without observation: [topics]")
    for key, spec in manifolds.items():
        try:
            parse_manifold(spec)
        except ValueError as err:
            raise DataError(f"{key}: manifold {spec!r}: {err}") from err
    return vectors, manifolds


@dataclass(frozen=True)
class RosbagConfig:
    """Which topics to read, as which keys, at which rate, and how to cut episodes.

    Attributes:
        topics: topic name -> `TopicConfig` (one key per topic).
        rate_hz: the control rate of the episode grid (``read_rosbags(rate_hz=...)`` overrides
            it).
        time_reference: a key whose stream's first/last stamps bound each episode; default:
            the overlap of all streams.
        segment_topic: a ``std_msgs/Bool`` or ``std_msgs/String`` topic whose start/end markers
            cut a bag into episodes; default: one bag is one episode.
        vectors: flat float32 keys built from several topics: ``"action"``,
            ``"observation"`` or ``"observation/<name>"`` -> its `VectorPart` s, in order.
        manifolds: vector key -> the manifold its flat layout must match (``"R3 x S3 x R1"``).
        max_gap_s: the longest time a stream may go without a message (also at the start or
            end of an episode); default: the larger of 0.5 s and 3 grid periods.
        on_gap: ``"error"`` (default) or ``"split"``: what a longer gap does.

    Example:
        >>> cfg = RosbagConfig.from_dict({
        ...     "rate_hz": 10,
        ...     "topics": {"/ee": {"key": "obs/ee_pose"}, "/cmd": "command"},
        ...     "action": ["/cmd_pose", "/gripper_cmd"],
        ...     "action_manifold": "R3 x S3 x R1",
        ...     "segment": {"topic": "/episode_marker"},
        ... })
        >>> cfg.topics["/ee"].nested_key, cfg.rate_hz, cfg.segment_topic
        (('obs', 'ee_pose'), 10.0, '/episode_marker')
        >>> [p.topic for p in cfg.vectors["action"]], cfg.gap_limit_s(10.0), cfg.on_gap
        (['/cmd_pose', '/gripper_cmd'], 0.5, 'error')
        >>> RosbagConfig.from_dict({"topics": {"/a": "x"}, "concat": {"action": ["/a"]}})
        Traceback (most recent call last):
        ...
        rfmp_rl.data.episodes.DataError: unknown rosbag config field(s) ['concat']; allowed: ...
    """

    topics: Mapping[str, TopicConfig] = field(default_factory=dict)
    rate_hz: float | None = None
    time_reference: str | None = None
    segment_topic: str | None = None
    vectors: Mapping[str, Sequence[VectorPart]] = field(default_factory=dict)
    manifolds: Mapping[str, str] = field(default_factory=dict)
    max_gap_s: float | None = None
    on_gap: str = "error"

    def __post_init__(self) -> None:
        topics = {str(t): TopicConfig.from_value(c) for t, c in dict(self.topics).items()}
        object.__setattr__(self, "topics", topics)
        vectors = {
            str(k): tuple(VectorPart.from_value(p) for p in v)
            for k, v in dict(self.vectors).items()
        }
        object.__setattr__(self, "vectors", vectors)
        object.__setattr__(self, "manifolds", {str(k): str(v) for k, v in self.manifolds.items()})
        if not topics and not vectors:
            raise DataError("rosbag config: no topics (give topics, action or observation)")
        unknown = set(self.manifolds) - set(vectors)
        if unknown:
            raise DataError(f"rosbag config: manifolds for unknown vector keys {sorted(unknown)}")
        keys = [c.key for c in topics.values()] + list(vectors) + [TIMESTAMP]
        for i, key in enumerate(keys):
            for other in keys[i + 1 :]:
                if key == other or other.startswith(key + "/") or key.startswith(other + "/"):
                    raise DataError(f"rosbag config: keys {key!r} and {other!r} collide")
        self.read_options()  # a topic read for several keys must be read one way
        if self.rate_hz is not None:
            rate = _number(self.rate_hz)
            if not (math.isfinite(rate) and rate > 0):
                raise DataError(f"rate_hz must be positive, got {self.rate_hz!r}")
            object.__setattr__(self, "rate_hz", rate)
        if self.time_reference is not None and self.time_reference not in keys[:-1]:
            raise DataError(
                f"time_reference {self.time_reference!r} is not one of the keys {keys[:-1]}"
            )
        if self.segment_topic is not None and self.segment_topic in self.read_options():
            raise DataError(f"segment topic {self.segment_topic} is also a data topic")
        if self.max_gap_s is not None:
            gap = _number(self.max_gap_s)
            if not (math.isfinite(gap) and gap > 0):
                raise DataError(f"max_gap_s must be a positive number of seconds, got "
                                f"{self.max_gap_s!r}")
            object.__setattr__(self, "max_gap_s", gap)
        if self.on_gap not in ON_GAP:
            raise DataError(f"on_gap must be one of {', '.join(ON_GAP)}, got {self.on_gap!r}")

    def read_options(self) -> dict[str, TopicConfig]:
        """Every topic read (data topics first, then vector parts) -> its reading options
        (``key`` is the first key it feeds, for messages)."""
        out: dict[str, TopicConfig] = dict(self.topics)
        for key, parts in self.vectors.items():
            for part in parts:
                seen = out.get(part.topic)
                if seen is None:
                    out[part.topic] = TopicConfig(key=key, field=part.field, joints=part.joints)
                    continue
                field_ = part.field if part.field is not None else seen.field
                joints = part.joints if part.joints is not None else seen.joints
                if (seen.field is not None and field_ != seen.field) or (
                    seen.joints is not None and joints != seen.joints
                ):
                    raise DataError(
                        f"topic {part.topic} is read with field={seen.field}, "
                        f"joints={seen.joints} for {seen.key} but field={part.field}, "
                        f"joints={part.joints} for {key}; a topic is read one way"
                    )
                out[part.topic] = TopicConfig(key=seen.key, field=field_, joints=joints)
        return out

    def gap_limit_s(self, rate_hz: float) -> float:
        """``max_gap_s``, or its default at this rate: max(0.5 s, 3 grid periods)."""
        return self.max_gap_s if self.max_gap_s is not None else max(0.5, 3.0 / rate_hz)

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> RosbagConfig:
        """Build from the mapping of a YAML file (see the `rfmp_rl.data.ros` docstring)."""
        unknown = set(data) - set(CONFIG_FIELDS)
        if unknown:
            raise DataError(
                f"unknown rosbag config field(s) {sorted(unknown)}; "
                f"allowed: {', '.join(CONFIG_FIELDS)}"
            )
        topics = data.get("topics", {})
        if not isinstance(topics, Mapping):
            raise DataError("rosbag config 'topics' must be a mapping topic -> {key: ...}")
        segment = data.get("segment")
        segment_topic = None
        if segment is not None:
            if not isinstance(segment, Mapping) or set(segment) != {"topic"}:
                raise DataError(f"segment must be a mapping {{topic: /name}}, got {segment!r}")
            segment_topic = str(segment["topic"])
        vectors, manifolds = _parse_vectors(data)
        return cls(
            topics=dict(topics),
            rate_hz=data.get("rate_hz"),
            time_reference=data.get("time_reference"),
            segment_topic=segment_topic,
            vectors=vectors,
            manifolds=manifolds,
            max_gap_s=data.get("max_gap_s"),
            on_gap=data.get("on_gap", "error"),
        )

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            "rate_hz": self.rate_hz,
            "topics": {t: c.to_dict() for t, c in self.topics.items()},
        }
        observation: dict[str, Any] = {}
        for key, parts in self.vectors.items():
            entries = [p.to_dict() for p in parts]
            if key == "action":
                out["action"] = entries
            elif key == "observation":
                out["observation"] = entries
            else:
                observation[key.removeprefix("observation/")] = entries
        if observation:
            out["observation"] = observation
        for key, spec in self.manifolds.items():
            if key in ("action", "observation"):
                out[f"{key}_manifold"] = spec
            else:
                out.setdefault("observation_manifold", {})[key.removeprefix("observation/")] = spec
        if self.time_reference is not None:
            out["time_reference"] = self.time_reference
        if self.segment_topic is not None:
            out["segment"] = {"topic": self.segment_topic}
        if self.max_gap_s is not None:
            out["max_gap_s"] = self.max_gap_s
        out["on_gap"] = self.on_gap
        return out


def load_rosbag_config(path: str | os.PathLike[str]) -> RosbagConfig:
    """Read a `RosbagConfig` from a YAML file (the layout in the `rfmp_rl.data.ros` docstring).

    Raises:
        DataError: an unreadable file or an invalid configuration, naming the file.

    Example:
        >>> import tempfile
        >>> from pathlib import Path
        >>> with tempfile.TemporaryDirectory() as tmp:
        ...     path = Path(tmp) / "topics.yaml"
        ...     _ = path.write_text("rate_hz: 10\\ntopics:\\n  /joint_states: {key: joints}\\n")
        ...     load_rosbag_config(path).topics["/joint_states"]
        TopicConfig(key='joints', field=None, joints=None)
    """
    import yaml  # PyYAML, a dependency of hydra-core

    try:
        with open(path, encoding="utf-8") as f:
            data = yaml.safe_load(f)
    except (OSError, yaml.YAMLError) as err:
        raise DataError(f"cannot read the rosbag config: {err}", file=str(path)) from err
    if not isinstance(data, Mapping):
        raise DataError(
            f"a rosbag config must be a YAML mapping, got {type(data).__name__}", file=str(path)
        )
    try:
        return RosbagConfig.from_dict(data)
    except ValueError as err:
        raise DataError(str(err), file=str(path)) from err
