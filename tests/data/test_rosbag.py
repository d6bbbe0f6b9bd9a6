"""ROS bag reader: ROS 2 sqlite3 / mcap and ROS 1 fixtures written with rosbags' own writers."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch

pytest.importorskip("rosbags", reason="ROS bag tests need rosbags==0.11.9 (rfmp_rl[data])")
cv2 = pytest.importorskip("cv2", reason="compressed-image tests need opencv-python")

from rosbags.rosbag1 import Writer as Writer1  # noqa: E402
from rosbags.rosbag2 import StoragePlugin  # noqa: E402
from rosbags.rosbag2 import Writer as Writer2  # noqa: E402
from rosbags.typesys import Stores, get_typestore  # noqa: E402

from rfmp_rl.data.episodes import DataError  # noqa: E402
from rfmp_rl.data.rosbag import (  # noqa: E402
    CONFIG_FIELDS,
    RosbagConfig,
    TopicConfig,
    load_rosbag_config,
    nearest_indices,
    read_rosbags,
    resample_linear,
    resample_slerp,
    slerp,
)
from rfmp_rl.manifolds.quaternion import hemisphere_continuous  # noqa: E402

FORMATS = ["sqlite3", "mcap", "ros1"]
T0 = 1_700_000_000 * 10**9  # an epoch-sized base time, to exercise nanosecond precision
SEC = 10**9
AXIS = np.array([1.0, 2.0, 2.0]) / 3.0


# --------------------------------------------------------------------------------------------
# Writing bags


@dataclass
class Bag:
    """Messages to write: (topic, msgtype, record time ns, message)."""

    fmt: str
    messages: list[tuple[str, str, int, Any]] = field(default_factory=list)
    empty_topics: list[tuple[str, str]] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.store = get_typestore(Stores.ROS1_NOETIC if self.fmt == "ros1" else Stores.ROS2_HUMBLE)
        self.types = self.store.types

    def msg(self, msgtype: str, **kw: Any) -> Any:
        return self.types[msgtype](**kw)

    def header(self, stamp_ns: int) -> Any:
        time = self.msg("builtin_interfaces/msg/Time", sec=stamp_ns // SEC, nanosec=stamp_ns % SEC)
        if self.fmt == "ros1":
            return self.msg("std_msgs/msg/Header", seq=0, stamp=time, frame_id="world")
        return self.msg("std_msgs/msg/Header", stamp=time, frame_id="world")

    def add(self, topic: str, msgtype: str, recorded: int, msg: Any) -> None:
        self.messages.append((topic, msgtype, recorded, msg))

    def write(self, path: Path) -> Path:
        if self.fmt == "ros1":
            path = path.with_suffix(".bag")
            writer: Any = Writer1(path)
            serialize = self.store.serialize_ros1
        else:
            plugin = StoragePlugin.MCAP if self.fmt == "mcap" else StoragePlugin.SQLITE3
            writer = Writer2(path, version=9, storage_plugin=plugin)
            serialize = self.store.serialize_cdr
        with writer:
            conns = {}
            for topic, msgtype, _, _ in self.messages:
                if topic not in conns:
                    conns[topic] = writer.add_connection(topic, msgtype, typestore=self.store)
            for topic, msgtype in self.empty_topics:
                writer.add_connection(topic, msgtype, typestore=self.store)
            for topic, msgtype, recorded, msg in sorted(self.messages, key=lambda m: m[2]):
                writer.write(conns[topic], recorded, serialize(msg, msgtype))
        return path

    # message helpers -------------------------------------------------------------------------

    def pose(self, topic: str, stamp: int, recorded: int, pos: Any, quat: Any) -> None:
        point = self.msg("geometry_msgs/msg/Point", x=pos[0], y=pos[1], z=pos[2])
        q = self.msg("geometry_msgs/msg/Quaternion", x=quat[0], y=quat[1], z=quat[2], w=quat[3])
        pose = self.msg("geometry_msgs/msg/Pose", position=point, orientation=q)
        msg = self.msg("geometry_msgs/msg/PoseStamped", header=self.header(stamp), pose=pose)
        self.add(topic, "geometry_msgs/msg/PoseStamped", recorded, msg)

    def joints(self, topic: str, stamp: int, recorded: int, names: list[str], pos: Any) -> None:
        pos = np.asarray(pos, dtype=np.float64)
        msg = self.msg(
            "sensor_msgs/msg/JointState", header=self.header(stamp), name=list(names),
            position=pos, velocity=-pos, effort=np.zeros(0),
        )
        self.add(topic, "sensor_msgs/msg/JointState", recorded, msg)

    def scalar(self, topic: str, recorded: int, value: float, msgtype: str = "Float32") -> None:
        cast = np.float32 if msgtype == "Float32" else np.float64
        self.add(topic, f"std_msgs/msg/{msgtype}", recorded,
                 self.msg(f"std_msgs/msg/{msgtype}", data=cast(value)))

    def flag(self, topic: str, recorded: int, value: bool) -> None:
        self.add(topic, "std_msgs/msg/Bool", recorded, self.msg("std_msgs/msg/Bool", data=value))

    def text(self, topic: str, recorded: int, value: str) -> None:
        msg = self.msg("std_msgs/msg/String", data=value)
        self.add(topic, "std_msgs/msg/String", recorded, msg)

    def image(self, topic: str, stamp: int, recorded: int, rgb: np.ndarray,
              encoding: str = "rgb8") -> None:
        h, w, c = rgb.shape
        msg = self.msg(
            "sensor_msgs/msg/Image", header=self.header(stamp), height=h, width=w,
            encoding=encoding, is_bigendian=0, step=w * c,
            data=np.ascontiguousarray(rgb, dtype=np.uint8).reshape(-1),
        )
        self.add(topic, "sensor_msgs/msg/Image", recorded, msg)

    def compressed(self, topic: str, stamp: int, recorded: int, data: bytes,
                   fmt: str = "png") -> None:
        msg = self.msg(
            "sensor_msgs/msg/CompressedImage", header=self.header(stamp), format=fmt,
            data=np.frombuffer(data, dtype=np.uint8).copy(),
        )
        self.add(topic, "sensor_msgs/msg/CompressedImage", recorded, msg)


# --------------------------------------------------------------------------------------------
# The analytic recording


def position(t: float) -> np.ndarray:
    return np.array([0.1 + 0.2 * t, -0.3 * t, 0.5])


def rotation(t: float) -> np.ndarray:
    """A rotation about a fixed axis at constant rate: a geodesic on S^3, which slerp follows."""
    half = 0.5 * (0.4 + 1.2 * t)
    return np.array([*(AXIS * math.sin(half)), math.cos(half)])


def joint_values(t: float) -> np.ndarray:
    return np.array([1.0 + 0.5 * t, -2.0 * t, 0.25 + 0.1 * t])


def gripper(t: float) -> float:
    return 0.5 - 0.25 * t


def rgb_frame(k: int) -> np.ndarray:
    return ((np.arange(4 * 6 * 3).reshape(4, 6, 3) + 11 * k) % 256).astype(np.uint8)


def wrist_frame(k: int) -> np.ndarray:
    return ((np.arange(5 * 3 * 3).reshape(5, 3, 3) * 3 + 17 * k) % 256).astype(np.uint8)


def png(rgb: np.ndarray) -> bytes:
    ok, buf = cv2.imencode(".png", rgb[:, :, ::-1])
    assert ok
    return buf.tobytes()


def grid_times(start: float, rate: float, count: int) -> np.ndarray:
    """``count`` times ``start + k / rate`` seconds, rounded to whole nanoseconds."""
    return np.round((start + np.arange(count) / rate) * SEC) / SEC


@dataclass
class Streams:
    """Per topic: the (stamp) times in seconds after T0 its messages carry."""

    times: dict[str, np.ndarray] = field(default_factory=dict)


def record(bag: Bag, start: float = 0.0, stop: float = 2.0) -> Streams:
    """The test recording between ``start`` and ``stop`` seconds (relative to T0)."""
    out = Streams()

    def ns(t: float) -> int:
        return T0 + round(t * SEC)

    # PoseStamped at ~50 Hz with jittered header stamps, recorded 2 ms late; the quaternion's
    # sign flips for the second half of the recording.
    k = np.arange(int((stop - start) * 50) + 1)
    t_pose = start + 0.02 * k + 0.003 * np.sin(k)
    t_pose = np.round(t_pose * SEC) / SEC  # whole nanoseconds, as stored
    for i, t in enumerate(t_pose):
        sign = -1.0 if i >= len(t_pose) // 2 else 1.0
        bag.pose("/robot/ee_pose", ns(t), ns(t) + 2_000_000, position(t), sign * rotation(t))
    out.times["/robot/ee_pose"] = t_pose
    # JointState at 30 Hz, header-stamped, recorded 5 ms late.
    t_joint = grid_times(start + 0.03, 30, int((stop - start - 0.03) * 30) + 1)
    for t in t_joint:
        bag.joints("/joint_states", ns(t), ns(t) + 5_000_000, ["j1", "j2", "j3"], joint_values(t))
    out.times["/joint_states"] = t_joint
    # Float32 at 7 Hz and Bool at 5 Hz: no header, timed by the record time.
    t_grip = grid_times(start, 7, int((stop - start) * 7) + 2)
    for t in t_grip:
        bag.scalar("/gripper", ns(t), gripper(t))
    out.times["/gripper"] = t_grip
    t_flag = grid_times(start, 5, int((stop - start) * 5) + 1)
    for i, t in enumerate(t_flag):
        bag.flag("/gripper_closed", ns(t), i % 2 == 0)
    out.times["/gripper_closed"] = t_flag
    # Image 4x6 rgb8 at 15 Hz and png CompressedImage 5x3 at 12 Hz, header-stamped.
    t_image = grid_times(start + 0.01, 15, int((stop - start) * 15))
    for i, t in enumerate(t_image):
        bag.image("/camera/image", ns(t), ns(t) + 1_000_000, rgb_frame(i))
    out.times["/camera/image"] = t_image
    t_wrist = grid_times(start + 0.02, 12, int((stop - start) * 12))
    for i, t in enumerate(t_wrist):
        bag.compressed("/camera/compressed", ns(t), ns(t) + 1_000_000, png(wrist_frame(i)))
    out.times["/camera/compressed"] = t_wrist
    return out


CONFIG = {
    "rate_hz": 10,
    "topics": {
        "/robot/ee_pose": {"key": "ee_pose"},
        "/joint_states": {"key": "joints", "field": "position"},
        "/gripper": {"key": "gripper"},
        "/gripper_closed": {"key": "gripper_closed"},
        "/camera/image": {"key": "image"},
        "/camera/compressed": {"key": "obs/wrist"},
    },
}


def expected_grid(streams: dict[str, np.ndarray], rate: float = 10.0) -> np.ndarray:
    t0 = max(t[0] for t in streams.values())
    t1 = min(t[-1] for t in streams.values())
    return t0 + np.arange(int(math.floor((t1 - t0) * rate + 1e-9)) + 1) / rate


def nearest(times: np.ndarray, grid: np.ndarray) -> np.ndarray:
    return np.array([int(np.argmin(np.abs(times - g))) for g in grid])


def check_episode(ep: Any, times: dict[str, np.ndarray], grid: np.ndarray) -> None:
    n = len(grid)
    assert ep.batch_size == (n,)
    pos = ep["ee_pose", "position"].numpy()
    np.testing.assert_allclose(pos, np.stack([position(t) for t in grid]), atol=1e-5)
    q = ep["ee_pose", "orientation"].double().numpy()
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-6)
    assert ((q[1:] * q[:-1]).sum(axis=1) > 0).all()
    truth = np.stack([rotation(t) for t in grid])
    sign = np.sign((q[0] * truth[0]).sum())
    np.testing.assert_allclose(q, sign * truth, atol=1e-5)
    np.testing.assert_allclose(
        ep["joints"].numpy(), np.stack([joint_values(t) for t in grid]), atol=1e-5
    )
    np.testing.assert_allclose(ep["gripper"].numpy()[:, 0], [gripper(t) for t in grid], atol=1e-5)
    flags = nearest(times["/gripper_closed"], grid) % 2 == 0
    assert ep["gripper_closed"].numpy()[:, 0].tolist() == flags.tolist()
    frames = nearest(times["/camera/image"], grid)
    np.testing.assert_array_equal(ep["image"].numpy(), np.stack([rgb_frame(k) for k in frames]))
    frames = nearest(times["/camera/compressed"], grid)
    np.testing.assert_array_equal(
        ep["obs", "wrist"].numpy(), np.stack([wrist_frame(k) for k in frames])
    )


# --------------------------------------------------------------------------------------------
# Reading


@pytest.mark.parametrize("fmt", FORMATS)
def test_every_stream_is_resampled_onto_the_grid(fmt, tmp_path):
    bag = Bag(fmt)
    streams = record(bag)
    path = bag.write(tmp_path / "demo")
    episodes, manifest = read_rosbags(path, CONFIG)

    grid = expected_grid(streams.times)
    assert len(episodes) == 1
    check_episode(episodes[0], streams.times, grid)
    # The quaternion flip in the recording was real (the check above saw it removed).
    assert len(streams.times["/robot/ee_pose"]) > 2

    assert manifest.format == ("ros1" if fmt == "ros1" else "ros2")
    assert manifest.rate_hz == 10.0 and manifest.source == str(path)
    assert manifest.episodes == 1 and manifest.steps == len(grid)
    assert manifest.episode_names == [path.name] and manifest.episode_lengths == [len(grid)]
    assert manifest.keys == {
        "ee_pose/position": {"shape": [3], "dtype": "float32"},
        "ee_pose/orientation": {"shape": [4], "dtype": "float32"},
        "joints": {"shape": [3], "dtype": "float32"},
        "gripper": {"shape": [1], "dtype": "float32"},
        "gripper_closed": {"shape": [1], "dtype": "bool"},
        "image": {"shape": [4, 6, 3], "dtype": "uint8"},
        "obs/wrist": {"shape": [5, 3, 3], "dtype": "uint8"},
        "timestamp": {"shape": [], "dtype": "float64"},
    }
    stamps = episodes[0]["timestamp"]
    assert stamps.dtype == torch.float64
    np.testing.assert_allclose(stamps.numpy(), grid - grid[0], atol=1e-12)
    assert manifest.gaps == [] and manifest.skipped == []
    topics = manifest.extra["topics"]
    assert topics["/robot/ee_pose"]["msgtypes"] == ["geometry_msgs/msg/PoseStamped"]
    assert topics["/camera/compressed"]["msgtypes"] == ["sensor_msgs/msg/CompressedImage"]
    for topic, times in streams.times.items():
        assert topics[topic]["messages"] == len(times), topic
    t0, t1 = manifest.extra["episode_spans_ns"][0]
    assert t0 == T0 + round(grid[0] * SEC) and abs(t1 - (T0 + grid[-1] * SEC)) < 2


@pytest.mark.parametrize(("fmt", "marker"), [("mcap", "String"), ("ros1", "Bool")])
def test_markers_split_a_bag_into_episodes(fmt, marker, tmp_path):
    bag = Bag(fmt)
    first, second = record(bag, 0.0, 0.9), record(bag, 1.2, 2.0)

    def mark(t: float, start: bool) -> None:
        ns = T0 + round(t * SEC)
        if marker == "Bool":
            bag.flag("/episode_marker", ns, start)
        else:
            bag.text("/episode_marker", ns, "start" if start else "end")

    mark(-0.5, False)  # an end while idle is ignored
    mark(0.0, True)
    mark(0.5, True)  # a repeated start while recording is ignored
    mark(0.95, False)
    mark(1.15, True)
    mark(2.1, False)
    path = bag.write(tmp_path / "two")
    config = {**CONFIG, "segment": {"topic": "/episode_marker"}}
    episodes, manifest = read_rosbags(path, config)

    assert len(episodes) == 2
    for ep, part in zip(episodes, (first, second), strict=True):
        check_episode(ep, part.times, expected_grid(part.times))
    assert manifest.episodes == 2
    assert manifest.episode_names == [f"{path.name}#0", f"{path.name}#1"]
    assert manifest.steps == sum(manifest.episode_lengths) == sum(len(e) for e in episodes)
    assert manifest.extra["topics"]["/episode_marker"]["messages"] == 6


def test_time_reference_bounds_the_episode_and_holds_streams_within_max_gap(tmp_path):
    bag = Bag("sqlite3")
    for k in range(21):  # action at 10 Hz over 2 s
        t = 0.1 * k
        bag.scalar("/action", T0 + round(t * SEC), 3.0 * t, "Float64")
    for k in range(6):  # a gripper published for the first 0.5 s only
        t = 0.1 * k
        bag.scalar("/gripper", T0 + round(t * SEC), gripper(t))
    path = bag.write(tmp_path / "ref")
    config = {
        "rate_hz": 5,
        "time_reference": "act",
        "topics": {"/action": "act", "/gripper": {"key": "gripper"}},
    }
    # The gripper stops 1.5 s before the action ends: longer than the default max_gap_s.
    with pytest.raises(DataError, match="the stream ends early") as err:
        read_rosbags(path, config)
    assert "topic /gripper" in str(err.value) and "from 0.500 s to 2.000 s" in str(err.value)
    (ep,), manifest = read_rosbags(path, {**config, "max_gap_s": 1.6})
    grid = np.arange(11) / 5
    assert ep.batch_size == (11,) and manifest.steps == 11
    np.testing.assert_allclose(ep["act"].numpy()[:, 0], 3.0 * grid, atol=1e-5)
    held = [gripper(min(t, 0.5)) for t in grid]
    np.testing.assert_allclose(ep["gripper"].numpy()[:, 0], held, atol=1e-6)


def test_rate_argument_and_several_bags(tmp_path):
    paths = []
    for i in range(2):
        bag = Bag("sqlite3")
        for k in range(11):
            bag.scalar("/x", T0 + round(0.1 * k * SEC), float(i + k), "Float64")
        paths.append(bag.write(tmp_path / f"run{i}"))
    episodes, manifest = read_rosbags(paths, {"topics": {"/x": "x"}}, rate_hz=20)
    assert [len(e) for e in episodes] == [21, 21] and manifest.rate_hz == 20.0
    np.testing.assert_allclose(episodes[1]["x"][:3, 0].numpy(), [1.0, 1.5, 2.0])
    assert manifest.source == str(tmp_path.absolute())
    assert manifest.extra["topics"]["/x"]["messages"] == 22
    with pytest.raises(ValueError, match="rate_hz"):
        read_rosbags(paths, {"topics": {"/x": "x"}})
    # a folder holding bags stands for them (here a rosbag2 folder and a ROS 1 file)
    bag = Bag("ros1")
    for k in range(3):
        bag.scalar("/x", T0 + round(0.1 * k * SEC), 7.0, "Float64")
    bag.write(tmp_path / "run2")
    episodes, manifest = read_rosbags(tmp_path, {"topics": {"/x": "x"}, "rate_hz": 10})
    assert manifest.episode_names == ["run0", "run1", "run2.bag"]
    assert manifest.format == "ros1+ros2" and [len(e) for e in episodes] == [11, 11, 3]


def test_joint_state_reordering_and_selection(tmp_path):
    bag = Bag("sqlite3")
    for k in range(5):
        ns = T0 + k * SEC // 10
        names, values = ["a", "b"], [k, 10 * k]
        if k % 2:
            names, values = names[::-1], values[::-1]
        bag.joints("/joint_states", ns, ns, names, values)
        bag.joints("/joint_states", ns + 1, ns + 1, ["finger"], [0.5])  # another publisher
    path = bag.write(tmp_path / "js")
    config = {"rate_hz": 10, "topics": {"/joint_states": {"key": "q", "joints": ["b", "a"]}}}
    (ep,), manifest = read_rosbags(path, config)
    np.testing.assert_allclose(ep["q"].numpy(), [[10 * k, k] for k in range(5)])
    assert manifest.extra["topics"]["/joint_states"]["skipped"] == 5
    with pytest.raises(DataError, match=r"joint names \['finger'\] differ"):
        read_rosbags(path, {"rate_hz": 10, "topics": {"/joint_states": "q"}})


def test_other_message_types_and_encodings(tmp_path):
    bag = Bag("ros1")
    rgb = [rgb_frame(k) for k in range(5)]
    for k in range(5):
        ns = T0 + k * SEC // 10
        t = 0.1 * k
        tr = bag.msg("geometry_msgs/msg/Vector3", x=t, y=2 * t, z=3.0)
        q = rotation(t)
        rot = bag.msg("geometry_msgs/msg/Quaternion", x=q[0], y=q[1], z=q[2], w=q[3])
        transform = bag.msg("geometry_msgs/msg/Transform", translation=tr, rotation=rot)
        msg = bag.msg(
            "geometry_msgs/msg/TransformStamped", header=bag.header(ns), child_frame_id="tool",
            transform=transform,
        )
        bag.add("/tf_target", "geometry_msgs/msg/TransformStamped", ns, msg)
        layout = bag.msg("std_msgs/msg/MultiArrayLayout", dim=[], data_offset=0)
        array = bag.msg("std_msgs/msg/Float64MultiArray", layout=layout,
                        data=np.array([t, -t, 1.0]))
        bag.add("/cmd", "std_msgs/msg/Float64MultiArray", ns, array)
        bag.image("/bgr", ns, ns, rgb[k][:, :, ::-1], encoding="bgr8")
        bag.image("/mono", ns, ns, rgb[k][:, :, :1], encoding="mono8")
        bag.compressed("/grey_png", ns, ns, cv2.imencode(".png", rgb[k][:, :, 0])[1].tobytes())
    path = bag.write(tmp_path / "types")
    config = {
        "rate_hz": 10,
        "topics": {"/tf_target": "target", "/cmd": "action", "/bgr": "bgr", "/mono": "mono",
                   "/grey_png": "grey"},
    }
    (ep,), manifest = read_rosbags(path, config)
    grid = 0.1 * np.arange(5)
    np.testing.assert_allclose(
        ep["target", "position"].numpy(), [[t, 2 * t, 3.0] for t in grid], atol=1e-6
    )
    np.testing.assert_allclose(
        ep["target", "orientation"].numpy(), [rotation(t) for t in grid], atol=1e-6
    )
    np.testing.assert_allclose(ep["action"].numpy(), [[t, -t, 1.0] for t in grid], atol=1e-6)
    np.testing.assert_array_equal(ep["bgr"].numpy(), np.stack(rgb))
    np.testing.assert_array_equal(ep["mono"].numpy(), np.stack(rgb)[..., :1])
    np.testing.assert_array_equal(ep["grey"].numpy(), np.stack(rgb)[..., :1])
    assert manifest.keys["mono"] == {"shape": [4, 6, 1], "dtype": "uint8"}
    assert manifest.extra["topics"]["/cmd"]["msgtypes"] == ["std_msgs/msg/Float64MultiArray"]


# --------------------------------------------------------------------------------------------
# Pure functions


def test_slerp_endpoints_midpoint_and_norm():
    q0 = torch.tensor([0.0, 0.0, 0.0, 1.0], dtype=torch.float64)
    q1 = torch.tensor([0.0, 0.0, math.sqrt(0.5), math.sqrt(0.5)], dtype=torch.float64)
    torch.testing.assert_close(slerp(q0, q1, 0.0), q0, atol=1e-15, rtol=0)
    torch.testing.assert_close(slerp(q0, q1, 1.0), q1, atol=1e-15, rtol=0)
    mid = slerp(q0, q1, 0.5)
    angle = 2 * math.atan2(float(mid[2]), float(mid[3]))
    assert abs(math.degrees(angle) - 45.0) < 1e-12
    w = torch.linspace(0, 1, 11, dtype=torch.float64)
    qs = slerp(q0.expand(11, 4), q1.expand(11, 4), w)
    torch.testing.assert_close(qs.norm(dim=-1), torch.ones(11, dtype=torch.float64))
    angles = 2 * torch.atan2(qs[:, 2], qs[:, 3])
    torch.testing.assert_close(angles, w * math.pi / 2)  # constant angular speed
    # nearly equal quaternions take the linear fallback and stay unit
    tiny = torch.tensor([0.0, 0.0, 1e-12, 1.0], dtype=torch.float64)
    assert abs(float(slerp(q0, tiny, 0.5).norm()) - 1.0) < 1e-15


def test_continuity_fix_removes_sign_flips():
    def about_z(angles: torch.Tensor) -> torch.Tensor:
        zero = torch.zeros_like(angles)
        return torch.stack([zero, zero, torch.sin(angles / 2), torch.cos(angles / 2)], dim=-1)

    q = about_z(torch.linspace(0, 2.5, 9, dtype=torch.float64))
    flipped = q.clone()
    flipped[3:6] *= -1
    flipped[8] *= -1
    fixed = hemisphere_continuous(flipped, dim=-2)
    torch.testing.assert_close(fixed, q)
    # resample_slerp applies it: the halfway point of a flipped pair is not a degenerate mix
    out = resample_slerp(torch.arange(9, dtype=torch.float64), flipped,
                         torch.arange(17, dtype=torch.float64) / 2)
    assert ((out[1:] * out[:-1]).sum(-1) > 0).all()
    truth = about_z(torch.linspace(0, 2.5, 17, dtype=torch.float64))
    torch.testing.assert_close(out, truth, atol=1e-12, rtol=0)


def test_linear_and_nearest_resampling():
    times = torch.tensor([0.0, 1.0, 3.0], dtype=torch.float64)
    values = torch.tensor([[0.0, 1.0], [2.0, 1.0], [0.0, 4.0]], dtype=torch.float64)
    grid = torch.tensor([-1.0, 0.0, 0.5, 2.0, 3.0, 5.0], dtype=torch.float64)
    out = resample_linear(times, values, grid)
    torch.testing.assert_close(
        out, torch.tensor([[0, 1], [0, 1], [1, 1], [1, 2.5], [0, 4], [0, 4]], dtype=torch.float64)
    )
    one = resample_linear(times[:1], values[:1], grid)
    torch.testing.assert_close(one, values[:1].expand(6, 2))
    assert nearest_indices(times, torch.tensor([0.5, 0.51, 2.0, 2.01, 9.0])).tolist() == [
        0, 1, 1, 2, 2,
    ]
    with pytest.raises(ValueError, match="strictly increasing"):
        resample_linear(torch.tensor([0.0, 0.0]), values[:2], grid)


YAML = """
rate_hz: 10
time_reference: action
topics:
  /robot/ee_pose: {key: ee_pose}
  /tf_target:     {key: target}
  /joint_states:  {key: joints, field: position}
  /camera/image:  {key: image}
  /camera/compressed: {key: wrist}
  /gripper:       {key: gripper}
  /cmd:           {key: action}
segment:
  topic: /episode_marker
"""


def test_yaml_config(tmp_path):
    path = tmp_path / "topics.yaml"
    path.write_text(YAML)
    cfg = load_rosbag_config(path)
    assert cfg.rate_hz == 10.0 and cfg.time_reference == "action"
    assert cfg.segment_topic == "/episode_marker" and len(cfg.topics) == 7
    assert cfg.topics["/joint_states"] == TopicConfig("joints", field="position")
    path.write_text("- just a list")
    with pytest.raises(ValueError, match="YAML mapping"):
        load_rosbag_config(path)


def test_config_validation():
    cfg = RosbagConfig.from_dict(
        {"rate_hz": 10, "topics": {"/a": {"key": "obs/a"}, "/b": "b"},
         "segment": {"topic": "/m"}, "time_reference": "b"}
    )
    assert cfg.topics["/b"] == TopicConfig("b") and cfg.topics["/a"].nested_key == ("obs", "a")
    assert RosbagConfig.from_dict(cfg.to_dict()) == cfg
    bad = [
        ({"topics": {}}, "no topics"),
        ({"topics": {"/a": {"key": "x", "fields": "position"}}}, "unknown topic option"),
        ({"topics": {"/a": {"key": "x", "field": "torque"}}}, "field must be one of"),
        ({"topics": {"/a": "x", "/b": "x/y"}}, "collide"),
        ({"topics": {"/a": "x"}, "time_reference": "y"}, "time_reference"),
        ({"topics": {"/a": "x"}, "rate_hz": -1}, "rate_hz"),
        ({"topics": {"/a": "x"}, "segment": {"topic": "/a"}}, "also a data topic"),
        ({"topics": {"/a": "x"}, "segment": "/m"}, "segment must be"),
    ]
    for data, match in bad:
        with pytest.raises(ValueError, match=match):
            RosbagConfig.from_dict(data)


# --------------------------------------------------------------------------------------------
# Bad input


def small_bag(fmt: str = "sqlite3") -> Bag:
    bag = Bag(fmt)
    for k in range(11):
        t = 0.1 * k
        ns = T0 + round(t * SEC)
        bag.joints("/joint_states", ns, ns, ["j1", "j2", "j3"], joint_values(t))
    return bag


SMALL = {"rate_hz": 10, "topics": {"/joint_states": {"key": "joints"}}}


def test_missing_bag_path(tmp_path):
    path = tmp_path / "nowhere.bag"
    with pytest.raises(DataError, match="no such ROS bag") as err:
        read_rosbags(path, SMALL)
    assert str(path) in str(err.value)
    (tmp_path / "folder").mkdir()
    with pytest.raises(DataError, match="not a ROS bag") as err:
        read_rosbags(tmp_path / "folder", SMALL)
    assert str(tmp_path / "folder") in str(err.value)


def test_topic_absent_lists_available_topics(tmp_path):
    path = small_bag().write(tmp_path / "b")
    config = {"rate_hz": 10, "topics": {"/joint_states": "joints", "/camera/image": "image"}}
    with pytest.raises(DataError, match="topic not in the bag") as err:
        read_rosbags(path, config)
    text = str(err.value)
    assert str(path) in text and "topic /camera/image" in text
    assert "available topics: /joint_states" in text


def test_unsupported_message_type(tmp_path):
    bag = small_bag("ros1")
    bag.text("/status", T0, "ok")
    path = bag.write(tmp_path / "b")
    config = {"rate_hz": 10, "topics": {"/joint_states": "joints", "/status": "status"}}
    with pytest.raises(DataError, match="unsupported message type std_msgs/msg/String") as err:
        read_rosbags(path, config)
    assert str(path) in str(err.value) and "topic /status" in str(err.value)
    # a data type is not a marker type either
    config = {**SMALL, "segment": {"topic": "/joint_states_copy"}}
    bag = small_bag()
    bag.scalar("/joint_states_copy", T0, 1.0)
    path = bag.write(tmp_path / "c")
    with pytest.raises(DataError, match="unsupported message type std_msgs/msg/Float32 for a"):
        read_rosbags(path, config)


@pytest.mark.parametrize("fmt", FORMATS)
def test_truncated_bag(fmt, tmp_path):
    bag = small_bag(fmt)
    path = bag.write(tmp_path / "b")
    storage = path if fmt == "ros1" else next(p for p in path.iterdir() if p.suffix != ".yaml")
    data = storage.read_bytes()
    storage.write_bytes(data[: len(data) // 2])
    with pytest.raises(DataError, match="truncated or corrupt") as err:
        read_rosbags(path, SMALL)
    assert str(path) in str(err.value)


@pytest.mark.parametrize("bad", [math.nan, math.inf])
def test_non_finite_value_names_topic_episode_and_step(bad, tmp_path):
    bag = Bag("mcap")
    for k in range(11):
        ns = T0 + k * SEC // 10
        values = [1.0, 2.0, bad if k == 7 else 3.0]
        bag.joints("/joint_states", ns, ns, ["j1", "j2", "j3"], values)
    path = bag.write(tmp_path / "b")
    with pytest.raises(DataError, match="non-finite value") as err:
        read_rosbags(path, SMALL)
    text = str(err.value)
    assert str(path) in text and "topic /joint_states" in text
    assert f"episode {path.name}" in text and "step 7" in text and "message 7" in text


def test_stream_without_messages(tmp_path):
    bag = small_bag()
    bag.empty_topics.append(("/gripper", "std_msgs/msg/Float32"))
    path = bag.write(tmp_path / "b")
    config = {"rate_hz": 10, "topics": {"/joint_states": "joints", "/gripper": "gripper"}}
    with pytest.raises(DataError, match="no messages") as err:
        read_rosbags(path, config)
    assert str(path) in str(err.value) and "topic /gripper" in str(err.value)


def test_streams_without_time_overlap(tmp_path):
    bag = small_bag()  # joints over [0, 1] s
    for k in range(5):
        bag.scalar("/gripper", T0 + (2 + k) * SEC, 1.0)  # gripper over [2, 6] s
    path = bag.write(tmp_path / "b")
    config = {"rate_hz": 10, "topics": {"/joint_states": "joints", "/gripper": "gripper"}}
    with pytest.raises(DataError, match="no time overlap") as err:
        read_rosbags(path, config)
    text = str(err.value)
    assert str(path) in text and "topic /gripper" in text and "/joint_states" in text
    with pytest.raises(DataError, match="no time overlap") as err:
        read_rosbags(path, {**config, "time_reference": "joints"})
    assert "topic /gripper" in str(err.value)


def test_unsupported_image_encoding(tmp_path):
    bag = small_bag("ros1")
    bag.image("/camera/image", T0, T0, np.zeros((2, 2, 2), np.uint8), encoding="16UC1")
    path = bag.write(tmp_path / "b")
    config = {"rate_hz": 10, "topics": {"/joint_states": "joints", "/camera/image": "image"}}
    with pytest.raises(DataError, match="unsupported image encoding '16UC1'") as err:
        read_rosbags(path, config)
    assert str(path) in str(err.value) and "topic /camera/image" in str(err.value)


def test_undecodable_compressed_image(tmp_path):
    bag = small_bag("mcap")
    for k in range(3):
        ns = T0 + k * SEC // 2
        bag.compressed("/camera/compressed", ns, ns, b"definitely not a png" if k == 1
                       else png(wrist_frame(k)))
    path = bag.write(tmp_path / "b")
    config = {"rate_hz": 10, "topics": {"/joint_states": "joints", "/camera/compressed": "cam"}}
    with pytest.raises(DataError, match="cannot decode compressed image") as err:
        read_rosbags(path, config)
    text = str(err.value)
    assert str(path) in text and "topic /camera/compressed" in text and "step 1" in text


def test_unterminated_segment(tmp_path):
    bag = small_bag()
    bag.text("/episode_marker", T0, "start")
    path = bag.write(tmp_path / "b")
    with pytest.raises(DataError, match="no end marker") as err:
        read_rosbags(path, {**SMALL, "segment": {"topic": "/episode_marker"}})
    assert str(path) in str(err.value) and "topic /episode_marker" in str(err.value)


# --------------------------------------------------------------------------------------------
# The conversion command


@pytest.mark.parametrize("fmt", ["sqlite3", "ros1"])
def test_convert_command_writes_the_resampled_bag_as_a_store(fmt, tmp_path, capsys):
    import yaml

    from rfmp_rl.data.convert import main as convert_main
    from rfmp_rl.data.store import DemonstrationStore

    bag = Bag(fmt)
    streams = record(bag)
    path = bag.write(tmp_path / "demo")
    config = tmp_path / "topics.yaml"
    config.write_text(yaml.safe_dump(CONFIG))
    code = convert_main(["ros", str(path), "--config", str(config), "--out",
                         str(tmp_path / "store")])
    assert code == 0
    out = capsys.readouterr().out
    grid = expected_grid(streams.times)
    assert f"1 episodes, {len(grid)} steps, 10 Hz" in out and "ee_pose/orientation" in out
    store = DemonstrationStore.load(tmp_path / "store")
    check_episode(store.episode(0), streams.times, grid)


def test_convert_command_reports_a_missing_topic(tmp_path, capsys):
    import yaml

    from rfmp_rl.data.convert import main as convert_main

    path = small_bag().write(tmp_path / "demo")
    config = tmp_path / "topics.yaml"
    config.write_text(yaml.safe_dump({"rate_hz": 10, "topics": {"/nope": {"key": "x"}}}))
    assert convert_main(["ros", str(path), "--config", str(config), "--dry-run"]) == 2
    err = capsys.readouterr().err
    assert str(path) in err and "/nope" in err


# --------------------------------------------------------------------------------------------
# Flat folders of ROS 2 bags


def bare_storage_file(bag: Bag, folder: Path, name: str) -> Path:
    """Write ``bag`` as a rosbag2 recording and keep only its storage file, as ``name``."""
    recording = bag.write(folder / f"{name}_recording")
    storage = next(p for p in recording.iterdir() if p.suffix in (".db3", ".mcap"))
    target = folder / f"{name}{storage.suffix}"
    storage.rename(target)
    for p in recording.iterdir():
        p.unlink()
    recording.rmdir()
    return target


@pytest.mark.parametrize("fmt", ["sqlite3", "mcap"])
def test_flat_folder_of_ros2_bags_gives_one_episode_per_bag(fmt, tmp_path):
    flat = tmp_path / "flat"
    flat.mkdir()
    for i in range(3):  # three recordings 50 s apart, each 1 s long
        bag = Bag(fmt)
        for k in range(11):
            bag.scalar("/x", T0 + (50 * i) * SEC + round(0.1 * k * SEC), 10.0 * i + k, "Float64")
        bare_storage_file(bag, flat, f"run{i}")
    episodes, manifest = read_rosbags(flat, {"rate_hz": 10, "topics": {"/x": "x"}})
    suffix = ".db3" if fmt == "sqlite3" else ".mcap"
    assert manifest.episode_names == [f"run{i}{suffix}" for i in range(3)]
    assert [len(e) for e in episodes] == [11, 11, 11] and manifest.format == "ros2"
    for i, ep in enumerate(episodes):  # nothing interpolated across the 49 s between them
        np.testing.assert_allclose(ep["x"][:, 0].numpy(), 10.0 * i + np.arange(11), atol=1e-9)
    # bare files, rosbag2 folders and ROS 1 files side by side: one bag each, in name order
    bag = Bag("sqlite3" if fmt == "mcap" else "mcap")
    for k in range(4):
        bag.scalar("/x", T0 + round(0.1 * k * SEC), 1.0, "Float64")
    bag.write(flat / "run3")
    bag = Bag("ros1")
    for k in range(5):
        bag.scalar("/x", T0 + round(0.1 * k * SEC), 2.0, "Float64")
    bag.write(flat / "run4")
    episodes, manifest = read_rosbags(flat, {"rate_hz": 10, "topics": {"/x": "x"}})
    assert manifest.episode_names == [*(f"run{i}{suffix}" for i in range(3)), "run3", "run4.bag"]
    assert [len(e) for e in episodes] == [11, 11, 11, 4, 5]


# --------------------------------------------------------------------------------------------
# Gaps


def gap_bag(fmt: str = "sqlite3", camera_until: float = 8.0, hole: tuple[float, float] | None = None
            ) -> Bag:
    """Joints at 10 Hz over 8 s; a camera at 10 Hz until ``camera_until`` with an optional
    ``hole`` (seconds) without frames."""
    bag = Bag(fmt)
    for k in range(81):
        t = 0.1 * k
        ns = T0 + round(t * SEC)
        bag.joints("/joint_states", ns, ns, ["j1", "j2", "j3"], joint_values(t))
        if t <= camera_until + 1e-9 and not (hole and hole[0] < t < hole[1]):
            bag.image("/camera/image", ns, ns, rgb_frame(k))
    return bag


GAP_CONFIG = {"rate_hz": 10, "topics": {"/joint_states": "joints", "/camera/image": "image"}}


@pytest.mark.parametrize("fmt", FORMATS)
def test_a_stream_that_stops_early_is_an_error_naming_bag_topic_and_times(fmt, tmp_path):
    path = gap_bag(fmt, camera_until=2.0).write(tmp_path / "cam")
    with pytest.raises(DataError, match="the stream ends early") as err:
        read_rosbags(path, GAP_CONFIG)
    text = str(err.value)
    assert str(path) in text and "topic /camera/image" in text
    assert "no message for 6.000 s, from 2.000 s to 8.000 s" in text
    assert "max_gap_s = 0.5 s" in text
    # the same with the joints as the time reference (the camera used to be held silently)
    with pytest.raises(DataError, match="the stream ends early"):
        read_rosbags(path, {**GAP_CONFIG, "time_reference": "joints"})


def test_a_stream_that_starts_late_is_a_gap(tmp_path):
    bag = Bag("mcap")
    for k in range(31):
        bag.scalar("/a", T0 + round(0.1 * k * SEC), 1.0, "Float64")
        if k >= 12:
            bag.scalar("/b", T0 + round(0.1 * k * SEC), 2.0, "Float64")
    path = bag.write(tmp_path / "late")
    config = {"rate_hz": 10, "topics": {"/a": "a", "/b": "b"}}
    with pytest.raises(DataError, match="the stream starts late") as err:
        read_rosbags(path, config)
    assert "topic /b" in str(err.value) and "from 0.000 s to 1.200 s" in str(err.value)
    (ep,), manifest = read_rosbags(path, {**config, "max_gap_s": 1.5})
    assert len(ep) == 19 and manifest.gaps == []


@pytest.mark.parametrize("fmt", ["sqlite3", "ros1"])
def test_gaps_split_episodes_when_configured_and_the_manifest_lists_them(fmt, tmp_path):
    # camera frames missing between 3 s and 5 s, and the camera dies at 7 s
    path = gap_bag(fmt, camera_until=7.0, hole=(3.0, 5.0)).write(tmp_path / "cam")
    with pytest.raises(DataError, match=r"gap: no message for 2\.000 s.*1 more gap"):
        read_rosbags(path, GAP_CONFIG)
    episodes, manifest = read_rosbags(path, {**GAP_CONFIG, "on_gap": "split"})
    name = path.name
    assert manifest.episode_names == [f"{name}~0", f"{name}~1"]
    assert [len(e) for e in episodes] == [31, 21]  # 0..3 s and 5..7 s
    np.testing.assert_allclose(
        episodes[1]["joints"].numpy(), np.stack([joint_values(5 + 0.1 * k) for k in range(21)]),
        atol=1e-5,
    )
    np.testing.assert_array_equal(episodes[1]["image"].numpy(),
                                  np.stack([rgb_frame(50 + k) for k in range(21)]))
    np.testing.assert_allclose(episodes[1]["timestamp"].numpy(), np.arange(21) / 10, atol=1e-12)
    assert [(g["topic"], g["kind"], g["start_s"], g["end_s"]) for g in manifest.gaps] == [
        ("/camera/image", "gap", 3.0, 5.0), ("/camera/image", "early end", 7.0, 8.0),
    ]
    assert all(g["episode"] == name and g["file"] == str(path) for g in manifest.gaps)
    text = str(manifest)
    assert f"{name} /camera/image: gap, 3.000 s to 5.000 s (2.000 s)" in text
    assert f"{name} /camera/image: early end, 7.000 s to 8.000 s (1.000 s)" in text
    # a gap up to max_gap_s is interpolated over
    episodes, manifest = read_rosbags(path, {**GAP_CONFIG, "max_gap_s": 2.5, "on_gap": "split"})
    assert manifest.episode_names == [name] and len(episodes[0]) == 71 and manifest.gaps == []


def test_gap_config_validation():
    for data, match in [
        ({"max_gap_s": 0}, "max_gap_s must be a positive"),
        ({"max_gap_s": "soon"}, "max_gap_s must be a positive number of seconds, got 'soon'"),
        ({"rate_hz": "fast"}, "rate_hz must be positive, got 'fast'"),
        ({"on_gap": "hold"}, "on_gap must be one of error, split"),
    ]:
        with pytest.raises(DataError, match=match):
            RosbagConfig.from_dict({"topics": {"/a": "a"}, **data})
    cfg = RosbagConfig.from_dict({"topics": {"/a": "a"}})
    assert cfg.gap_limit_s(100.0) == 0.5 and cfg.gap_limit_s(2.0) == 1.5


# --------------------------------------------------------------------------------------------
# Unreadable bags


def bad_bags(tmp_path: Path) -> tuple[Path, list[Path]]:
    folder = tmp_path / "bags"
    folder.mkdir()
    good = small_bag("ros1").write(folder / "a_good")
    corrupt = small_bag("ros1").write(folder / "b_corrupt")
    corrupt.write_bytes(corrupt.read_bytes()[:300])
    bag = Bag("ros1")
    bag.scalar("/other", T0, 1.0)
    missing = bag.write(folder / "c_missing_topic")
    return folder, [good, corrupt, missing]


def test_skip_bad_lists_unreadable_bags_in_the_manifest(tmp_path):
    folder, (good, corrupt, missing) = bad_bags(tmp_path)
    with pytest.raises(DataError, match="truncated or corrupt") as err:
        read_rosbags(folder, SMALL)
    assert str(corrupt) in str(err.value)
    episodes, manifest = read_rosbags(folder, SMALL, skip_bad=True)
    assert manifest.episode_names == [good.name] and len(episodes) == 1
    assert [s["file"] for s in manifest.skipped] == [str(corrupt), str(missing)]
    assert "truncated or corrupt" in manifest.skipped[0]["reason"]
    assert "topic /joint_states" in manifest.skipped[1]["reason"]
    assert "topic not in the bag" in manifest.skipped[1]["reason"]
    assert "2 skipped:" in str(manifest) and str(missing) in str(manifest)
    with pytest.raises(DataError, match="no readable bag among 2"):
        read_rosbags([corrupt, missing], SMALL, skip_bad=True)


def test_convert_command_skip_bad(tmp_path, capsys):
    import yaml

    from rfmp_rl.data.convert import main as convert_main
    from rfmp_rl.data.store import DemonstrationStore

    folder, (good, corrupt, missing) = bad_bags(tmp_path)
    config = tmp_path / "topics.yaml"
    config.write_text(yaml.safe_dump(SMALL))
    args = ["ros", str(folder), "--config", str(config), "--out", str(tmp_path / "store")]
    assert convert_main(args) == 2
    captured = capsys.readouterr()
    assert str(corrupt) in captured.err and "Traceback" not in captured.err
    assert not (tmp_path / "store").exists()
    assert convert_main([*args, "--skip-bad"]) == 0
    out = capsys.readouterr().out
    tail = out[out.index("wrote"):]
    assert "skipped 2 unreadable bag(s)" in tail and str(corrupt) in tail and str(missing) in tail
    store = DemonstrationStore.load(tmp_path / "store")
    assert store.num_episodes == 1
    assert [s["file"] for s in store.manifest.skipped] == [str(corrupt), str(missing)]
    with pytest.raises(SystemExit) as exit_:
        convert_main(["lasa", "LShape", "--dry-run", "--skip-bad"])
    assert exit_.value.code == 2 and "ros format only" in capsys.readouterr().err


# --------------------------------------------------------------------------------------------
# Flat vectors from several topics


def pose_gripper_bag(fmt: str) -> Bag:
    """A commanded pose whose quaternion starts with w < 0 and flips sign halfway, a gripper
    command, the measured pose and joint velocities: all at 20 Hz for 1 s."""
    bag = Bag(fmt)
    for k in range(21):
        t = 0.05 * k
        ns = T0 + round(t * SEC)
        sign = -1.0 if k < 10 else 1.0  # w = cos(...) > 0, so w < 0 for the first half
        bag.pose("/cmd_pose", ns, ns, position(t), sign * rotation(t))
        bag.scalar("/gripper_cmd", ns, gripper(t), "Float64")
        bag.pose("/ee_pose", ns, ns, position(t) + 1.0, rotation(t))
        bag.joints("/joint_states", ns, ns, ["j1", "j2", "j3"], joint_values(t))
    return bag


@pytest.mark.parametrize("fmt", ["mcap", "ros1"])
def test_action_and_observation_vectors_from_several_topics(fmt, tmp_path):
    path = pose_gripper_bag(fmt).write(tmp_path / "teleop")
    config = {
        "rate_hz": 10,
        "action": ["/cmd_pose", "/gripper_cmd"],
        "action_manifold": "R3 x S3 x R1",
        "observation": {"state": ["/ee_pose", {"topic": "/joint_states", "field": "velocity"}]},
        "topics": {"/gripper_cmd": "gripper"},  # a vector's topic may also have its own key
    }
    (ep,), manifest = read_rosbags(path, config)
    grid = np.arange(11) / 10
    action = ep["action"]
    assert action.shape == (11, 8) and action.dtype == torch.float32
    np.testing.assert_allclose(action[:, :3].numpy(), [position(t) for t in grid], atol=1e-5)
    q = action[:, 3:7].double().numpy()
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-6)
    assert q[0, 3] >= 0 and ((q[1:] * q[:-1]).sum(axis=1) > 0).all()  # xyzw, w >= 0 first
    np.testing.assert_allclose(q, [rotation(t) for t in grid], atol=1e-5)
    np.testing.assert_allclose(action[:, 7].numpy(), [gripper(t) for t in grid], atol=1e-6)
    state = ep["observation", "state"]
    assert state.shape == (11, 10)
    np.testing.assert_allclose(state[:, :3].numpy(), [position(t) + 1 for t in grid], atol=1e-5)
    np.testing.assert_allclose(state[:, 7:].numpy(), [-joint_values(t) for t in grid], atol=1e-5)
    np.testing.assert_allclose(ep["gripper"][:, 0].numpy(), action[:, 7].numpy())
    assert manifest.keys["action"] == {"shape": [8], "dtype": "float32"}
    assert manifest.extra["vectors"]["action"] == [
        {"topic": "/cmd_pose", "kind": "pose", "start": 0, "size": 7},
        {"topic": "/gripper_cmd", "kind": "vector", "start": 7, "size": 1},
    ]
    assert manifest.extra["config"]["action_manifold"] == "R3 x S3 x R1"
    assert RosbagConfig.from_dict(manifest.extra["config"]) == RosbagConfig.from_dict(config)


def test_vector_layout_must_match_the_declared_manifold(tmp_path):
    path = pose_gripper_bag("sqlite3").write(tmp_path / "teleop")
    config = {"rate_hz": 10, "action": ["/cmd_pose", "/joint_states"],
              "action_manifold": "R3 x S3 x R1"}
    with pytest.raises(DataError, match="flat layout R3 x S3 x R3") as err:
        read_rosbags(path, config)
    text = str(err.value)
    assert str(path) in text and "key action" in text and "/joint_states: R3" in text
    # a list of topics as the observation gives one flat 'observation' key
    (ep,), _ = read_rosbags(path, {"rate_hz": 10, "observation": ["/gripper_cmd", "/ee_pose"],
                                   "observation_manifold": "R1 x R3 x S3"})
    assert ep["observation"].shape == (11, 8)


def test_images_cannot_be_part_of_a_vector(tmp_path):
    bag = small_bag("mcap")
    bag.image("/camera/image", T0, T0, rgb_frame(0))
    path = bag.write(tmp_path / "b")
    with pytest.raises(DataError, match="cannot be part of the flat vector observation"):
        read_rosbags(path, {"rate_hz": 10, "observation": ["/joint_states", "/camera/image"]})


def test_unknown_or_conflicting_vector_config_is_refused(tmp_path):
    with pytest.raises(DataError, match=r"unknown rosbag config field\(s\) \['concat'\]") as err:
        RosbagConfig.from_dict({"topics": {"/a": "a"}, "concat": {"action": ["/a", "/b"]}})
    assert "allowed: rate_hz, topics, action, action_manifold, observation" in str(err.value)
    path = tmp_path / "topics.yaml"
    path.write_text("rate_hz: 10\ntopics: {/a: a}\nconcat: {action: [/a]}\n")
    with pytest.raises(DataError, match="concat") as err:
        load_rosbag_config(path)
    assert str(path) in str(err.value)
    bad = [
        ({"action": "/a"}, "action must be a non-empty list"),
        ({"action": ["/a"], "action_manifold": "R3 x Q3"}, "cannot read factor"),
        ({"action_manifold": "R3"}, "without action"),
        ({"action": [{"topic": "/a", "fields": "velocity"}]}, "allowed fields are topic"),
        ({"action": ["/a"], "topics": {"/b": "action/x"}}, "collide"),
        ({"topics": {"/a": "timestamp"}}, "collide"),
        ({"action": [{"topic": "/j", "field": "velocity"}],
          "observation": [{"topic": "/j", "field": "effort"}]}, "a topic is read one way"),
        ({"observation": {"s": ["/a"]}, "observation_manifold": "R1"}, "must be one too"),
    ]
    for data, match in bad:
        with pytest.raises(DataError, match=match):
            RosbagConfig.from_dict(data)
    cfg = RosbagConfig.from_dict({"action": ["/j"], "time_reference": "action"})
    assert cfg.read_options()["/j"].key == "action"


def test_readme_topic_config_is_a_valid_config():
    import yaml

    readme = Path(__file__).resolve().parents[2] / "rfmp_rl" / "data" / "README.md"
    section = readme.read_text().split("## ROS bags: the topic config", 1)[1]
    block = section.split("```yaml\n", 1)[1].split("```", 1)[0]
    data = yaml.safe_load(block)
    assert set(data) == set(CONFIG_FIELDS)  # the data README shows every field
    cfg = RosbagConfig.from_dict(data)
    assert [p.topic for p in cfg.vectors["action"]] == ["/cmd_pose", "/gripper_cmd"]
    assert cfg.manifolds == {"action": "R3 x S3 x R1", "observation/state": "R3 x S3 x R1"}


def test_rosbag_module_re_exports_the_ros_package():
    import rfmp_rl.data.ros as ros
    import rfmp_rl.data.rosbag as rosbag

    for name in rosbag.__all__:
        assert getattr(rosbag, name) is getattr(ros, name), name
    assert set(rosbag.__all__) == set(ros.__all__)


def test_an_episode_recorded_as_minus_q_is_canonicalised_like_the_others(tmp_path):
    folder = tmp_path / "bags"
    folder.mkdir()
    for name, sign in (("a_plus", 1.0), ("b_minus", -1.0)):
        bag = Bag("mcap")
        for k in range(21):
            t = 0.05 * k
            ns = T0 + round(t * SEC)
            bag.pose("/cmd_pose", ns, ns, position(t), sign * rotation(t))
            bag.scalar("/gripper_cmd", ns, gripper(t), "Float64")
        bag.write(folder / name)
    config = {"rate_hz": 10, "action": ["/cmd_pose", "/gripper_cmd"],
              "action_manifold": "R3 x S3 x R1", "topics": {"/cmd_pose": "cmd"}}
    episodes, manifest = read_rosbags(folder, config)
    expected = np.array([rotation(t) for t in np.arange(11) / 10])
    for ep in episodes:  # both +q: in the flat vector and under the nested key
        np.testing.assert_allclose(ep["action"][:, 3:7].numpy(), expected, atol=1e-5)
        np.testing.assert_allclose(ep["cmd", "orientation"].numpy(), expected, atol=1e-5)
    fields = manifest.extra["quaternions"]["fields"]
    assert [(f["key"], f["columns"], f["first_flipped"]) for f in fields] == [
        ("cmd/orientation", None, 1), ("action", [3, 7], 1)]
    raw, manifest = read_rosbags(folder, config, raw_quaternion_signs=True)
    np.testing.assert_allclose(raw[1]["action"][:, 3:7].numpy(), -expected, atol=1e-5)
    np.testing.assert_allclose(raw[1]["cmd", "orientation"].numpy(), -expected, atol=1e-5)
    np.testing.assert_allclose(raw[0]["action"][:, 3:7].numpy(), expected, atol=1e-5)
    assert manifest.extra["quaternions"]["raw_signs"] is True


def _crashed_recordings(tmp_path):
    """A flat folder: one good ROS 1 bag, an unfinished ROS 1 bag (``.bag.active``) and a
    rosbag2 folder whose recorder died before writing ``metadata.yaml``."""
    folder = tmp_path / "flat"
    folder.mkdir()
    gap_bag("ros1").write(folder / "ep1")
    gap_bag("ros1").write(folder / "tmp")
    (folder / "tmp.bag").rename(folder / "ep2.bag.active")
    gap_bag("sqlite3").write(folder / "ep3")
    (folder / "ep3" / "metadata.yaml").unlink()
    return folder


def test_unfinished_recordings_in_a_folder_are_not_left_out_silently(tmp_path):
    folder = _crashed_recordings(tmp_path)
    with pytest.raises(DataError, match="ep2.bag.active") as err:
        read_rosbags(folder, GAP_CONFIG)
    message = str(err.value)
    assert "rosbag reindex" in message and "ep3" in message and "ros2 bag reindex" in message
    episodes, manifest = read_rosbags(folder, GAP_CONFIG, skip_bad=True)
    assert manifest.extra["files"] == [str(folder / "ep1.bag")] and len(episodes) == 1
    skipped = {item["file"]: item["reason"] for item in manifest.skipped}
    assert sorted(skipped) == [str(folder / "ep2.bag.active"), str(folder / "ep3")]
    assert "rosbag reindex" in skipped[str(folder / "ep2.bag.active")]
    assert "ros2 bag reindex" in skipped[str(folder / "ep3")]
    assert (folder / "ep2.bag.active").exists() and (folder / "ep3").is_dir()  # left as they are


def test_convert_command_passes_rate_to_the_ros_reader(tmp_path, capsys):
    import yaml

    from rfmp_rl.data.convert import main as convert_main

    path = gap_bag("ros1").write(tmp_path / "demo")
    config = tmp_path / "topics.yaml"
    config.write_text(yaml.safe_dump(GAP_CONFIG))  # 10 Hz
    assert convert_main(["ros", str(path), "--config", str(config), "--rate", "5",
                         "--dry-run"]) == 0
    assert ", 5 Hz" in capsys.readouterr().out
