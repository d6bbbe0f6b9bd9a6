"""Reading ROS 1 / ROS 2 bags into episodes (`read_rosbags`; the behaviour is described in
`rfmp_rl.data.ros`)."""

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
from rfmp_rl.data.quaternions import QuaternionField, canonicalize_episode_quaternions
from rfmp_rl.data.ros.config import TIMESTAMP, RosbagConfig, TopicConfig
from rfmp_rl.data.ros.resample import nearest_indices, resample_linear, resample_slerp
from rfmp_rl.manifolds import Euclidean, Product, Sphere, parse_manifold

__all__ = ["read_rosbags"]

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
_IMAGE_CHANNELS = {"rgb8": 3, "bgr8": 3, "mono8": 1}



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


def _unfinished(path: Path) -> str | None:
    """Why ``path`` is a recording whose recorder stopped before closing it, or None."""
    if path.is_file() and path.name.endswith(".bag.active"):
        return ("an unfinished ROS 1 recording (.bag.active): run `rosbag reindex` on it and "
                "rename it to .bag, or move it out of the folder")
    if path.is_dir() and not (path / "metadata.yaml").exists() and any(
            p.suffix in (".db3", ".mcap") for p in path.iterdir()):
        return ("a rosbag2 folder without metadata.yaml (an unfinished recording): run "
                "`ros2 bag reindex` on the folder, or move it out of the folder")
    return None


def _expand(path: Path) -> list[Path]:
    """A folder that is no bag itself but holds bags -> them, in name order: ``.bag`` files,
    rosbag2 folders (with ``metadata.yaml``) and bare ``.db3`` / ``.mcap`` files, one bag each,
    and the unfinished recordings among them (see `_unfinished`; never read)."""
    if path.is_dir() and not _is_bag(path):
        bags = sorted(p for p in path.iterdir() if _is_bag(p) or _unfinished(p))
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
    raise DataError(
        "not a ROS bag: expected a .bag file (ROS 1), a rosbag2 folder with metadata.yaml or a "
        ".db3/.mcap file (ROS 2), or a folder holding such bags",
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
    options = cfg.read_options()
    in_vectors = {p.topic: key for key, parts in cfg.vectors.items() for p in parts}
    wanted = list(options) + ([cfg.segment_topic] if cfg.segment_topic else [])
    by_topic: dict[str, list[Any]] = {}
    for conn in reader.connections:
        by_topic.setdefault(conn.topic, []).append(conn)
    for topic in wanted:
        if topic not in by_topic:
            available = ", ".join(sorted(by_topic)) or "none"
            raise DataError(
                f"topic not in the bag; available topics: {available}", file=file, topic=topic
            )
        spec = options.get(topic)
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
            if topic in in_vectors and _KINDS[msgtype] in ("image", "compressed"):
                raise DataError(
                    f"an image ({msgtype}) cannot be part of the flat vector "
                    f"{in_vectors[topic]}; map it to a key under topics",
                    file=file, topic=topic, key=in_vectors[topic],
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
    streams = {t: _Stream(topic=t, spec=s) for t, s in cfg.read_options().items()}
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


#: Per data topic: the positions (in the stream's lists) of the messages an episode uses,
#: ordered by time with one message per time, and their times in nanoseconds.
_Selection = dict[str, tuple[np.ndarray, np.ndarray]]


def _select(
    streams: dict[str, _Stream], window: tuple[int, int] | None, file: str, name: str
) -> _Selection:
    selection: _Selection = {}
    for topic, s in streams.items():
        if s.spec is None:
            continue
        key = s.spec.key
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
        selection[topic] = (pos[keep], st[pos[keep]])
    return selection


def _reference_topics(cfg: RosbagConfig) -> list[str]:
    ref = cfg.time_reference
    if ref in cfg.vectors:
        return [p.topic for p in cfg.vectors[ref]]
    return [t for t, c in cfg.topics.items() if c.key == ref]


def _bounds(
    selection: _Selection, streams: dict[str, _Stream], cfg: RosbagConfig, file: str, name: str
) -> tuple[int, int]:
    """The episode's first and last grid time (ns): the time reference's span, or the overlap
    of all streams; `DataError` when it is empty."""
    stamps = {t: st for t, (_, st) in selection.items()}
    if cfg.time_reference is not None:
        refs = _reference_topics(cfg)
        t0 = max(int(stamps[t][0]) for t in refs)
        t1 = min(int(stamps[t][-1]) for t in refs)
        ref = ", ".join(refs)
        for topic, st in stamps.items():
            if st[-1] < t0 or st[0] > t1:
                raise DataError(
                    f"no time overlap: messages span {_seconds(st[0])} to {_seconds(st[-1])}, "
                    f"the time reference {ref} spans {_seconds(t0)} to {_seconds(t1)} "
                    "(empty episode)",
                    file=file, topic=topic, key=streams[topic].spec.key, episode=name,
                )
        return t0, t1
    late = max(stamps, key=lambda t: stamps[t][0])
    early = min(stamps, key=lambda t: stamps[t][-1])
    t0, t1 = int(stamps[late][0]), int(stamps[early][-1])
    if t1 < t0:
        raise DataError(
            f"no time overlap: the first message is at {_seconds(t0)}, after the last "
            f"message of {early} at {_seconds(t1)} (empty episode)",
            file=file, topic=late, key=streams[late].spec.key, episode=name,
        )
    return t0, t1


@dataclass(frozen=True)
class _Gap:
    topic: str
    start: int  # ns
    end: int  # ns
    kind: str  # "gap", "late start", "early end"


def _find_gaps(
    selection: _Selection, span: tuple[int, int], limit_ns: int
) -> list[_Gap]:
    """Every stretch of ``span`` longer than ``limit_ns`` in which a stream has no message."""
    a, b = span
    gaps: list[_Gap] = []
    for topic, (_, st) in selection.items():
        lo = np.concatenate([[a], st]).astype(np.int64)
        hi = np.concatenate([st, [b]]).astype(np.int64)
        start, end = np.maximum(lo, a), np.minimum(hi, b)
        for i in np.flatnonzero(end - start > limit_ns):
            kind = "late start" if i == 0 else "early end" if i == st.size else "gap"
            gaps.append(_Gap(topic, int(start[i]), int(end[i]), kind))
    return sorted(gaps, key=lambda g: (g.start, g.topic))


def _pieces(span: tuple[int, int], gaps: list[_Gap]) -> list[tuple[int, int]]:
    """The parts of ``span`` outside every gap (a gap's ends are messages, so they belong to the
    parts around it)."""
    pieces, cursor = [], span[0]
    for gap in gaps:
        if gap.start > cursor:
            pieces.append((cursor, gap.start))
        cursor = max(cursor, gap.end)
    if span[1] > cursor:
        pieces.append((cursor, span[1]))
    return pieces


def _gap_entry(gap: _Gap, origin: int, file: str, name: str) -> dict[str, Any]:
    return {
        "file": file, "episode": name, "topic": gap.topic, "kind": gap.kind,
        "start_s": round((gap.start - origin) / 1e9, 6),
        "end_s": round((gap.end - origin) / 1e9, 6),
        "length_s": round((gap.end - gap.start) / 1e9, 6),
    }


def _gap_error(
    gaps: list[_Gap], origin: int, limit: float, streams: dict[str, _Stream], file: str,
    name: str,
) -> DataError:
    gap = gaps[0]
    what = {"gap": "gap", "late start": "the stream starts late",
            "early end": "the stream ends early"}[gap.kind]
    more = f"; {len(gaps) - 1} more gap(s) in this episode" if len(gaps) > 1 else ""
    return DataError(
        f"{what}: no message for {(gap.end - gap.start) / 1e9:.3f} s, from "
        f"{(gap.start - origin) / 1e9:.3f} s to {(gap.end - origin) / 1e9:.3f} s into the "
        f"recording (stamps {_seconds(gap.start)} to {_seconds(gap.end)}), longer than "
        f"max_gap_s = {limit:g} s{more}. Set on_gap: split to cut the episode at gaps, or raise "
        "max_gap_s",
        file=file, topic=gap.topic, key=streams[gap.topic].spec.key, episode=name,
    )


def _layout(kind: str, width: int | None) -> list[tuple[str, int]]:
    """A stream's share of a flat vector as ``(factor, coordinates)`` pieces."""
    if kind == "pose":
        return [("R", 3), ("S", 4)]
    return [("R", 1 if kind == "bool" else int(width or 0))]


def _merged(layout: Sequence[tuple[str, int]]) -> list[tuple[str, int]]:
    out: list[tuple[str, int]] = []
    for factor, n in layout:
        if out and factor == "R" and out[-1][0] == "R":
            out[-1] = ("R", out[-1][1] + n)
        else:
            out.append((factor, n))
    return out


def _layout_text(layout: Sequence[tuple[str, int]]) -> str:
    return " x ".join(f"{f}{n if f == 'R' else n - 1}" for f, n in _merged(layout))


def _vector_layouts(
    streams: dict[str, _Stream], cfg: RosbagConfig, file: str
) -> dict[str, list[dict[str, Any]]]:
    """Each flat vector's columns per topic; checks them against the declared manifolds."""
    out: dict[str, list[dict[str, Any]]] = {}
    for key, parts in cfg.vectors.items():
        columns, start, layout = [], 0, []
        for part in parts:
            s = streams[part.topic]
            share = _layout(s.kind, s.width)
            size = sum(n for _, n in share)
            columns.append({"topic": part.topic, "kind": s.kind, "start": start, "size": size})
            start += size
            layout += share
        spec = cfg.manifolds.get(key)
        if spec is not None:
            manifold = parse_manifold(spec)
            factors = manifold.components if isinstance(manifold, Product) else [manifold]
            expected = [("R", c.dim) if isinstance(c, Euclidean) else ("S", c.dim)
                        for c in factors if isinstance(c, Euclidean | Sphere)]
            if _merged(expected) != _merged(layout):
                shares = ", ".join(
                    f"{p.topic}: "
                    f"{_layout_text(_layout(streams[p.topic].kind, streams[p.topic].width))}"
                    for p in parts
                )
                raise DataError(
                    f"the topics give the flat layout {_layout_text(layout)} ({shares}), which "
                    f"does not match {key}_manifold {spec!r}; orientations are S3 (xyzw), "
                    "every other value is R",
                    file=file, key=key,
                )
        out[key] = columns
    return out


def _nested(key: str) -> str | tuple[str, ...]:
    parts = tuple(key.split("/"))
    return parts[0] if len(parts) == 1 else parts


def _resample(
    streams: dict[str, _Stream],
    selection: _Selection,
    cfg: RosbagConfig,
    bounds: tuple[int, int],
    rate: float,
    file: str,
    name: str,
) -> _Plan:
    t0, t1 = bounds
    steps = int(math.floor((t1 - t0) * rate / 1e9 + 1e-9)) + 1
    grid = torch.arange(steps, dtype=torch.float64) / rate
    values: dict[str, torch.Tensor] = {}  # topic -> (T, D) float64, or bool (T, 1)
    frames: dict[str, np.ndarray] = {}
    for topic, (pos, stamps) in selection.items():
        s = streams[topic]
        assert s.spec is not None
        times = torch.from_numpy((stamps - t0).astype(np.float64) / 1e9)
        if s.kind == "vector":
            values[topic] = resample_linear(times, torch.from_numpy(np.stack(
                [s.values[p] for p in pos])), grid)
        elif s.kind == "pose":
            raw = torch.from_numpy(np.stack([s.values[p] for p in pos]))
            quats = raw[:, 3:]
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
            # continuous here (slerp needs it); w >= 0 at the first step in read_rosbags
            quats = resample_slerp(times, quats / norms[:, None], grid)
            values[topic] = torch.cat([resample_linear(times, raw[:, :3], grid), quats], dim=-1)
        else:
            nearest = nearest_indices(times, grid).numpy()
            if s.kind == "bool":
                flags = np.array([s.values[p] for p in pos], dtype=bool)
                values[topic] = torch.from_numpy(flags[nearest][:, None].copy())
            else:
                frames[topic] = np.asarray(s.ordinals, np.int64)[pos][nearest]
    arrays: dict[Any, torch.Tensor] = {TIMESTAMP: grid}
    for topic, spec in cfg.topics.items():
        if topic in frames:
            continue
        key = spec.nested_key
        if streams[topic].kind == "pose":
            parts = key if isinstance(key, tuple) else (key,)
            arrays[(*parts, "position")] = values[topic][:, :3].to(torch.float32)
            arrays[(*parts, "orientation")] = values[topic][:, 3:].to(torch.float32)
        elif streams[topic].kind == "bool":
            arrays[key] = values[topic]
        else:
            arrays[key] = values[topic].to(torch.float32)
    for key, parts in cfg.vectors.items():
        columns = [values[p.topic].to(torch.float64) for p in parts]
        arrays[_nested(key)] = torch.cat(columns, dim=-1).to(torch.float32)
    span = (t0, t0 + round((steps - 1) * 1e9 / rate))
    return _Plan(name=name, arrays=arrays, frames=frames, span=span)


def _plans(
    streams: dict[str, _Stream],
    cfg: RosbagConfig,
    window: tuple[int, int] | None,
    rate: float,
    file: str,
    name: str,
    manifest: Manifest,
) -> list[_Plan]:
    """One marker window (or the whole bag) -> its episode, or its parts between gaps."""
    selection = _select(streams, window, file, name)
    bounds = _bounds(selection, streams, cfg, file, name)
    if cfg.time_reference is not None:
        span = bounds
    else:
        span = (min(int(st[0]) for _, st in selection.values()),
                max(int(st[-1]) for _, st in selection.values()))
    limit = cfg.gap_limit_s(rate)
    gaps = _find_gaps(selection, span, round(limit * 1e9))
    if not gaps:
        return [_resample(streams, selection, cfg, bounds, rate, file, name)]
    if cfg.on_gap == "error":
        raise _gap_error(gaps, span[0], limit, streams, file, name)
    manifest.gaps += [_gap_entry(g, span[0], file, name) for g in gaps]
    plans = []
    for k, (a, b) in enumerate(_pieces(span, gaps)):
        part = f"{name}~{k}"
        piece = {t: (pos[(st >= a) & (st <= b)], st[(st >= a) & (st <= b)])
                 for t, (pos, st) in selection.items()}
        empty = [t for t, (pos, _) in piece.items() if pos.size == 0]
        try:
            if empty:
                raise DataError(f"no messages of {', '.join(empty)} in this part")
            bounds = _bounds(piece, streams, cfg, file, part)
        except DataError as err:  # a sliver between two gaps: listed, not returned
            manifest.skipped.append({
                "file": file, "episode": part,
                "reason": f"{(a - span[0]) / 1e9:.3f} s to {(b - span[0]) / 1e9:.3f} s between "
                          f"gaps, too short for an episode ({err})",
            })
            continue
        plans.append(_resample(streams, piece, cfg, bounds, rate, file, part))
    return plans


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


def _read_bag(
    bag: Path, fmt: str, files: list[Path], cfg: RosbagConfig, rate: float, manifest: Manifest
) -> tuple[dict[str, _Stream], list[_Plan], dict[str, list[dict[str, Any]]]]:
    """One bag -> its streams, its episode plans (images decoded) and its vectors' columns."""
    file = str(bag)
    with _open_bag(files, fmt, file) as reader:
        streams = _pass1(reader, cfg, file)
        layouts = _vector_layouts(streams, cfg, file)
        if cfg.segment_topic:
            windows: list[tuple[int, int] | None] = list(
                _windows(streams[cfg.segment_topic], file)
            )
        else:
            windows = [None]
        plans = [
            plan
            for i, window in enumerate(windows)
            for plan in _plans(streams, cfg, window, rate, file,
                               bag.name if window is None else f"{bag.name}#{i}", manifest)
        ]
        _pass2(reader, cfg, streams, plans, file)
    return streams, plans, layouts


def read_rosbags(
    paths: str | os.PathLike[str] | Sequence[str | os.PathLike[str]],
    config: RosbagConfig | Mapping[str, Any],
    *,
    rate_hz: float | None = None,
    skip_bad: bool = False,
    raw_quaternion_signs: bool = False,
) -> tuple[list[TensorDict], Manifest]:
    """Read ROS 1 / ROS 2 bags into episodes resampled to one control rate.

    See the `rfmp_rl.data.ros` docstring for the configuration, timing, gaps, resampling, keys
    and dtypes.

    Args:
        paths: one bag or a list of bags: ``.bag`` files (ROS 1), rosbag2 folders (with
            ``metadata.yaml``), or bare ``.db3`` / ``.mcap`` files. A folder that is not a bag
            but holds bags of these kinds stands for them, in name order, one bag each.
            Unfinished recordings given or found there (a ``.bag.active`` file, a subfolder
            with ``.db3`` / ``.mcap`` files but no ``metadata.yaml``) are not read: `DataError`
            suggesting ``rosbag reindex`` / ``ros2 bag reindex``, or with ``skip_bad`` an entry
            in ``manifest.skipped``.
        config: a `RosbagConfig` or the mapping to build one from.
        rate_hz: the control rate; overrides ``config.rate_hz``.
        skip_bad: skip a bag that raises `DataError` (corrupt, a missing topic, a gap with
            ``on_gap: error``, ...) and list it in ``manifest.skipped`` instead of raising.
        raw_quaternion_signs: keep each episode's orientations in the hemisphere of its first
            recorded sample instead of ``w >= 0`` (`rfmp_rl.data.quaternions`); the samples
            are still made continuous before slerp, which needs it.

    Returns:
        The episodes (``TensorDict`` of batch ``[T]``), in bag order and, within a bag, in
        marker and time order; and the `rfmp_rl.data.episodes.Manifest` (format ``"ros1"`` or
        ``"ros2"``), with ``gaps`` and ``skipped`` filled in.

    Raises:
        DataError: a missing or unreadable bag, a missing topic, an unsupported message type or
            image encoding, NaN/inf values, an empty episode, a gap (see `rfmp_rl.data.ros`);
            with ``skip_bad`` only when no bag could be read.
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
        raise ValueError(f"no control rate: set rate_hz in the topic config (a positive number "
                         f"of Hz; read_rosbags also takes rate_hz=), got {rate}")
    rate = float(rate)
    if isinstance(paths, str | os.PathLike):
        paths = [paths]
    bags = [bag for p in paths for bag in _expand(Path(p))]
    if not bags:
        raise ValueError("read_rosbags: no bag paths given")
    unfinished = [(bag, reason) for bag in bags if (reason := _unfinished(bag))]
    if unfinished and not skip_bad:
        (first, reason), *more = unfinished
        raise DataError(reason + "".join(f"; also {b}: {r}" for b, r in more), file=str(first))
    bags = [bag for bag in bags if not _unfinished(bag)]
    if not bags:
        listed = "; ".join(f"{b}: {r}" for b, r in unfinished)
        raise DataError(f"no readable bag: {listed}", file=str(unfinished[0][0]))
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
        t: {"key": s.key, "msgtypes": [], "messages": 0} for t, s in cfg.read_options().items()
    }
    if cfg.segment_topic:
        topics[cfg.segment_topic] = {"key": None, "msgtypes": [], "messages": 0}
    manifest = Manifest(
        source=source,
        format="+".join(formats),
        rate_hz=rate,
        extra={"files": [str(b) for b in bags], "config": cfg.to_dict(), "topics": topics,
               "max_gap_s": cfg.gap_limit_s(rate), "episode_spans_ns": []},
    )
    if cfg.vectors:
        manifest.extra["vectors"] = {}
    manifest.skipped += [{"file": str(b), "reason": r} for b, r in unfinished]
    episodes: list[TensorDict] = []
    for bag, fmt, files in resolved:
        file = str(bag)
        # A bag's gaps and episodes enter the manifest only once the whole bag is read.
        trial = Manifest(source=source, format=manifest.format, keys=dict(manifest.keys))
        try:
            streams, plans, layouts = _read_bag(bag, fmt, files, cfg, rate, trial)
            if not plans:
                raise DataError("no episode left between the gaps", file=file)
            built = []
            for plan in plans:
                episode = make_episode(plan.arrays, file=file, episode=plan.name)
                trial.add(episode, plan.name)
                built.append((plan, episode))
        except DataError as err:
            if not skip_bad:
                raise
            manifest.skipped.append({"file": file, "reason": str(err)})
            continue
        manifest.gaps += trial.gaps
        manifest.skipped += trial.skipped
        for key, columns in layouts.items():
            manifest.extra["vectors"].setdefault(key, columns)
        for topic, stream in streams.items():
            info = topics[topic]
            info["messages"] += stream.count
            info["msgtypes"] += [m for m in stream.msgtypes if m not in info["msgtypes"]]
            if stream.spec is not None and stream.spec.joints is not None:
                info["skipped"] = info.get("skipped", 0) + stream.skipped
        for plan, episode in built:
            manifest.add(episode, plan.name)
            manifest.extra["episode_spans_ns"].append(list(plan.span))
            episodes.append(episode)
    if not episodes:
        listed = "; ".join(f"{s['file']}: {s['reason']}" for s in manifest.skipped)
        raise DataError(f"no readable bag among {len(bags)}: {listed}", file=source)
    canonicalize_episode_quaternions(episodes, manifest, _quaternion_fields(cfg, manifest),
                                     raw=raw_quaternion_signs)
    return episodes, manifest


def _quaternion_fields(cfg: RosbagConfig, manifest: Manifest) -> list[QuaternionField]:
    """Pose orientations (xyzw): ``<key>/orientation`` and the S3 columns of flat vectors."""
    fields = [QuaternionField(f"{spec.key}/orientation") for spec in cfg.topics.values()
              if f"{spec.key}/orientation" in manifest.keys]
    for key, columns in manifest.extra.get("vectors", {}).items():
        fields += [QuaternionField(key, (c["start"] + 3, c["start"] + 7)) for c in columns
                   if c["kind"] == "pose"]
    return fields
