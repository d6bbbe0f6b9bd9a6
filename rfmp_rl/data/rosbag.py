"""ROS 1 and ROS 2 bags as episodes on one control-rate time grid.

`read_rosbags` reads ``.bag`` files (ROS 1) and rosbag2 recordings (a folder with
``metadata.yaml``, or bare ``.db3`` / ``.mcap`` storage files) with ``rosbags==0.11.9``
(``pip install rfmp_rl[data]``); compressed images also need OpenCV (``opencv-python``). A
`RosbagConfig` maps each topic to an episode key::

    rate_hz: 10                # the control rate every stream is resampled to
    time_reference: action     # optional: this key's first/last stamps bound the episode
    topics:
      /robot/ee_pose: {key: ee_pose}                    # PoseStamped / Pose / TransformStamped
      /joint_states:  {key: joints, field: position}    # JointState position|velocity|effort
      /camera/image:  {key: image}                      # Image rgb8 / bgr8 / mono8
      /camera/compressed: {key: wrist}                  # CompressedImage (jpeg, png)
      /gripper:       {key: gripper}                    # Float32 / Float64 / Bool
    segment:
      topic: /episode_marker   # std_msgs/Bool (True = start) or std_msgs/String "start" / "end"

**Time.** A message's time is its ``header.stamp`` when the type has a header and the stamp is
non-zero, else the time the bag recorded it. Within each topic, messages are ordered by that
time (stable, so ties keep recording order) and of several messages with the same time the last
one recorded is used.

**Episodes.** Without ``segment`` one bag is one episode. With it, the marker topic's messages
(always timed by their record time: Bool and String have no header) act as a recording switch:
an episode spans from a start marker (``True`` / ``"start"``) to the next end marker
(``False`` / ``"end"``); repeated markers of the current state are ignored, so markers may be
published once per edge or continuously; a start without an end is an error. Only messages
timed inside ``[start, end]`` belong to the episode.

**Grid.** By default an episode covers the overlap of all its streams, ``[max first stamp,
min last stamp]``; with ``time_reference`` it covers that key's span, and the other streams are
held at their first/last value outside their own span. The grid is ``t0, t0 + 1/rate, ...``
up to the end of the span (both ends included when they fall on the grid). Values on it are:

* vectors (positions, joint values, scalars): linear interpolation (`resample_linear`);
* orientations: normalised, made hemisphere-continuous (``q_k -> -q_k`` when its dot product
  with ``q_{k-1}`` is negative, `rfmp_rl.manifolds.quaternion.hemisphere_continuous`), then
  slerp (`resample_slerp`) — so a sign flip in the recording disappears;
* images and bools: the nearest message in time (`nearest_indices`, ties to the earlier one).

**Keys, shapes and dtypes.** A key ``"a/b"`` becomes the nested key ``("a", "b")``. Per step:

* poses: ``(key, "position")`` float32 ``(3,)`` and ``(key, "orientation")`` float32 ``(4,)``, a
  unit quaternion in ROS's xyzw order (interpolated in float64, stored as float32);
* JointState ``field`` (default ``position``), Float32/Float64 and Float32/Float64MultiArray:
  float32 ``(D,)`` (``(1,)`` for scalars);
* Bool: bool ``(1,)``;
* Image: uint8 ``(H, W, 3)`` RGB (``bgr8`` is converted), ``mono8`` -> ``(H, W, 1)``;
* CompressedImage: decoded by OpenCV to uint8 RGB ``(H, W, 3)`` (grey -> ``(H, W, 1)``, alpha
  dropped). Only the frames the grid uses are decoded.

**JointState names.** Messages may list the joints in another order than the first message;
they are reordered by name. With ``joints: [j1, j2]`` the topic yields those joints in that
order, and messages that do not name all of them (another publisher on the same topic) are
skipped and counted in the manifest (``extra["topics"][topic]["skipped"]``).

**Errors.** Every problem raises `rfmp_rl.data.episodes.DataError` naming the bag and, where
known, the topic, key and episode: a missing path, a configured topic absent from a bag (the
message lists the bag's topics), an unsupported message type, an unreadable or truncated bag,
NaN/inf in a message (``step`` is then the message's index on its topic, counted from 0 in
recording order), a stream without messages in an episode or without time overlap with the
others, an unsupported image encoding and an undecodable compressed image.

The `rfmp_rl.data.episodes.Manifest` has format ``"ros1"`` or ``"ros2"`` (``"ros1+ros2"`` when
given both) and ``extra`` holds the files, the configuration, each topic's message types and the
number of messages read from it, and each episode's ``[first, last]`` grid stamp in nanoseconds.
"""

from __future__ import annotations

import math
import os
from collections.abc import Iterable, Iterator, Mapping, Sequence
from contextlib import contextmanager, suppress
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tensordict import TensorDict

from rfmp_rl.data.episodes import DataError, Manifest, make_episode
from rfmp_rl.manifolds.quaternion import hemisphere_continuous

__all__ = [
    "RosbagConfig",
    "TopicConfig",
    "load_rosbag_config",
    "read_rosbags",
    "slerp",
    "resample_linear",
    "resample_slerp",
    "nearest_indices",
]

#: Supported message types -> how they are read.
_KINDS: dict[str, str] = {
    "geometry_msgs/msg/PoseStamped": "pose",
    "geometry_msgs/msg/Pose": "pose",
    "geometry_msgs/msg/TransformStamped": "pose",
    "geometry_msgs/msg/Transform": "pose",
    "sensor_msgs/msg/JointState": "vector",
    "std_msgs/msg/Float32": "vector",
    "std_msgs/msg/Float64": "vector",
    "std_msgs/msg/Float32MultiArray": "vector",
    "std_msgs/msg/Float64MultiArray": "vector",
    "std_msgs/msg/Bool": "bool",
    "sensor_msgs/msg/Image": "image",
    "sensor_msgs/msg/CompressedImage": "compressed",
}
_MARKER_TYPES = ("std_msgs/msg/Bool", "std_msgs/msg/String")
_JOINT_STATE = "sensor_msgs/msg/JointState"
_JOINT_FIELDS = ("position", "velocity", "effort")
_IMAGE_CHANNELS = {"rgb8": 3, "bgr8": 3, "mono8": 1}


# --------------------------------------------------------------------------------------------
# Configuration


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
            raise ValueError(
                f"topic key must be a non-empty name like 'a' or 'a/b', got {self.key!r}"
            )
        if self.field is not None and self.field not in _JOINT_FIELDS:
            raise ValueError(f"field must be one of {_JOINT_FIELDS}, got {self.field!r}")
        if self.joints is not None:
            joints = tuple(self.joints)
            if not joints or len(set(joints)) != len(joints):
                raise ValueError(f"joints must be distinct names, got {list(joints)}")
            object.__setattr__(self, "joints", joints)

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
            raise ValueError(f"a topic entry must be a key name or a mapping, got {value!r}")
        unknown = set(value) - {"key", "field", "joints"}
        if unknown:
            raise ValueError(
                f"unknown topic option(s) {sorted(unknown)}; allowed: key, field, joints"
            )
        if "key" not in value:
            raise ValueError(f"topic entry {dict(value)} has no 'key'")
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
class RosbagConfig:
    """Which topics to read, as which keys, at which rate, and how to cut episodes.

    Attributes:
        topics: topic name -> `TopicConfig`.
        rate_hz: the control rate of the episode grid (``read_rosbags(rate_hz=...)`` overrides
            it).
        time_reference: a key whose stream's first/last stamps bound each episode; default:
            the overlap of all streams.
        segment_topic: a ``std_msgs/Bool`` or ``std_msgs/String`` topic whose start/end markers
            cut a bag into episodes; default: one bag is one episode.

    Example:
        >>> cfg = RosbagConfig.from_dict({
        ...     "rate_hz": 10,
        ...     "topics": {"/ee": {"key": "obs/ee_pose"}, "/cmd": "action"},
        ...     "time_reference": "action",
        ...     "segment": {"topic": "/episode_marker"},
        ... })
        >>> cfg.topics["/ee"].nested_key, cfg.rate_hz, cfg.segment_topic
        (('obs', 'ee_pose'), 10.0, '/episode_marker')
        >>> RosbagConfig.from_dict({"topics": {"/a": "x"}, "rate": 10})
        Traceback (most recent call last):
        ...
        ValueError: unknown rosbag config entry(s) ['rate']; allowed: rate_hz, segment, ...
    """

    topics: Mapping[str, TopicConfig]
    rate_hz: float | None = None
    time_reference: str | None = None
    segment_topic: str | None = None

    def __post_init__(self) -> None:
        topics = {str(t): TopicConfig.from_value(c) for t, c in dict(self.topics).items()}
        object.__setattr__(self, "topics", topics)
        if not topics:
            raise ValueError("rosbag config: no topics")
        keys = [c.key for c in topics.values()]
        for i, key in enumerate(keys):
            for other in keys[i + 1 :]:
                if key == other or other.startswith(key + "/") or key.startswith(other + "/"):
                    raise ValueError(f"rosbag config: keys {key!r} and {other!r} collide")
        if self.rate_hz is not None:
            rate = float(self.rate_hz)
            if not (math.isfinite(rate) and rate > 0):
                raise ValueError(f"rate_hz must be positive, got {self.rate_hz!r}")
            object.__setattr__(self, "rate_hz", rate)
        if self.time_reference is not None and self.time_reference not in keys:
            raise ValueError(
                f"time_reference {self.time_reference!r} is not one of the keys {keys}"
            )
        if self.segment_topic is not None and self.segment_topic in topics:
            raise ValueError(f"segment topic {self.segment_topic} is also a data topic")

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> RosbagConfig:
        """Build from the mapping of a YAML file (see the module docstring)."""
        allowed = {"rate_hz", "time_reference", "topics", "segment"}
        unknown = set(data) - allowed
        if unknown:
            raise ValueError(
                f"unknown rosbag config entry(s) {sorted(unknown)}; "
                f"allowed: {', '.join(sorted(allowed))}"
            )
        topics = data.get("topics")
        if not isinstance(topics, Mapping):
            raise ValueError("rosbag config needs 'topics': a mapping topic -> {key: ...}")
        segment = data.get("segment")
        segment_topic = None
        if segment is not None:
            if not isinstance(segment, Mapping) or set(segment) != {"topic"}:
                raise ValueError(f"segment must be a mapping {{topic: /name}}, got {segment!r}")
            segment_topic = str(segment["topic"])
        return cls(
            topics=dict(topics),
            rate_hz=data.get("rate_hz"),
            time_reference=data.get("time_reference"),
            segment_topic=segment_topic,
        )

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            "rate_hz": self.rate_hz,
            "topics": {t: c.to_dict() for t, c in self.topics.items()},
        }
        if self.time_reference is not None:
            out["time_reference"] = self.time_reference
        if self.segment_topic is not None:
            out["segment"] = {"topic": self.segment_topic}
        return out


def load_rosbag_config(path: str | os.PathLike[str]) -> RosbagConfig:
    """Read a `RosbagConfig` from a YAML file (the layout of the module docstring).

    Example:
        >>> import tempfile
        >>> with tempfile.TemporaryDirectory() as tmp:
        ...     path = Path(tmp) / "topics.yaml"
        ...     _ = path.write_text("rate_hz: 10\\ntopics:\\n  /joint_states: {key: joints}\\n")
        ...     load_rosbag_config(path).topics["/joint_states"]
        TopicConfig(key='joints', field=None, joints=None)
    """
    import yaml  # PyYAML, a dependency of hydra-core

    with open(path, encoding="utf-8") as f:
        data = yaml.safe_load(f)
    if not isinstance(data, Mapping):
        raise ValueError(
            f"{path}: a rosbag config must be a YAML mapping, got {type(data).__name__}"
        )
    return RosbagConfig.from_dict(data)


# --------------------------------------------------------------------------------------------
# Resampling (pure functions)


def slerp(q0: torch.Tensor, q1: torch.Tensor, w: torch.Tensor | float) -> torch.Tensor:
    """Spherical linear interpolation between unit quaternions along the great circle of S^3.

    ``q0`` and ``q1`` are interpolated as given (no sign flip): for the shorter rotation make
    them hemisphere-continuous first. They must not be antipodal. Nearly equal quaternions
    fall back to normalised linear interpolation.

    Args:
        q0, q1: unit quaternions, shape ``(..., 4)`` (any component order).
        w: interpolation weights in ``[0, 1]``, shape ``(...)`` or a float: 0 gives ``q0``.

    Returns:
        Unit quaternions, shape ``(..., 4)``.

    Example:
        >>> h = math.sqrt(0.5)
        >>> q = slerp(torch.tensor([0.0, 0, 0, 1]), torch.tensor([0.0, 0, h, h]), 0.5)
        >>> q  # half of a 90 degree rotation about z: 45 degrees
        tensor([0.0000, 0.0000, 0.3827, 0.9239])
        >>> float(2 * torch.atan2(q[2], q[3]).rad2deg())
        45.0
    """
    q0, q1 = torch.broadcast_tensors(q0, q1)
    w = torch.as_tensor(w, dtype=q0.dtype, device=q0.device)[..., None]
    # The angle between the two, stable for small and large angles alike.
    theta = 2 * torch.atan2((q0 - q1).norm(dim=-1), (q0 + q1).norm(dim=-1))[..., None]
    sin = torch.sin(theta)
    small = sin < 1e-9
    safe = torch.where(small, torch.ones_like(sin), sin)
    a = torch.where(small, 1 - w, torch.sin((1 - w) * theta) / safe)
    b = torch.where(small, w, torch.sin(w * theta) / safe)
    out = a * q0 + b * q1
    return out / out.norm(dim=-1, keepdim=True)


def _brackets(times: torch.Tensor, grid: torch.Tensor) -> tuple[torch.Tensor, ...]:
    """Indices ``i, j = i + 1`` of the samples around each grid time and the weight of ``j``,
    clamped so that grid times outside ``[times[0], times[-1]]`` hold the end values."""
    n = times.shape[0]
    if n == 0:
        raise ValueError("cannot resample a stream without samples")
    if n > 1 and not bool((times[1:] > times[:-1]).all()):
        raise ValueError("sample times must be strictly increasing")
    i = (torch.searchsorted(times, grid, right=True) - 1).clamp(0, max(n - 2, 0))
    j = (i + 1).clamp(max=n - 1)
    span = times[j] - times[i]
    w = torch.where(span > 0, (grid - times[i]) / torch.where(span > 0, span, 1), 0)
    return i, j, w.clamp(0, 1)


def resample_linear(times: torch.Tensor, values: torch.Tensor, grid: torch.Tensor) -> torch.Tensor:
    """Linear interpolation of ``values`` sampled at ``times`` onto ``grid``; grid times outside
    the samples' span take the first/last value.

    Args:
        times: strictly increasing sample times, shape ``(N,)``.
        values: samples, shape ``(N, ...)``.
        grid: query times, shape ``(T,)``.

    Returns:
        Shape ``(T, ...)``, in the dtype of ``values``.

    Example:
        >>> resample_linear(torch.tensor([0.0, 1.0, 3.0]), torch.tensor([[0.0], [2.0], [0.0]]),
        ...                 torch.tensor([-1.0, 0.5, 2.0, 4.0]))
        tensor([[0.],
                [1.],
                [1.],
                [0.]])
    """
    i, j, w = _brackets(times, grid)
    w = w.to(values.dtype).reshape(-1, *([1] * (values.ndim - 1)))
    return values[i] + w * (values[j] - values[i])


def resample_slerp(times: torch.Tensor, quats: torch.Tensor, grid: torch.Tensor) -> torch.Tensor:
    """Slerp of a quaternion trajectory onto ``grid`` after removing its sign flips.

    The samples are made hemisphere-continuous (``q_k -> -q_k`` when ``<q_k, q_{k-1}> < 0``),
    then each grid time is interpolated between the samples around it; outside the samples'
    span the first/last sample is held. The result keeps the sign of the first sample and is
    itself hemisphere-continuous.

    Args:
        times: strictly increasing sample times, shape ``(N,)``.
        quats: unit quaternions, shape ``(N, 4)``.
        grid: query times, shape ``(T,)``.

    Returns:
        Unit quaternions, shape ``(T, 4)``.

    Example:
        >>> h = math.sqrt(0.5)
        >>> q = torch.tensor([[0.0, 0, 0, 1], [0.0, 0, -h, -h]])  # 90 deg about z, stored as -q
        >>> resample_slerp(torch.tensor([0.0, 1.0]), q, torch.tensor([0.0, 0.5, 1.0]))
        tensor([[0.0000, 0.0000, 0.0000, 1.0000],
                [0.0000, 0.0000, 0.3827, 0.9239],
                [0.0000, 0.0000, 0.7071, 0.7071]])
    """
    quats = hemisphere_continuous(quats, dim=-2)
    i, j, w = _brackets(times, grid)
    out = slerp(quats[i], quats[j], w.to(quats.dtype))
    return hemisphere_continuous(out, dim=-2)


def nearest_indices(times: torch.Tensor, grid: torch.Tensor) -> torch.Tensor:
    """For each grid time, the index of the sample nearest in time (ties: the earlier sample).

    Args:
        times: increasing sample times, shape ``(N,)``, N >= 1.
        grid: query times, shape ``(T,)``.

    Returns:
        int64 indices into ``times``, shape ``(T,)``.

    Example:
        >>> nearest_indices(torch.tensor([0.0, 1.0, 2.0]), torch.tensor([-5.0, 0.4, 0.5, 1.6, 9.0]))
        tensor([0, 0, 0, 2, 2])
    """
    n = times.shape[0]
    if n == 0:
        raise ValueError("cannot pick from a stream without samples")
    hi = torch.searchsorted(times, grid).clamp(0, n - 1)
    lo = (hi - 1).clamp(min=0)
    take_lo = (grid - times[lo]).abs() <= (times[hi] - grid).abs()
    return torch.where(take_lo, lo, hi)


# --------------------------------------------------------------------------------------------
# Reading


@dataclass
class _Stream:
    """Everything pass 1 keeps of one topic: per message its time, index and value."""

    topic: str
    spec: TopicConfig | None  # None for the segment marker topic
    kind: str = ""
    msgtypes: list[str] = field(default_factory=list)
    count: int = 0  # messages read (the next message's index on the topic)
    skipped: int = 0
    stamps: list[int] = field(default_factory=list)
    ordinals: list[int] = field(default_factory=list)
    values: list[Any] = field(default_factory=list)
    joint_names: list[str] | None = None
    width: int | None = None  # vector length
    image_shape: tuple[int, int, int] | None = None

    def arrays(self) -> tuple[np.ndarray, np.ndarray]:
        return np.asarray(self.stamps, np.int64), np.asarray(self.ordinals, np.int64)


def _normalize_type(msgtype: str) -> str:
    parts = msgtype.split("/")
    return f"{parts[0]}/msg/{parts[1]}" if len(parts) == 2 else msgtype


def _corrupt(file: str, err: BaseException, topic: str | None = None) -> DataError:
    text = str(err).strip() or "(no details)"
    return DataError(
        f"cannot read the bag, it may be truncated or corrupt ({type(err).__name__}: {text})",
        file=file, topic=topic,
    )


def _is_bag(path: Path) -> bool:
    if path.is_file():
        return path.suffix in (".bag", ".db3", ".mcap")
    return path.is_dir() and (path / "metadata.yaml").exists()


def _expand(path: Path) -> list[Path]:
    """A folder that is no bag itself but holds bags (``.bag`` files, rosbag2 folders) -> them."""
    if path.is_dir() and not _is_bag(path):
        if any(p.suffix in (".db3", ".mcap") for p in path.iterdir()):
            return [path]  # a rosbag2 recording without metadata.yaml
        bags = sorted(
            p for p in path.iterdir() if p.suffix == ".bag" or (p.is_dir() and _is_bag(p))
        )
        if bags:
            return bags
    return [path]


def _resolve(path: Path) -> tuple[str, list[Path]]:
    """The bag's format and the paths to hand to ``AnyReader``."""
    file = str(path)
    if not path.exists():
        raise DataError("no such ROS bag (file or folder)", file=file)
    if path.is_file():
        if path.suffix == ".bag":
            return "ros1", [path]
        if path.suffix in (".db3", ".mcap"):
            return "ros2", [path]
    elif (path / "metadata.yaml").exists():
        return "ros2", [path]
    else:
        storage = sorted(p for p in path.iterdir() if p.suffix in (".db3", ".mcap"))
        if storage:
            return "ros2", storage
    raise DataError(
        "not a ROS bag: expected a .bag file (ROS 1), or a folder with metadata.yaml or "
        ".db3/.mcap files, or a .db3/.mcap file (ROS 2)",
        file=file,
    )


@contextmanager
def _open_bag(files: list[Path], fmt: str, file: str) -> Iterator[Any]:
    try:
        from rosbags.highlevel import AnyReader
        from rosbags.typesys import Stores, get_typestore
    except ImportError as err:  # pragma: no cover - depends on the environment
        raise ImportError("reading ROS bags needs rosbags: pip install rfmp_rl[data]") from err
    store = get_typestore(Stores.ROS1_NOETIC if fmt == "ros1" else Stores.ROS2_HUMBLE)
    try:
        reader = AnyReader(files, default_typestore=store)
        reader.open()
    except Exception as err:
        raise _corrupt(file, err) from err
    try:
        yield reader
    finally:
        with suppress(Exception):
            reader.close()


def _guarded(messages: Iterable[Any], file: str) -> Iterator[Any]:
    """Iterate over the reader's messages, turning its failures into `DataError`."""
    iterator = iter(messages)
    while True:
        try:
            item = next(iterator)
        except StopIteration:
            return
        except Exception as err:
            raise _corrupt(file, err) from err
        yield item


def _connections(reader: Any, cfg: RosbagConfig, file: str) -> list[Any]:
    """The connections of the configured topics; checks that each exists with a usable type."""
    wanted = list(cfg.topics) + ([cfg.segment_topic] if cfg.segment_topic else [])
    by_topic: dict[str, list[Any]] = {}
    for conn in reader.connections:
        by_topic.setdefault(conn.topic, []).append(conn)
    for topic in wanted:
        if topic not in by_topic:
            available = ", ".join(sorted(by_topic)) or "none"
            raise DataError(
                f"topic not in the bag; available topics: {available}", file=file, topic=topic
            )
        spec = cfg.topics.get(topic)
        for conn in by_topic[topic]:
            msgtype = _normalize_type(conn.msgtype)
            supported = _MARKER_TYPES if spec is None else tuple(_KINDS)
            if msgtype not in supported:
                role = "a segment marker" if spec is None else "a data topic"
                raise DataError(
                    f"unsupported message type {msgtype} for {role}; supported: "
                    f"{', '.join(supported)}",
                    file=file, topic=topic, key=None if spec is None else spec.key,
                )
            if spec is not None and (spec.field or spec.joints) and msgtype != _JOINT_STATE:
                raise DataError(
                    f"'field' and 'joints' apply to {_JOINT_STATE} only, not {msgtype}",
                    file=file, topic=topic, key=spec.key,
                )
    return [c for topic in wanted for c in by_topic[topic]]


def _stamp(msg: Any, recorded: int) -> int:
    header = getattr(msg, "header", None)
    if header is not None:
        ns = int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)
        if ns:
            return ns
    return recorded


def _vector(stream: _Stream, msg: Any, msgtype: str, index: int, file: str) -> np.ndarray | None:
    spec = stream.spec
    assert spec is not None
    if msgtype == _JOINT_STATE:
        name = spec.field or "position"
        values = np.asarray(getattr(msg, name), dtype=np.float64).reshape(-1)
        names = [str(n) for n in msg.name]
        if names and len(names) != values.size:
            raise DataError(
                f"JointState.{name} has {values.size} values for {len(names)} joint names",
                file=file, topic=stream.topic, key=spec.key, step=index,
            )
        if spec.joints is not None:
            if not set(spec.joints) <= set(names):
                return None  # another publisher's joints: skipped and counted
            values = values[[names.index(j) for j in spec.joints]]
        elif names:
            if stream.joint_names is None:
                stream.joint_names = names
            elif names != stream.joint_names:
                if sorted(names) != sorted(stream.joint_names) or len(set(names)) != len(names):
                    raise DataError(
                        f"joint names {names} differ from the first message's "
                        f"{stream.joint_names}; select joints with 'joints: [...]'",
                        file=file, topic=stream.topic, key=spec.key, step=index,
                    )
                values = values[[names.index(j) for j in stream.joint_names]]
    elif msgtype.endswith("MultiArray"):
        values = np.asarray(msg.data, dtype=np.float64).reshape(-1)
    else:  # Float32 / Float64
        values = np.array([float(msg.data)], dtype=np.float64)
    if values.size == 0:
        raise DataError("message holds no values", file=file, topic=stream.topic, key=spec.key,
                        step=index)
    if stream.width is None:
        stream.width = values.size
    elif values.size != stream.width:
        raise DataError(
            f"{values.size} values, but earlier messages have {stream.width}",
            file=file, topic=stream.topic, key=spec.key, step=index,
        )
    return values


def _pose(msg: Any, msgtype: str) -> np.ndarray:
    if msgtype.endswith("PoseStamped"):
        pos, rot = msg.pose.position, msg.pose.orientation
    elif msgtype.endswith("Pose"):
        pos, rot = msg.position, msg.orientation
    elif msgtype.endswith("TransformStamped"):
        pos, rot = msg.transform.translation, msg.transform.rotation
    else:  # Transform
        pos, rot = msg.translation, msg.rotation
    return np.array([pos.x, pos.y, pos.z, rot.x, rot.y, rot.z, rot.w], dtype=np.float64)


def _image_shape(stream: _Stream, msg: Any, index: int, file: str) -> tuple[int, int, int]:
    key = stream.spec.key if stream.spec else None
    encoding = str(msg.encoding)
    if encoding not in _IMAGE_CHANNELS:
        raise DataError(
            f"unsupported image encoding {encoding!r}; supported: {', '.join(_IMAGE_CHANNELS)}",
            file=file, topic=stream.topic, key=key, step=index,
        )
    h, w, c = int(msg.height), int(msg.width), _IMAGE_CHANNELS[encoding]
    if h == 0 or w == 0 or int(msg.step) < w * c or len(msg.data) < int(msg.step) * h:
        raise DataError(
            f"image {h}x{w} {encoding} with step {msg.step} does not fit its "
            f"{len(msg.data)} data bytes",
            file=file, topic=stream.topic, key=key, step=index,
        )
    return h, w, c


def _read_marker(stream: _Stream, msg: Any, msgtype: str, index: int, file: str) -> bool:
    if msgtype.endswith("Bool"):
        return bool(msg.data)
    text = str(msg.data).strip().lower()
    if text not in ("start", "end"):
        raise DataError(
            f"segment marker {msg.data!r} is neither 'start' nor 'end'",
            file=file, topic=stream.topic, step=index,
        )
    return text == "start"


def _pass1(reader: Any, cfg: RosbagConfig, file: str) -> dict[str, _Stream]:
    """Read every configured topic: times and values (for images: only their shapes)."""
    conns = _connections(reader, cfg, file)
    streams = {t: _Stream(topic=t, spec=s) for t, s in cfg.topics.items()}
    if cfg.segment_topic:
        streams[cfg.segment_topic] = _Stream(topic=cfg.segment_topic, spec=None, kind="marker")
    for conn, recorded, raw in _guarded(reader.messages(connections=conns), file):
        stream = streams[conn.topic]
        msgtype = _normalize_type(conn.msgtype)
        if msgtype not in stream.msgtypes:
            stream.msgtypes.append(msgtype)
        index = stream.count
        stream.count += 1
        try:
            msg = reader.deserialize(raw, conn.msgtype)
        except Exception as err:
            raise _corrupt(file, err, topic=conn.topic) from err
        if stream.spec is None:
            value: Any = _read_marker(stream, msg, msgtype, index, file)
        else:
            kind = _KINDS[msgtype]
            if stream.kind and kind != stream.kind:
                raise DataError(
                    f"message type {msgtype} cannot be mixed with {stream.msgtypes[0]}",
                    file=file, topic=stream.topic, key=stream.spec.key, step=index,
                )
            stream.kind = kind
            if kind == "vector":
                value = _vector(stream, msg, msgtype, index, file)
                if value is None:
                    stream.skipped += 1
                    continue
            elif kind == "pose":
                value = _pose(msg, msgtype)
            elif kind == "bool":
                value = bool(msg.data)
            elif kind == "image":
                shape = _image_shape(stream, msg, index, file)
                if stream.image_shape is not None and shape != stream.image_shape:
                    raise DataError(
                        f"image shape {shape} differs from earlier messages' "
                        f"{stream.image_shape}",
                        file=file, topic=stream.topic, key=stream.spec.key, step=index,
                    )
                stream.image_shape = shape
                value = None
            else:  # compressed
                if "compresseddepth" in str(msg.format).lower():
                    raise DataError(
                        f"unsupported compressed image format {msg.format!r} (depth)",
                        file=file, topic=stream.topic, key=stream.spec.key, step=index,
                    )
                value = None
        stream.stamps.append(_stamp(msg, recorded))
        stream.ordinals.append(index)
        stream.values.append(value)
    return streams


def _windows(marker: _Stream, file: str) -> list[tuple[int, int]]:
    """``[start, end]`` record times of the episodes the marker topic delimits."""
    windows: list[tuple[int, int]] = []
    start: tuple[int, int] | None = None
    for stamp, index, is_start in zip(marker.stamps, marker.ordinals, marker.values, strict=True):
        if is_start and start is None:
            start = (stamp, index)
        elif not is_start and start is not None:
            windows.append((start[0], stamp))
            start = None
    if start is not None:
        raise DataError(
            f"start marker (message {start[1]}) has no end marker before the bag ends",
            file=file, topic=marker.topic, step=start[1],
        )
    if not windows:
        raise DataError(
            f"no start/end marker pair among the topic's {marker.count} messages",
            file=file, topic=marker.topic,
        )
    return windows


def _seconds(ns: int | float) -> str:
    return f"{ns / 1e9:.3f} s"


@dataclass
class _Plan:
    """One episode before its images are decoded."""

    name: str
    arrays: dict[Any, torch.Tensor]
    frames: dict[str, np.ndarray]  # image topic -> message index per step
    span: tuple[int, int]


def _plan(
    streams: dict[str, _Stream],
    cfg: RosbagConfig,
    window: tuple[int, int] | None,
    rate: float,
    file: str,
    name: str,
) -> _Plan:
    data = {t: s for t, s in streams.items() if s.spec is not None}
    chosen: dict[str, np.ndarray] = {}  # topic -> positions in the stream's lists, by time
    stamps: dict[str, np.ndarray] = {}
    for topic, s in data.items():
        key = s.spec.key if s.spec else None
        st, ordinals = s.arrays()
        pos = np.arange(st.size) if window is None else np.flatnonzero(
            (st >= window[0]) & (st <= window[1])
        )
        if pos.size == 0:
            where = (
                "" if window is None
                else f" between the markers at {_seconds(window[0])} and {_seconds(window[1])}"
            )
            raise DataError(
                f"no messages{where} ({s.count} on the topic in the bag, {s.skipped} skipped)",
                file=file, topic=topic, key=key, episode=name,
            )
        if s.kind in ("vector", "pose"):
            values = np.stack([s.values[p] for p in pos])
            finite = np.isfinite(values).all(axis=1)
            if not finite.all():
                bad = int(np.argmin(finite))
                row = values[bad]
                raise DataError(
                    f"non-finite value {row[~np.isfinite(row)][0]} in message "
                    f"{ordinals[pos[bad]]} of the topic",
                    file=file, topic=topic, key=key, episode=name, step=int(ordinals[pos[bad]]),
                )
        pos = pos[np.argsort(st[pos], kind="stable")]
        keep = np.append(st[pos][1:] != st[pos][:-1], True)  # equal times: the last recorded
        chosen[topic], stamps[topic] = pos[keep], st[pos[keep]]

    if cfg.time_reference is not None:
        ref = next(t for t, s in data.items() if s.spec and s.spec.key == cfg.time_reference)
        t0, t1 = int(stamps[ref][0]), int(stamps[ref][-1])
        for topic, st in stamps.items():
            if st[-1] < t0 or st[0] > t1:
                raise DataError(
                    f"no time overlap: messages span {_seconds(st[0])} to {_seconds(st[-1])}, "
                    f"the time reference {ref} spans {_seconds(t0)} to {_seconds(t1)} "
                    "(empty episode)",
                    file=file, topic=topic, key=data[topic].spec.key, episode=name,
                )
    else:
        late = max(stamps, key=lambda t: stamps[t][0])
        early = min(stamps, key=lambda t: stamps[t][-1])
        t0, t1 = int(stamps[late][0]), int(stamps[early][-1])
        if t1 < t0:
            raise DataError(
                f"no time overlap: the first message is at {_seconds(t0)}, after the last "
                f"message of {early} at {_seconds(t1)} (empty episode)",
                file=file, topic=late, key=data[late].spec.key, episode=name,
            )

    steps = int(math.floor((t1 - t0) * rate / 1e9 + 1e-9)) + 1
    grid = torch.arange(steps, dtype=torch.float64) / rate
    arrays: dict[Any, torch.Tensor] = {}
    frames: dict[str, np.ndarray] = {}
    for topic, s in data.items():
        assert s.spec is not None
        pos = chosen[topic]
        times = torch.from_numpy((stamps[topic] - t0).astype(np.float64) / 1e9)
        key = s.spec.nested_key
        if s.kind == "vector":
            values = torch.from_numpy(np.stack([s.values[p] for p in pos]))
            arrays[key] = resample_linear(times, values, grid).to(torch.float32)
        elif s.kind == "pose":
            values = torch.from_numpy(np.stack([s.values[p] for p in pos]))
            quats = values[:, 3:]
            norms = quats.norm(dim=-1)
            bad = (norms - 1).abs() > 1e-2
            if bool(bad.any()):
                k = int(torch.argmax(bad.to(torch.int8)))
                index = s.ordinals[int(pos[k])]
                raise DataError(
                    f"orientation {quats[k].tolist()} in message {index} is not a unit "
                    "quaternion",
                    file=file, topic=topic, key=s.spec.key, episode=name, step=index,
                )
            quats = quats / norms[:, None]
            parts = key if isinstance(key, tuple) else (key,)
            arrays[(*parts, "position")] = resample_linear(times, values[:, :3], grid).to(
                torch.float32
            )
            arrays[(*parts, "orientation")] = resample_slerp(times, quats, grid).to(
                torch.float32
            )
        else:
            nearest = nearest_indices(times, grid).numpy()
            if s.kind == "bool":
                flags = np.array([s.values[p] for p in pos], dtype=bool)
                arrays[key] = torch.from_numpy(flags[nearest][:, None].copy())
            else:
                frames[topic] = np.asarray(s.ordinals, np.int64)[pos][nearest]
    span = (t0, t0 + round((steps - 1) * 1e9 / rate))
    return _Plan(name=name, arrays=arrays, frames=frames, span=span)


def _decode(stream: _Stream, msg: Any, index: int, file: str) -> np.ndarray:
    key = stream.spec.key if stream.spec else None
    if stream.kind == "image":
        h, w, c = stream.image_shape or _image_shape(stream, msg, index, file)
        step = int(msg.step)
        data = np.asarray(msg.data, dtype=np.uint8)[: step * h]
        image = data.reshape(h, step)[:, : w * c].reshape(h, w, c)
        if msg.encoding == "bgr8":
            image = image[..., ::-1]
        return np.ascontiguousarray(image)
    try:
        import cv2
    except ImportError as err:  # pragma: no cover - depends on the environment
        raise ImportError("decoding sensor_msgs/CompressedImage needs opencv-python") from err
    buffer = np.asarray(msg.data, dtype=np.uint8).reshape(-1)
    try:
        image = cv2.imdecode(buffer, cv2.IMREAD_UNCHANGED) if buffer.size else None
    except cv2.error:
        image = None
    if image is None:
        raise DataError(
            f"cannot decode compressed image (format {msg.format!r}, {buffer.size} bytes)",
            file=file, topic=stream.topic, key=key, step=index,
        )
    if image.dtype != np.uint8:
        raise DataError(
            f"unsupported compressed image depth {image.dtype} (format {msg.format!r}); "
            "8-bit images only",
            file=file, topic=stream.topic, key=key, step=index,
        )
    if image.ndim == 2:
        return image[:, :, None]
    if image.shape[2] == 1:
        return image
    return np.ascontiguousarray(image[:, :, 2::-1])  # BGR(A) -> RGB


def _pass2(
    reader: Any, cfg: RosbagConfig, streams: dict[str, _Stream], plans: list[_Plan], file: str
) -> None:
    """Decode the image frames the episodes use and add them to the plans."""
    needed: dict[str, set[int]] = {}
    for plan in plans:
        for topic, indices in plan.frames.items():
            needed.setdefault(topic, set()).update(int(i) for i in indices)
    if not needed:
        return
    decoded: dict[str, dict[int, np.ndarray]] = {t: {} for t in needed}
    counts = dict.fromkeys(streams, 0)
    # The same connections as pass 1, so every topic's messages come in the same order.
    conns = _connections(reader, cfg, file)
    for conn, _, raw in _guarded(reader.messages(connections=conns), file):
        index = counts[conn.topic]
        counts[conn.topic] += 1
        if index not in needed.get(conn.topic, ()):
            continue
        try:
            msg = reader.deserialize(raw, conn.msgtype)
        except Exception as err:
            raise _corrupt(file, err, topic=conn.topic) from err
        decoded[conn.topic][index] = _decode(streams[conn.topic], msg, index, file)
    for plan in plans:
        for topic, indices in plan.frames.items():
            spec = streams[topic].spec
            assert spec is not None
            images = [decoded[topic][int(i)] for i in indices]
            for i, image in zip(indices, images, strict=True):
                if image.shape != images[0].shape:
                    raise DataError(
                        f"image shape {image.shape} differs from {images[0].shape} earlier in "
                        "the episode",
                        file=file, topic=topic, key=spec.key, episode=plan.name, step=int(i),
                    )
            plan.arrays[spec.nested_key] = torch.from_numpy(np.stack(images))


def read_rosbags(
    paths: str | os.PathLike[str] | Sequence[str | os.PathLike[str]],
    config: RosbagConfig | Mapping[str, Any],
    *,
    rate_hz: float | None = None,
) -> tuple[list[TensorDict], Manifest]:
    """Read ROS 1 / ROS 2 bags into episodes resampled to one control rate.

    See the module docstring for the configuration, timing, resampling, keys and dtypes.

    Args:
        paths: one bag or a list of bags: ``.bag`` files (ROS 1), rosbag2 folders, or bare
            ``.db3`` / ``.mcap`` files. A folder that is not a bag but holds ``.bag`` files or
            rosbag2 folders stands for those bags, in name order.
        config: a `RosbagConfig` or the mapping to build one from.
        rate_hz: the control rate; overrides ``config.rate_hz``.

    Returns:
        The episodes (``TensorDict`` of batch ``[T]``), in bag order and, within a bag, in
        marker order; and the `rfmp_rl.data.episodes.Manifest` (format ``"ros1"`` or ``"ros2"``).

    Raises:
        DataError: a missing or unreadable bag, a missing topic, an unsupported message type or
            image encoding, NaN/inf values, an empty episode (see the module docstring).
        ValueError: an invalid configuration or no rate.

    Example:
        >>> config = {"rate_hz": 10, "topics": {"/joint_states": {"key": "joints"}}}
        >>> read_rosbags("missing.bag", config)
        Traceback (most recent call last):
        ...
        rfmp_rl.data.episodes.DataError: missing.bag: no such ROS bag (file or folder)
    """
    cfg = config if isinstance(config, RosbagConfig) else RosbagConfig.from_dict(config)
    rate = rate_hz if rate_hz is not None else cfg.rate_hz
    if rate is None or not (math.isfinite(float(rate)) and float(rate) > 0):
        raise ValueError(f"read_rosbags needs a positive rate_hz (config or argument), got {rate}")
    rate = float(rate)
    if isinstance(paths, str | os.PathLike):
        paths = [paths]
    bags = [bag for p in paths for bag in _expand(Path(p))]
    if not bags:
        raise ValueError("read_rosbags: no bag paths given")
    resolved = [(bag, *_resolve(bag)) for bag in bags]  # every path checked before reading
    formats = sorted({fmt for _, fmt, _ in resolved})
    if len(bags) == 1:
        source = str(bags[0])
    else:
        try:
            source = os.path.commonpath([str(b.absolute()) for b in bags])
        except ValueError:
            source = str(bags[0].absolute().parent)
    topics: dict[str, dict[str, Any]] = {
        t: {"key": s.key, "msgtypes": [], "messages": 0} for t, s in cfg.topics.items()
    }
    if cfg.segment_topic:
        topics[cfg.segment_topic] = {"key": None, "msgtypes": [], "messages": 0}
    manifest = Manifest(
        source=source,
        format="+".join(formats),
        rate_hz=rate,
        extra={"files": [str(b) for b in bags], "config": cfg.to_dict(), "topics": topics,
               "episode_spans_ns": []},
    )
    episodes: list[TensorDict] = []
    for bag, fmt, files in resolved:
        file = str(bag)
        with _open_bag(files, fmt, file) as reader:
            streams = _pass1(reader, cfg, file)
            if cfg.segment_topic:
                windows: list[tuple[int, int] | None] = list(
                    _windows(streams[cfg.segment_topic], file)
                )
            else:
                windows = [None]
            plans = [
                _plan(streams, cfg, window, rate, file,
                      bag.name if window is None else f"{bag.name}#{i}")
                for i, window in enumerate(windows)
            ]
            _pass2(reader, cfg, streams, plans, file)
        for topic, stream in streams.items():
            info = topics[topic]
            info["messages"] += stream.count
            info["msgtypes"] += [m for m in stream.msgtypes if m not in info["msgtypes"]]
            if stream.spec is not None and stream.spec.joints is not None:
                info["skipped"] = info.get("skipped", 0) + stream.skipped
        for plan in plans:
            episode = make_episode(plan.arrays, file=file, episode=plan.name)
            manifest.add(episode, plan.name)
            manifest.extra["episode_spans_ns"].append(list(plan.span))
            episodes.append(episode)
    return episodes, manifest
