"""Conversion throughput of ``rfmp-convert ros``: messages per second from a bag to a store.

    OMP_NUM_THREADS=1 .venv/bin/python recipes/benchmarks/ros_throughput.py \\
        [--seconds 60] [--formats mcap,sqlite3,ros1] [--repeats 3] [--out results/conversion_ros.md]

Writes one synthetic teleoperation bag per format into a temporary folder: a commanded
``PoseStamped`` and a ``Float64`` gripper command at 100 Hz and a 64x64 JPEG ``CompressedImage``
at 15 Hz, for ``--seconds`` seconds. Then runs the command's entry point,
``rfmp-convert ros BAG --config topics.yaml --out STORE`` (flat ``action`` R3 x S3 x R1 and the
image, resampled to 10 Hz, store written to disk), ``--repeats`` times, and reports the median
wall time and the messages read per second. The first line of the markdown written to ``--out``
is the exact command that produced it.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import math
import os
import platform
import shlex
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from rfmp_rl.data.convert import main as convert_main

ROOT = Path(__file__).resolve().parents[2]

T0 = 1_700_000_000 * 10**9
CONFIG = """rate_hz: 10
topics:
  /camera/compressed: {key: wrist}
action: [/cmd_pose, /gripper_cmd]
action_manifold: R3 x S3 x R1
"""


def write_bag(folder: Path, fmt: str, seconds: float) -> tuple[Path, int]:
    """A teleoperation bag of ``fmt`` (``mcap``, ``sqlite3`` or ``ros1``); returns its path and
    its number of messages."""
    import cv2
    from rosbags.rosbag1 import Writer as Writer1
    from rosbags.rosbag2 import StoragePlugin
    from rosbags.rosbag2 import Writer as Writer2
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC if fmt == "ros1" else Stores.ROS2_HUMBLE)
    t = store.types
    if fmt == "ros1":
        path, writer, serialize = folder / "teleop.bag", None, store.serialize_ros1
        writer = Writer1(path)
    else:
        plugin = StoragePlugin.MCAP if fmt == "mcap" else StoragePlugin.SQLITE3
        path, serialize = folder / f"teleop_{fmt}", store.serialize_cdr
        writer = Writer2(path, version=9, storage_plugin=plugin)

    def header(ns: int):
        stamp = t["builtin_interfaces/msg/Time"](sec=ns // 10**9, nanosec=ns % 10**9)
        if fmt == "ros1":
            return t["std_msgs/msg/Header"](seq=0, stamp=stamp, frame_id="world")
        return t["std_msgs/msg/Header"](stamp=stamp, frame_id="world")

    events = []  # (record time, topic, msgtype, message)
    for k in range(int(seconds * 100) + 1):
        ns = T0 + k * 10_000_000
        s = k / 100
        half = 0.25 * s
        pose = t["geometry_msgs/msg/Pose"](
            position=t["geometry_msgs/msg/Point"](x=0.3 + 0.1 * math.sin(s), y=0.1 * s, z=0.2),
            orientation=t["geometry_msgs/msg/Quaternion"](
                x=0.0, y=0.0, z=math.sin(half), w=math.cos(half)),
        )
        events.append((ns, "/cmd_pose", "geometry_msgs/msg/PoseStamped",
                       t["geometry_msgs/msg/PoseStamped"](header=header(ns), pose=pose)))
        events.append((ns, "/gripper_cmd", "std_msgs/msg/Float64",
                       t["std_msgs/msg/Float64"](data=float(k % 200 < 100))))
    rng = np.random.default_rng(0)
    for k in range(int(seconds * 15) + 1):
        ns = T0 + round(k * 1e9 / 15)
        image = rng.integers(0, 256, (64, 64, 3), dtype=np.uint8)
        ok, jpeg = cv2.imencode(".jpg", image)
        assert ok
        events.append((ns, "/camera/compressed", "sensor_msgs/msg/CompressedImage",
                       t["sensor_msgs/msg/CompressedImage"](
                           header=header(ns), format="jpeg", data=jpeg.reshape(-1))))
    events.sort(key=lambda e: e[0])
    with writer:
        conns = {}
        for _, topic, msgtype, _ in events:
            if topic not in conns:
                conns[topic] = writer.add_connection(topic, msgtype, typestore=store)
        for ns, topic, msgtype, msg in events:
            writer.write(conns[topic], ns, serialize(msg, msgtype))
    return path, len(events)


def measure(fmt: str, seconds: float, repeats: int) -> dict:
    """Median wall time of ``rfmp-convert ros`` on a fresh bag of ``fmt``."""
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        bag, messages = write_bag(folder, fmt, seconds)
        config = folder / "topics.yaml"
        config.write_text(CONFIG)
        times = []
        for _ in range(repeats):
            out = io.StringIO()
            start = time.perf_counter()
            with contextlib.redirect_stdout(out):
                code = convert_main(["ros", str(bag), "--config", str(config),
                                     "--out", str(folder / "store")])
            times.append(time.perf_counter() - start)
            if code != 0:
                raise SystemExit(f"rfmp-convert ros failed on the {fmt} bag (exit {code})")
        steps = int(out.getvalue().split(" steps")[0].rsplit(" ", 1)[-1])
    median = statistics.median(times)
    return {"format": fmt, "messages": messages, "steps": steps, "seconds": median,
            "rate": messages / median}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seconds", type=float, default=60.0, help="length of the bag")
    parser.add_argument("--formats", default="mcap,sqlite3,ros1")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--out", type=Path, default=None, help="markdown file to write")
    args = parser.parse_args()
    load_before = os.getloadavg()[0]
    rows = [measure(fmt, args.seconds, args.repeats) for fmt in args.formats.split(",")]
    load_after = os.getloadavg()[0]
    command = shlex.join([".venv/bin/python", *sys.argv])  # from the repository root
    threads = os.environ.get("OMP_NUM_THREADS")
    if threads is not None:
        command = f"OMP_NUM_THREADS={threads} {command}"
    lines = [
        f"Command: `{command}`",
        "",
        "## `rfmp-convert ros` throughput",
        "",
        f"One synthetic {args.seconds:g} s bag per format: PoseStamped + Float64 at 100 Hz and a "
        "64x64 JPEG CompressedImage at 15 Hz, converted to a store at 10 Hz (flat action "
        "R3 x S3 x R1, decoded images, written to disk); median of "
        f"{args.repeats} runs in one process ({platform.machine()}, Python "
        f"{platform.python_version()}, OMP_NUM_THREADS={threads or 'unset'}), on a "
        f"{os.cpu_count()}-core CPU machine (1-minute load average {load_before:.1f} before, "
        f"{load_after:.1f} after: with a load above {os.cpu_count()} the figures are lower "
        "bounds).",
        "",
        "| format | messages | episode steps | wall time s | messages/s |",
        "|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(f"| {r['format']} | {r['messages']} | {r['steps']} | {r['seconds']:.2f} | "
                     f"{r['rate']:,.0f} |")
    text = "\n".join(lines) + "\n"
    print(text)
    if args.out:
        args.out.write_text(text)


if __name__ == "__main__":
    main()
