"""Writes small LeRobot datasets (on-disk format v2.1 or v3.0) for the reader's tests and the
conversion benchmark: tables with pyarrow, PNG images with Pillow, mp4 videos with PyAV.

Frames carry distinct, structured content (smooth gradients and a block whose place and colour
depend on the episode and step), so a wrong frame, a wrong episode or a swapped channel shows as
a large pixel error.
"""

from __future__ import annotations

import io
import json
from collections.abc import Sequence
from fractions import Fraction
from pathlib import Path

import numpy as np

TASK = "push the block"


def frame(episode: int, step: int, height: int = 32, width: int = 32) -> np.ndarray:
    """``uint8 (H, W, 3)``: a brightness ramp with a 10x10 block, bright or dark, placed by
    (episode, step), tinted by the episode. The colour varies smoothly (as in camera
    images), so yuv420p's halved chroma resolution costs little; the detail is in brightness."""
    y, x = np.mgrid[0:height, 0:width]
    luma = 40 + 100 * x / max(width - 1, 1) + 40 * y / max(height - 1, 1)
    size = 10
    top = (2 * step) % max(height - size, 1)
    left = (6 * episode + 4 * step) % max(width - size, 1)
    luma[top:top + size, left:left + size] = 215 if (step + episode) % 2 == 0 else 30
    tint = np.array([12.0 * (episode % 3) - 12, 6.0 * ((step // 4) % 3) - 6,
                     8.0 - 8 * (episode % 3)])
    return np.clip(luma[:, :, None] + tint, 0, 255).round().astype(np.uint8)


def make_episodes(lengths: Sequence[int], fps: float, *, video_key: str | None = None,
                  image_key: str | None = None, size: int = 32, jitter: bool = False,
                  seed: int = 0) -> list[dict[str, np.ndarray]]:
    """Per-episode arrays under LeRobot feature names: ``observation.state (T, 3)`` and
    ``action (T, 2)`` float32, ``next.reward (T,)`` float32, ``timestamp (T,)`` float32 (step /
    fps, optionally moved by up to 0.05 frame periods so that it is not a plain step count),
    and the image / video frames ``(T, H, W, 3)``."""
    rng = np.random.default_rng(seed)
    out = []
    for e, n in enumerate(lengths):
        ts = np.arange(n) / fps
        if jitter:
            ts[1:] += rng.uniform(-0.05, 0.05, n - 1) / fps
        ep = {
            "observation.state": rng.standard_normal((n, 3)).astype(np.float32),
            "action": rng.standard_normal((n, 2)).astype(np.float32),
            "next.reward": rng.random(n).astype(np.float32),
            "timestamp": ts.astype(np.float32),
        }
        frames = np.stack([frame(e, i, size, size) for i in range(n)])
        if image_key:
            ep[image_key] = frames[:, ::-1].copy()  # another picture than the video's
        if video_key:
            ep[video_key] = frames
        out.append(ep)
    return out


def _png(img: np.ndarray) -> bytes:
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(img).save(buf, format="PNG")
    return buf.getvalue()


def encode_video(path: Path, frames: np.ndarray, fps: float, codec: str = "libx264",
                 crf: int = 12) -> None:
    """Frames ``(N, H, W, 3)`` at ``pts = i`` in a 1/fps time base (yuv420p)."""
    import av

    path.parent.mkdir(parents=True, exist_ok=True)
    with av.open(str(path), "w") as container:
        rate = Fraction(fps).limit_denominator(1000)
        stream = container.add_stream(codec, rate=rate)
        stream.height, stream.width = frames.shape[1:3]
        stream.pix_fmt = "yuv420p"
        stream.options = {"crf": str(crf)} if codec == "libx264" else {"qscale": "2"}
        for i, img in enumerate(frames):
            vf = av.VideoFrame.from_ndarray(np.ascontiguousarray(img), format="rgb24")
            vf.pts = i
            vf.time_base = 1 / rate
            for packet in stream.encode(vf):
                container.mux(packet)
        for packet in stream.encode():
            container.mux(packet)


def _feature(values: np.ndarray, name: str, kind: str | None) -> dict:
    if kind in ("image", "video"):
        h, w, c = values.shape[1:]
        feat = {"dtype": kind, "shape": [h, w, c], "names": ["height", "width", "channels"]}
        return feat
    shape = list(values.shape[1:]) or [1]
    return {"dtype": str(values.dtype), "shape": shape, "names": None}


def _table(episodes: Sequence[dict[str, np.ndarray]], indices: Sequence[int], first_index: int,
           kinds: dict[str, str]):
    import pyarrow as pa

    columns: dict[str, list] = {}
    for e, ep in zip(indices, episodes, strict=True):
        n = len(ep["timestamp"])
        for name, values in ep.items():
            kind = kinds.get(name)
            if kind == "video":
                continue
            if kind == "image":
                col = [{"bytes": _png(img), "path": None} for img in values]
            else:
                col = list(values)
            columns.setdefault(name, []).extend(col)
        columns.setdefault("frame_index", []).extend(range(n))
        columns.setdefault("episode_index", []).extend([e] * n)
        columns.setdefault("task_index", []).extend([0] * n)
    total = len(columns["frame_index"])
    columns["index"] = list(range(first_index, first_index + total))
    arrays = {}
    for name, col in columns.items():
        kind = kinds.get(name)
        if kind == "image":
            arrays[name] = pa.array(col, type=pa.struct([("bytes", pa.binary()),
                                                         ("path", pa.string())]))
        elif name in ("frame_index", "episode_index", "task_index", "index"):
            arrays[name] = pa.array(col, type=pa.int64())
        elif np.ndim(col[0]) == 0:
            arrays[name] = pa.array(np.asarray(col))
        else:
            flat = np.asarray(col)
            arrays[name] = pa.array(list(flat), type=pa.list_(pa.from_numpy_dtype(flat.dtype)))
    return pa.table(arrays)


def write_lerobot(root: Path, episodes: Sequence[dict[str, np.ndarray]], *, version: str,
                  fps: float, video_keys: Sequence[str] = (), image_keys: Sequence[str] = (),
                  codec: str = "libx264") -> Path:
    """Write ``episodes`` (from `make_episodes`, or any dicts of LeRobot feature -> array with
    a float32 ``timestamp``) as a LeRobot dataset of ``version`` "v2.1" or "v3.0" under
    ``root``. v3.0 puts every episode in one data parquet and one mp4 per video key."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    root = Path(root)
    (root / "meta").mkdir(parents=True, exist_ok=True)
    kinds = {k: "video" for k in video_keys} | {k: "image" for k in image_keys}
    first = episodes[0]
    features = {name: _feature(values, name, kinds.get(name)) for name, values in first.items()}
    features["timestamp"] = {"dtype": "float32", "shape": [1], "names": None}
    for name in ("frame_index", "episode_index", "index", "task_index"):
        features[name] = {"dtype": "int64", "shape": [1], "names": None}
    lengths = [len(ep["timestamp"]) for ep in episodes]
    info = {
        "codebase_version": version, "robot_type": "fixture", "total_episodes": len(episodes),
        "total_frames": sum(lengths), "total_tasks": 1, "chunks_size": 1000, "fps": fps,
        "splits": {"train": f"0:{len(episodes)}"}, "features": features,
    }
    if version == "v3.0":
        info["data_path"] = "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
        info["video_path"] = ("videos/{video_key}/chunk-{chunk_index:03d}/"
                              "file-{file_index:03d}.mp4") if video_keys else None
        data = root / "data" / "chunk-000" / "file-000.parquet"
        data.parent.mkdir(parents=True, exist_ok=True)
        pq.write_table(_table(episodes, range(len(episodes)), 0, kinds), data)
        rows, start = [], 0
        for e, n in enumerate(lengths):
            row = {"episode_index": e, "tasks": [TASK], "length": n, "data/chunk_index": 0,
                   "data/file_index": 0, "dataset_from_index": start,
                   "dataset_to_index": start + n}
            for key in video_keys:
                row |= {f"videos/{key}/chunk_index": 0, f"videos/{key}/file_index": 0,
                        f"videos/{key}/from_timestamp": start / fps,
                        f"videos/{key}/to_timestamp": (start + n) / fps}
            rows.append(row)
            start += n
        meta = root / "meta" / "episodes" / "chunk-000" / "file-000.parquet"
        meta.parent.mkdir(parents=True, exist_ok=True)
        pq.write_table(pa.Table.from_pylist(rows), meta)
        pq.write_table(pa.table({"task_index": pa.array([0], pa.int64()),
                                 "__index_level_0__": [TASK]}), root / "meta" / "tasks.parquet")
        for key in video_keys:
            encode_video(root / "videos" / key / "chunk-000" / "file-000.mp4",
                         np.concatenate([ep[key] for ep in episodes]), fps, codec)
    elif version == "v2.1":
        info["data_path"] = "data/chunk-{episode_chunk:03d}/episode_{episode_index:06d}.parquet"
        info["video_path"] = ("videos/chunk-{episode_chunk:03d}/{video_key}/"
                              "episode_{episode_index:06d}.mp4") if video_keys else None
        start = 0
        for e, ep in enumerate(episodes):
            data = root / "data" / "chunk-000" / f"episode_{e:06d}.parquet"
            data.parent.mkdir(parents=True, exist_ok=True)
            pq.write_table(_table([ep], [e], start, kinds), data)
            start += lengths[e]
            for key in video_keys:
                encode_video(root / "videos" / "chunk-000" / key / f"episode_{e:06d}.mp4",
                             ep[key], fps, codec)
        (root / "meta" / "episodes.jsonl").write_text("".join(
            json.dumps({"episode_index": e, "tasks": [TASK], "length": n}) + "\n"
            for e, n in enumerate(lengths)))
        (root / "meta" / "tasks.jsonl").write_text(
            json.dumps({"task_index": 0, "task": TASK}) + "\n")
    else:
        raise ValueError(f"version must be v2.1 or v3.0, got {version}")
    (root / "meta" / "info.json").write_text(json.dumps(info, indent=2))
    return root
