"""Reader for Diffusion Policy's zarr replay buffers (also the layout LeRobot's Push-T export uses).

Layout: ``data/<key>`` arrays with steps on axis 0 (``img (N, H, W, 3)``, ``state``, ``keypoint``,
``action``, ...) and ``meta/episode_ends (E,)``: the exclusive end index of every episode, so
episode ``e`` is ``[episode_ends[e-1], episode_ends[e])``. Diffusion Policy's Push-T set
(``pusht_cchi_v7_replay.zarr``: 206 episodes, 25,650 steps at 10 Hz) stores its 96x96 images as
float32 holding integers in [0, 255]; they are converted to ``uint8`` here (a non-integral or
out-of-range pixel is an error, not a silent rounding).

The store has no clock: each episode gets ``timestamp`` = ``step / rate_hz`` (float64, from 0.0)
at the rate given to `read_dp_zarr` (Push-T's 10 Hz by default); with ``rate_hz=None`` no
timestamps are written.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
from tensordict import TensorDict

from rfmp_rl.data.episodes import (
    DataError,
    Manifest,
    check_finite,
    make_episode,
    step_timestamps,
)
from rfmp_rl.data.quaternions import (
    QuaternionField,
    canonicalize_episode_quaternions,
    parse_quaternion_fields,
)
from rfmp_rl.keys import TIMESTAMP

__all__ = ["read_dp_zarr", "write_dp_zarr", "PUSHT_RATE_HZ"]

#: Push-T's control rate (Diffusion Policy's ``fps`` for the Push-T env).
PUSHT_RATE_HZ = 10.0

_BLOCK = 4096  # rows decoded at a time


def _open(path: Path):
    import zarr

    if not path.exists():
        raise DataError("no such zarr store (set the data path in the config)", file=str(path))
    try:
        return zarr.open_group(str(path), mode="r")
    except Exception as err:  # zarr raises several types for a damaged store
        raise DataError(f"cannot open as a zarr group: {err}", file=str(path)) from err


def _is_image(name: str, arr) -> bool:
    return len(arr.shape) == 4 and arr.shape[-1] in (1, 3, 4)


def read_dp_zarr(
    path: str | Path,
    keys: Sequence[str] | None = None,
    *,
    image_keys: Sequence[str] | None = None,
    rate_hz: float | None = PUSHT_RATE_HZ,
    quaternions: str | Sequence[str | QuaternionField] | None = None,
    raw_quaternion_signs: bool = False,
) -> tuple[list[TensorDict], Manifest]:
    """Read a Diffusion Policy zarr replay buffer into episodes.

    Args:
        path: the ``.zarr`` folder.
        keys: the ``data/`` arrays to read (default: all). ``action`` is always read.
        image_keys: arrays to treat as images (``uint8 (T, H, W, C)``); default: every 4-D array
            whose last axis is 1, 3 or 4.
        rate_hz: the control rate to record in the manifest (Push-T: 10 Hz); each episode's
            ``timestamp`` is ``step / rate_hz``. ``None``: unknown, no timestamps.
        quaternions: further quaternion fields, a spec ``"KEY[a:b][:ORDER],..."`` or a list
            (`rfmp_rl.data.quaternions`): each episode's first sample is put at ``w >= 0``,
            then its signs are made continuous.
        raw_quaternion_signs: keep the recorded quaternion signs.

    Returns:
        ``(episodes, manifest)``; episode keys keep the store's names.

    Raises:
        DataError: a missing store, group or key; episode ends that are not increasing or do not
            end at the arrays' length; arrays of different lengths; NaN/inf; an image value that
            is not an integer in [0, 255]; a corrupt chunk. Each names the file, key, episode and
            step where known.

    Example:
        >>> import tempfile
        >>> tmp = tempfile.mkdtemp()
        >>> write_dp_zarr(f"{tmp}/d.zarr", {"action": np.zeros((5, 2), np.float32),
        ...               "img": np.zeros((5, 4, 4, 3), np.float32)}, episode_ends=[3, 5])
        >>> eps, manifest = read_dp_zarr(f"{tmp}/d.zarr")
        >>> [ep.batch_size[0] for ep in eps], eps[0]["img"].dtype, manifest.steps
        ([3, 2], torch.uint8, 5)
    """
    quats = parse_quaternion_fields(quaternions)
    path = Path(path)
    root = _open(path)
    file = str(path)
    try:
        data, meta = root["data"], root["meta"]
    except KeyError as err:
        raise DataError(f"missing group {err} (expected data/ and meta/)", file=file) from err
    try:
        ends = np.asarray(meta["episode_ends"][:], dtype=np.int64)
    except KeyError as err:
        raise DataError("missing array", file=file, key="meta/episode_ends") from err
    available = sorted(data.array_keys())
    names = list(available if keys is None else keys)
    if "action" not in names:
        names.append("action")
    for name in names:
        if name not in available:
            raise DataError(
                f"missing array (available: {', '.join(available)})", file=file, key=f"data/{name}"
            )
    arrays = {name: data[name] for name in names}
    if image_keys is None:
        image_keys = [n for n, a in arrays.items() if _is_image(n, a)]
    lengths = {name: int(a.shape[0]) for name, a in arrays.items()}
    total = lengths["action"]
    starts = np.concatenate([[0], ends[:-1]]) if len(ends) else np.zeros(0, np.int64)
    for e, (start, end) in enumerate(zip(starts, ends, strict=True)):
        if end <= start:
            raise DataError(
                f"episode_ends[{e}] = {end} does not exceed the previous end {start} "
                "(empty or reversed episode)", file=file, key="meta/episode_ends", episode=e,
            )
    if len(ends) == 0:
        raise DataError("no episodes (meta/episode_ends is empty)", file=file)
    for name, n in lengths.items():
        if n != int(ends[-1]):
            last = int(np.searchsorted(ends, n, side="right")) if n < ends[-1] else len(ends) - 1
            raise DataError(
                f"{n} steps, but meta/episode_ends ends at {int(ends[-1])} (data/action has "
                f"{total})", file=file, key=f"data/{name}", episode=last,
                step=n - int(starts[min(last, len(ends) - 1)]),
            )
    manifest = Manifest(source=file, format="dp_zarr", rate_hz=rate_hz)
    manifest.extra["image_keys"] = list(image_keys)
    decoded: dict[str, np.ndarray] = {}
    for name, arr in arrays.items():
        blocks = []
        for lo in range(0, total, _BLOCK):
            hi = min(lo + _BLOCK, total)
            try:
                block = np.asarray(arr[lo:hi])
            except Exception as err:
                e = int(np.searchsorted(ends, lo, side="right"))
                raise DataError(
                    f"cannot decode rows {lo}..{hi - 1}: {err}", file=file, key=f"data/{name}",
                    episode=e, step=lo - int(starts[e]),
                ) from err
            if name in image_keys:
                block = _to_uint8(block, file, name, lo, starts, ends)
            blocks.append(block)
        decoded[name] = np.concatenate(blocks) if len(blocks) > 1 else blocks[0]
    episodes = []
    for e, (start, end) in enumerate(zip(starts, ends, strict=True)):
        for name, values in decoded.items():
            check_finite(values[start:end], file=file, key=f"data/{name}", episode=e)
        arrays = {n: v[start:end] for n, v in decoded.items()}
        if rate_hz is not None:
            arrays[TIMESTAMP] = step_timestamps(end - start, rate_hz)
        ep = make_episode(arrays, file=file, episode=e)
        manifest.add(ep, name=e)
        episodes.append(ep)
    if quats:
        canonicalize_episode_quaternions(episodes, manifest, quats, raw=raw_quaternion_signs)
    return episodes, manifest


def _to_uint8(block, file, name, lo, starts, ends) -> np.ndarray:
    if block.dtype == np.uint8:
        return block
    flat = block.reshape(block.shape[0], -1)
    bad = ~(np.isfinite(flat) & (flat >= 0) & (flat <= 255) & (flat == np.round(flat))).all(1)
    if bad.any():
        row = lo + int(np.argmax(bad))
        e = int(np.searchsorted(ends, row, side="right"))
        values = flat[int(np.argmax(bad))]
        value = values[~(np.isfinite(values) & (values >= 0) & (values <= 255)
                         & (values == np.round(values)))][0]
        raise DataError(
            f"image value {value} is not an integer in [0, 255]", file=file, key=f"data/{name}",
            episode=e, step=row - int(starts[e]),
        )
    return block.astype(np.uint8)


def write_dp_zarr(
    path: str | Path, arrays: dict[str, np.ndarray], episode_ends: Sequence[int]
) -> None:
    """Write arrays in Diffusion Policy's zarr layout (zarr format 2, as DP writes it).

    Meant for tests and for exporting a store to DP/LeRobot tools.
    """
    import zarr

    root = zarr.open_group(str(path), mode="w", zarr_format=2)
    data = root.create_group("data")
    for name, values in arrays.items():
        values = np.asarray(values)
        data.create_array(name, shape=values.shape, dtype=values.dtype,
                          chunks=(min(len(values), 161), *values.shape[1:]))
        data[name][:] = values
    meta = root.create_group("meta")
    ends = np.asarray(episode_ends, dtype=np.int64)
    meta.create_array("episode_ends", shape=ends.shape, dtype=ends.dtype)
    meta["episode_ends"][:] = ends
