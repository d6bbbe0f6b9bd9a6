"""Reader for local LeRobot datasets (on-disk format v2.0/v2.1 and v3.0), read offline.

Both layouts share ``meta/info.json`` (``codebase_version``, ``fps``, ``features``, the
``data_path`` / ``video_path`` templates, ``chunks_size``):

* **v2.x**: one parquet per episode, ``data/chunk-{episode_chunk:03d}/episode_{episode_index:06d}
  .parquet``; one mp4 per episode and camera, ``videos/chunk-{episode_chunk:03d}/{video_key}/
  episode_{episode_index:06d}.mp4`` (a frame sits at the step's own ``timestamp``); episodes
  listed in ``meta/episodes.jsonl`` (``episode_index``, ``length``, ``tasks``), tasks in
  ``meta/tasks.jsonl``.
* **v3.0**: many episodes per file. ``meta/episodes/chunk-*/file-*.parquet`` holds one row per
  episode (``length``, ``data/chunk_index``, ``data/file_index``, ``dataset_from_index``,
  ``dataset_to_index`` and, per camera, ``videos/<key>/chunk_index``, ``file_index``,
  ``from_timestamp``, ``to_timestamp``); ``data/chunk-*/file-*.parquet`` hold the steps of many
  episodes; ``videos/<key>/chunk-*/file-*.mp4`` hold many episodes back to back, an episode's
  frame at ``from_timestamp + timestamp``; tasks in ``meta/tasks.parquet``.

Why not TorchRL's ``LeRobotExperienceReplay`` (torchrl 0.14.1): it reads a raw LeRobot folder only
on its download path (``huggingface_hub.snapshot_download`` plus the ``datasets`` package, i.e.
the network), its ``download=False`` path opens only a copy it converted itself, it decodes video
only through ``torchcodec``, and it places v3.0 frames by cumulative episode length rather than by
``from_timestamp``. So the tables are read with ``pyarrow`` and the videos decoded with PyAV
(``av``), both in ``rfmp_rl[data]``; nothing is downloaded.

Store keys. A LeRobot feature name is split at its dots into a nested key, with a leading
``observation`` written ``obs`` and a leading ``next`` dropped (its value is the step's outcome,
stored per step as robomimic's ``reward``/``done`` are):

=============================  =============================
LeRobot feature                store key
=============================  =============================
``action``                     ``action``
``observation.state``          ``obs/state``
``observation.images.top``     ``obs/images/top``
``next.reward``, ``next.done`` ``reward``, ``done``
``timestamp``                  ``timestamp`` (float64, see below)
``task_index``                 ``task_index`` (int64; texts in the manifest's ``extra``)
=============================  =============================

``episode_index``, ``frame_index`` and ``index`` are used to cut and check episodes, not stored;
string features are skipped. ``keys`` (``--keys`` on the command line) selects features and may
rename them: ``observation.state=obs/agent_pos,action`` (``action`` is always read).

Values: tabular features keep their dtype and the per-step shape ``features[name]["shape"]``
(scalars stored with shape ``[1]`` stay ``(T, 1)``). Images (``dtype: image``, PNG/JPEG bytes in
the parquet) and videos (``dtype: video``) become ``uint8 (T, H, W, C)``, the store's image
layout (`rfmp_rl.data.ContextChunk` hands them to the policy as ``(C, H, W)``). A video frame is
the one whose presentation time is nearest to the step's time in the file; none within half a
frame period (``0.5 / fps``) is an error naming the file, episode and timestamp.
``timestamp`` is LeRobot's column as float64 (exactly its float32 values), minus the episode's
first value when that is not 0.0 (the video lookup still uses the recorded values).

Bad input — a missing ``meta/info.json``, an unknown ``codebase_version``, a missing parquet or
mp4 file, a column whose size disagrees with its feature shape, timestamps not increasing, an
undecodable image or video, an image that is not 8-bit (e.g. a 16-bit depth PNG), a tasks row
without ``task``/``task_index``, a store key nested under another — raises `DataError` naming
the file and, where known, the feature, episode and step.
"""

from __future__ import annotations

import io
import json
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from tensordict import TensorDict
from tensordict.utils import NestedKey

from rfmp_rl.data.episodes import (
    DataError,
    Manifest,
    check_timestamps,
    key_name,
    make_episode,
    parse_key,
)
from rfmp_rl.data.quaternions import (
    QuaternionField,
    canonicalize_episode_quaternions,
    parse_quaternion_fields,
)
from rfmp_rl.keys import TIMESTAMP

__all__ = ["read_lerobot", "lerobot_store_key", "LEROBOT_VERSIONS"]

#: The on-disk format versions this reader knows.
LEROBOT_VERSIONS = ("v2.0", "v2.1", "v3.0")

_BOOKKEEPING = ("episode_index", "frame_index", "index")  # cut and check episodes; not stored


def lerobot_store_key(name: str) -> NestedKey:
    """The store key of a LeRobot feature name (see the module docstring).

    Example:
        >>> lerobot_store_key("observation.images.top"), lerobot_store_key("next.reward")
        (('obs', 'images', 'top'), 'reward')
    """
    parts = [p for p in name.split(".") if p]
    if parts and parts[0] == "observation":
        parts[0] = "obs"
    if len(parts) > 1 and parts[0] == "next":
        parts = parts[1:]
    return parts[0] if len(parts) == 1 else tuple(parts)


def _imports():
    try:
        import av
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ImportError as err:  # pragma: no cover - both ship with rfmp_rl[data]
        raise ImportError("LeRobot datasets need pyarrow and av: pip install 'rfmp_rl[data]'") \
            from err
    return pa, pq, av


@dataclass
class _Dataset:
    root: Path
    info: dict[str, Any]
    version: str
    fps: float
    features: dict[str, dict[str, Any]]
    episodes: list[dict[str, Any]]  # metadata rows, by episode_index
    tasks: dict[int, str] = field(default_factory=dict)

    @property
    def info_file(self) -> str:
        return str(self.root / "meta" / "info.json")

    @property
    def v3(self) -> bool:
        return self.version.startswith("v3")

    def path(self, template_key: str, **fields: Any) -> Path:
        template = self.info.get(template_key)
        if not isinstance(template, str):
            raise DataError(f"no {template_key} template", file=self.info_file, key=template_key)
        try:
            return self.root / template.format(**fields)
        except (KeyError, IndexError, ValueError) as err:
            raise DataError(f"cannot fill the template {template!r}: {err!r}",
                            file=self.info_file, key=template_key) from err


def _read_json(path: Path) -> Any:
    try:
        return json.loads(path.read_text())
    except FileNotFoundError as err:
        raise DataError("missing file", file=str(path)) from err
    except (OSError, json.JSONDecodeError, UnicodeDecodeError) as err:
        raise DataError(f"cannot read as JSON: {err}", file=str(path)) from err


def _read_jsonl(path: Path) -> list[dict[str, Any]]:
    if not path.exists():
        raise DataError("missing file", file=str(path))
    rows = []
    for n, line in enumerate(path.read_text().splitlines()):
        if line.strip():
            try:
                rows.append(json.loads(line))
            except json.JSONDecodeError as err:
                raise DataError(f"line {n + 1} is not JSON: {err}", file=str(path)) from err
    return rows


def _read_table(path: Path, columns: Sequence[str] | None = None):
    _, pq, _ = _imports()
    if not path.exists():
        raise DataError("missing parquet file", file=str(path))
    try:
        return pq.read_table(path, columns=list(columns) if columns is not None else None)
    except Exception as err:  # pyarrow raises ArrowInvalid, OSError, KeyError, ...
        raise DataError(f"cannot read as parquet: {err}", file=str(path)) from err


def _check_episode_rows(rows: list[dict[str, Any]], file: Path) -> None:
    """Every episode row has an integer ``episode_index`` and ``length``."""
    for n, row in enumerate(rows):
        for name in ("episode_index", "length"):
            if name not in row:
                raise DataError(f"episode row {n + 1} lacks {name!r}", file=str(file), key=name)
            try:
                if int(row[name]) != float(row[name]):
                    raise ValueError
            except (TypeError, ValueError, OverflowError) as err:
                raise DataError(f"episode row {n + 1}: {name} must be an integer, got "
                                f"{row[name]!r}", file=str(file), key=name) from err


def _open_dataset(root: Path) -> _Dataset:
    info_path = root / "meta" / "info.json"
    if not root.is_dir():
        raise DataError("no such LeRobot dataset folder", file=str(root))
    if not info_path.exists():
        raise DataError("missing meta/info.json (not a LeRobot dataset folder?)",
                        file=str(info_path))
    info = _read_json(info_path)
    if not isinstance(info, dict):
        raise DataError("expected a JSON object", file=str(info_path))
    version = str(info.get("codebase_version"))
    if version not in LEROBOT_VERSIONS:
        raise DataError(f"unknown codebase_version {info.get('codebase_version')!r}; this reader "
                        f"knows {', '.join(LEROBOT_VERSIONS)}", file=str(info_path),
                        key="codebase_version")
    try:
        fps = float(info["fps"])
        features = dict(info["features"])
    except (KeyError, TypeError, ValueError) as err:
        raise DataError(f"missing or bad field {err}", file=str(info_path)) from err
    if not fps > 0:
        raise DataError(f"fps must be > 0, got {fps}", file=str(info_path), key="fps")
    for name in ("timestamp", "episode_index"):
        if name not in features:
            raise DataError(f"no {name!r} feature", file=str(info_path), key="features")
    meta = root / "meta"
    if version.startswith("v3"):
        files = sorted((meta / "episodes").glob("chunk-*/file-*.parquet"))
        if not files:
            raise DataError("missing episode metadata parquet files",
                            file=str(meta / "episodes" / "chunk-000" / "file-000.parquet"))
        rows = []
        for file in files:
            table = _read_table(file)
            keep = [c for c in table.column_names if not c.startswith("stats/")]
            rows.extend(table.select(keep).to_pylist())
            _check_episode_rows(rows[len(rows) - table.num_rows:], file)
        tasks = {}
        if (meta / "tasks.parquet").exists():
            for row in _read_table(meta / "tasks.parquet").to_pylist():
                text = row.get("task", row.get("__index_level_0__"))
                if "task_index" in row and isinstance(text, str):
                    tasks[int(row["task_index"])] = text
    else:
        rows = _read_jsonl(meta / "episodes.jsonl")
        _check_episode_rows(rows, meta / "episodes.jsonl")
        tasks = {}
        if (meta / "tasks.jsonl").exists():
            for n, r in enumerate(_read_jsonl(meta / "tasks.jsonl")):  # blank lines skipped
                try:
                    tasks[int(r["task_index"])] = str(r["task"])
                except (KeyError, TypeError, ValueError) as err:
                    raise DataError(f"task row {n + 1} ({json.dumps(r)}) needs an integer "
                                    f"'task_index' and a 'task' (bad or missing: {err})",
                                    file=str(meta / "tasks.jsonl")) from err
    rows.sort(key=lambda r: int(r["episode_index"]))
    return _Dataset(root, info, version, fps, features, rows, tasks)


def _select_features(
    ds: _Dataset, keys: Sequence[str] | Mapping[str, str] | None
) -> dict[str, NestedKey]:
    """LeRobot feature name -> store key, for the features to read."""
    if isinstance(keys, str):
        keys = keys.split(",")
    if keys is None:
        names = [n for n, f in ds.features.items()
                 if n not in _BOOKKEEPING and f.get("dtype") != "string"]
        chosen = {n: lerobot_store_key(n) for n in names}
    elif isinstance(keys, Mapping):
        chosen = {n: parse_key(k) for n, k in keys.items()}
    else:
        chosen = {}
        for item in keys:
            name, _, renamed = item.partition("=")
            name = name.strip()
            chosen[name] = parse_key(renamed.strip()) if renamed else lerobot_store_key(name)
    if "action" in ds.features and "action" not in chosen:
        chosen["action"] = "action"
    chosen.pop("timestamp", None)  # always read, as TIMESTAMP
    for name in chosen:
        if name not in ds.features:
            raise DataError(f"no feature {name!r} (features: {', '.join(ds.features)})",
                            file=ds.info_file, key=name)
        if ds.features[name].get("dtype") == "string":
            raise DataError("string features are not stored", file=ds.info_file, key=name)
    stored = [key_name(k) for k in chosen.values()]
    dupes = sorted({k for k in stored if stored.count(k) > 1} | ({TIMESTAMP} & set(stored)))
    if dupes:
        raise DataError(f"two features map to the store key {dupes[0]!r}; rename one with "
                        "--keys name=store/key", file=ds.info_file)
    for outer in stored:
        for inner in stored:
            if inner.startswith(outer + "/"):
                raise DataError(f"the store key {inner!r} would be nested under the store key "
                                f"{outer!r}; rename one with --keys name=store/key",
                                file=ds.info_file)
    return chosen


def _shape(ds: _Dataset, name: str) -> tuple[int, ...]:
    try:
        return tuple(int(s) for s in ds.features[name]["shape"])
    except (KeyError, TypeError, ValueError) as err:
        raise DataError(f"feature has no valid shape: {err!r}", file=ds.info_file,
                        key=name) from err


def _image_hwc(ds: _Dataset, name: str) -> tuple[int, int, int]:
    """The feature's image shape as (H, W, C); LeRobot lists ``names`` to say which is which."""
    shape = _shape(ds, name)
    if len(shape) != 3:
        raise DataError(f"image shape must have 3 dims, got {list(shape)}", file=ds.info_file,
                        key=name)
    names = ds.features[name].get("names") or []
    if isinstance(names, Mapping):  # {"axes": [...]} in some datasets
        names = names.get("axes") or []
    if isinstance(names, list) and names and str(names[0]).lower().startswith("channel"):
        return shape[1], shape[2], shape[0]
    return shape  # (height, width, channels), as LeRobot writes it


def _column(table, name: str, *, file: str, episode: int, shape: tuple[int, ...]) -> np.ndarray:
    """A tabular column -> ``(T, *shape)``, checking every row's size against the feature."""
    pa, _, _ = _imports()
    if name not in table.column_names:
        raise DataError("column missing from the parquet file", file=file, key=name,
                        episode=episode)
    arr = table.column(name).combine_chunks()
    steps = len(arr)
    if arr.null_count:
        raise DataError(f"{arr.null_count} null values", file=file, key=name, episode=episode)
    size = int(np.prod(shape)) if shape else 1
    level, dims = 0, list(shape)
    while pa.types.is_list(arr.type) or pa.types.is_large_list(arr.type) or \
            pa.types.is_fixed_size_list(arr.type):
        lengths = np.asarray(arr.value_lengths() if not pa.types.is_fixed_size_list(arr.type)
                             else [arr.type.list_size] * len(arr))
        want = dims[level] if level < len(dims) else None
        if want is None or (lengths != want).any():
            bad = int(np.argmax(lengths != want)) if want is not None else 0
            raise DataError(
                f"per-step shape disagrees with the feature shape {list(shape)} in "
                f"meta/info.json (a list of {lengths[bad]} values at level {level})",
                file=file, key=name, episode=episode, step=bad if level == 0 else None,
            )
        arr = arr.flatten()
        level += 1
    values = arr.to_numpy(zero_copy_only=False)
    if values.size != steps * size:
        raise DataError(f"{values.size // max(steps, 1)} values per step, but the feature shape "
                        f"in meta/info.json is {list(shape)}", file=file, key=name,
                        episode=episode)
    if not values.flags.writeable:  # pyarrow's zero-copy view
        values = values.copy()
    return values.reshape(steps, *shape)


def _images(table, name: str, hwc: tuple[int, int, int], *, file: str,
            episode: int) -> np.ndarray:
    from PIL import Image

    if name not in table.column_names:
        raise DataError("column missing from the parquet file", file=file, key=name,
                        episode=episode)
    rows = table.column(name).to_pylist()
    out = np.empty((len(rows), *hwc), dtype=np.uint8)
    for step, row in enumerate(rows):
        data = row.get("bytes") if isinstance(row, dict) else row
        if not data:
            raise DataError("image without embedded bytes", file=file, key=name,
                            episode=episode, step=step)
        try:
            with Image.open(io.BytesIO(data)) as img:
                pixels = np.asarray(img)
        except Exception as err:  # PIL raises several types for bad bytes
            raise DataError(f"cannot decode the image: {err}", file=file, key=name,
                            episode=episode, step=step) from err
        if pixels.dtype != np.uint8:
            raise DataError(f"a {pixels.dtype} image: only 8-bit images are supported",
                            file=file, key=name, episode=episode, step=step)
        if pixels.ndim == 2:
            pixels = pixels[:, :, None]
        if pixels.shape != hwc:
            raise DataError(f"image shape {list(pixels.shape)} (H, W, C) disagrees with the "
                            f"feature shape in meta/info.json ({list(hwc)} as H, W, C)",
                            file=file, key=name, episode=episode, step=step)
        out[step] = pixels
    return out


def _decode_video(path: Path, times: np.ndarray, hwc: tuple[int, int, int], fps: float, *,
                  key: str, episode: int) -> np.ndarray:
    """Frames of ``path`` nearest to ``times`` (seconds in the file, increasing) -> ``uint8
    (N, H, W, C)``; the nearest must lie within half a frame period."""
    _, _, av = _imports()
    file = str(path)
    if not path.exists():
        raise DataError("missing video file", file=file, key=key, episode=episode)
    out = np.empty((len(times), *hwc), dtype=np.uint8)
    tolerance = 0.5 / fps
    fmt = {1: "gray", 3: "rgb24"}.get(hwc[2])
    if fmt is None:
        raise DataError(f"video frames must have 1 or 3 channels, the feature has {hwc[2]}",
                        file=file, key=key, episode=episode)

    def take(i: int, frame_time: float, frame) -> None:
        if abs(frame_time - times[i]) > tolerance:
            raise DataError(
                f"no frame within half a frame period ({tolerance:g} s) of timestamp "
                f"{times[i]:.6f} s (nearest at {frame_time:.6f} s)",
                file=file, key=key, episode=episode, step=i,
            )
        pixels = frame.to_ndarray(format=fmt)
        if pixels.ndim == 2:
            pixels = pixels[:, :, None]
        if pixels.shape != hwc:
            raise DataError(f"frame shape {list(pixels.shape)} (H, W, C) disagrees with the "
                            f"feature shape in meta/info.json ({list(hwc)} as H, W, C)",
                            file=file, key=key, episode=episode, step=i)
        out[i] = pixels

    try:
        with av.open(file) as container:
            if not container.streams.video:
                raise DataError("no video stream", file=file, key=key, episode=episode)
            stream = container.streams.video[0]
            base = float(stream.time_base)
            start = float(times[0]) - tolerance
            if start > 0:  # to the key frame at or before the first wanted time
                container.seek(int(start / base), stream=stream, backward=True)
            i, prev = 0, None  # prev: (time, frame) of the last frame before times[i]
            for frame in container.decode(stream):
                if frame.pts is None:
                    continue
                now = frame.pts * base
                while i < len(times) and now >= times[i]:
                    if prev is not None and times[i] - prev[0] <= now - times[i]:
                        take(i, *prev)
                    else:
                        take(i, now, frame)
                    i += 1
                if i == len(times):
                    break
                prev = (now, frame)
            while i < len(times):  # past the last frame
                if prev is None:
                    raise DataError(f"no frame at or after timestamp {times[i]:.6f} s",
                                    file=file, key=key, episode=episode, step=i)
                take(i, *prev)
                i += 1
    except DataError:
        raise
    except Exception as err:  # av.error.* for damaged or non-video files
        raise DataError(f"cannot decode the video: {err}", file=file, key=key,
                        episode=episode) from err
    return out


def _episode_table(ds: _Dataset, row: dict[str, Any], columns: list[str],
                   cache: dict[Path, Any]) -> tuple[Any, Path]:
    """The steps of one episode as a pyarrow table, and the parquet file they came from."""
    pa, _, _ = _imports()
    import pyarrow.compute as pc

    ep = int(row["episode_index"])
    if ds.v3:
        try:
            path = ds.path("data_path", chunk_index=int(row["data/chunk_index"]),
                           file_index=int(row["data/file_index"]))
        except KeyError as err:
            raise DataError(f"episode row lacks {err}", file=str(ds.root / "meta" / "episodes"),
                            episode=ep) from err
    else:
        chunk = ep // int(ds.info.get("chunks_size", 1000))
        path = ds.path("data_path", episode_chunk=chunk, episode_index=ep)
    if path not in cache:
        if len(cache) > 2:  # v3 episodes come in file order: keep a few tables
            cache.pop(next(iter(cache)))
        _, pq, _ = _imports()
        try:
            names = pq.read_schema(path).names
        except Exception:  # missing or unreadable: _read_table says which
            names = _read_table(path).column_names
        missing = [c for c in columns if c not in names]
        if missing:
            raise DataError("column missing from the parquet file", file=str(path),
                            key=missing[0], episode=ep)
        cache[path] = _read_table(path, columns)  # only the selected features' columns
    table = cache[path]
    mask = pc.equal(table.column("episode_index"), pa.scalar(ep, table.schema.field(
        "episode_index").type))
    table = table.filter(mask)
    if "index" in table.column_names and ds.v3 and "dataset_from_index" in row:
        index = table.column("index").to_numpy()
        lo, hi = int(row["dataset_from_index"]), int(row["dataset_to_index"])
        if len(index) and (index[0] != lo or index[-1] != hi - 1):
            raise DataError(f"rows hold index {index[0]}..{index[-1]}, but the episode metadata "
                            f"says {lo}..{hi - 1}", file=str(path), key="index", episode=ep)
    if table.num_rows != int(row["length"]):
        raise DataError(f"{table.num_rows} rows, but the episode metadata says length "
                        f"{int(row['length'])}", file=str(path), key="episode_index", episode=ep)
    return table, path


def read_lerobot(
    path: str | os.PathLike[str],
    *,
    episodes: Sequence[int] | None = None,
    keys: Sequence[str] | Mapping[str, str] | str | None = None,
    quaternions: str | Sequence[str | QuaternionField] | None = None,
    raw_quaternion_signs: bool = False,
) -> tuple[list[TensorDict], Manifest]:
    """Read a local LeRobot dataset folder (format v2.0, v2.1 or v3.0) into episodes.

    Args:
        path: the dataset folder (holding ``meta/info.json``).
        episodes: ``episode_index`` values to read, in the given order (default: all, in
            index order).
        keys: the features to read, each ``name`` or ``name=store/key`` (a list, a
            comma-separated string, or a ``{name: store key}`` mapping); default: every
            feature but the bookkeeping and string ones. ``action`` and ``timestamp`` are always
            read.
        quaternions: quaternion fields by store key (after renaming), a spec
            ``"KEY[a:b][:ORDER],..."`` or a list (`rfmp_rl.data.quaternions`): each episode's
            first sample is put at ``w >= 0``, then its signs are made continuous.
        raw_quaternion_signs: keep the recorded quaternion signs.

    Returns:
        ``(episodes, manifest)``: TensorDicts of batch ``[T]`` keyed as in the module docstring;
        the manifest has ``format="lerobot"``, ``rate_hz`` = ``fps``, and ``extra`` with
        ``codebase_version``, ``features`` (LeRobot name -> store key), ``image_keys``,
        ``video_keys``, ``tasks`` (index -> text) and ``robot_type``.

    Raises:
        DataError: see the module docstring.

    Example:
        >>> read_lerobot("no/such/folder")
        Traceback (most recent call last):
        ...
        rfmp_rl.data.episodes.DataError: no/such/folder: no such LeRobot dataset folder
    """
    quats = parse_quaternion_fields(quaternions)
    root = Path(path)
    ds = _open_dataset(root)
    chosen = _select_features(ds, keys)
    by_index = {int(r["episode_index"]): r for r in ds.episodes}
    if episodes is None:
        wanted = sorted(by_index)
    else:
        wanted = [int(e) for e in episodes]
        for n, e in enumerate(wanted):
            if e in wanted[:n]:
                raise DataError(f"episode {e} is asked for twice", file=str(root / "meta"),
                                episode=e)
            if e not in by_index:
                raise DataError(f"episode {e} is not in the dataset (it has "
                                f"{len(by_index)} episodes, indices {min(by_index, default=0)}.."
                                f"{max(by_index, default=-1)})", file=str(root / "meta"),
                                episode=e)
    if not wanted:
        raise DataError("no episodes to read", file=str(root / "meta"))
    kinds = {n: ds.features[n].get("dtype") for n in chosen}
    tabular = [n for n, k in kinds.items() if k not in ("image", "video")]
    images = [n for n, k in kinds.items() if k == "image"]
    videos = [n for n, k in kinds.items() if k == "video"]
    columns = ["timestamp", "episode_index", *tabular, *images]
    if "index" in ds.features:
        columns.append("index")
    manifest = Manifest(source=str(root), format="lerobot", rate_hz=ds.fps)
    manifest.extra.update(
        codebase_version=ds.version,
        features={n: key_name(k) for n, k in chosen.items()},
        image_keys=[key_name(chosen[n]) for n in images],
        video_keys=[key_name(chosen[n]) for n in videos],
        tasks=ds.tasks,
        robot_type=ds.info.get("robot_type"),
    )
    cache: dict[Path, Any] = {}
    out = []
    for ep in wanted:
        row = by_index[ep]
        table, parquet = _episode_table(ds, row, list(dict.fromkeys(columns)), cache)
        file = str(parquet)
        recorded = _column(table, "timestamp", file=file, episode=ep, shape=())
        recorded = recorded.astype(np.float64)  # LeRobot's float32 values, exactly
        shifted = recorded - recorded[0] if len(recorded) else recorded
        check_timestamps(shifted, file=file, key="timestamp", episode=ep)
        arrays: dict[NestedKey, np.ndarray] = {TIMESTAMP: shifted}
        for name in tabular:
            arrays[chosen[name]] = _column(table, name, file=file, episode=ep,
                                           shape=_shape(ds, name))
        for name in images:
            arrays[chosen[name]] = _images(table, name, _image_hwc(ds, name), file=file,
                                           episode=ep)
        for name in videos:
            if ds.v3:
                try:
                    video = ds.path("video_path", video_key=name,
                                    chunk_index=int(row[f"videos/{name}/chunk_index"]),
                                    file_index=int(row[f"videos/{name}/file_index"]))
                    offset = float(row[f"videos/{name}/from_timestamp"])
                except (KeyError, TypeError) as err:
                    raise DataError(f"episode row lacks {err}", key=name, episode=ep,
                                    file=str(root / "meta" / "episodes")) from err
            else:
                chunk = ep // int(ds.info.get("chunks_size", 1000))
                video = ds.path("video_path", episode_chunk=chunk, video_key=name,
                                episode_index=ep)
                offset = 0.0
            arrays[chosen[name]] = _decode_video(video, offset + recorded, _image_hwc(ds, name),
                                                 ds.fps, key=name, episode=ep)
        episode = make_episode(arrays, file=file, episode=ep)
        manifest.add(episode, name=ep)
        out.append(episode)
    if quats:
        canonicalize_episode_quaternions(out, manifest, quats, raw=raw_quaternion_signs)
    return out, manifest
