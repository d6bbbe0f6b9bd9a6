"""Reader for local Minari datasets (Farama's offline-RL format), read offline with h5py.

Where: a dataset id such as ``D4RL/door/human-v2`` names the folder
``$MINARI_DATASETS_PATH/<id>/`` (``~/.minari/datasets/<id>/`` when the variable is unset, as
Minari does); a path to that folder, to its ``data/`` folder or to ``main_data.hdf5`` works too.
Nothing is ever downloaded: a dataset that is not on disk is refused with a `DataError` that
says where it was looked for (fetch it first with ``minari download <id>``).

Layout (Minari 0.5, ``data_format: hdf5``): ``data/metadata.json`` (``dataset_id``,
``total_episodes``, ``total_steps``, spaces, ...) and ``data/main_data.hdf5`` with one group
``episode_<id>`` per episode holding ``observations`` (a dataset, or a group of them for
``Dict`` spaces), ``actions``, ``rewards``, ``terminations``, ``truncations`` and ``infos``.

Alignment: Minari stores ``T + 1`` observations (the reset observation, then one after each
step) and ``T`` actions per episode. Step ``i`` of the store pairs ``o_i`` with ``a_i`` (the
action taken after observing ``o_i``) and with the ``reward``, ``terminated``, ``truncated``
(``(T, 1)``) that action produced; the final observation ``o_T``, which no action follows, is
dropped. Store keys: ``observation`` (``observation/<name>`` for a Dict space), ``action``,
``reward``, ``terminated``, ``truncated``; ``infos`` are not read. Non-numeric observation
entries (e.g. MiniGrid's ``mission`` text) are not stored: they are listed in the manifest's
``extra["skipped_keys"]`` (store key -> reason) and printed with it. Minari records no control
rate, so there are no timestamps unless ``rate_hz`` is given (then ``step / rate_hz``).

Why not TorchRL's ``MinariExperienceReplay`` (torchrl 0.14.1): with
``load_from_local_minari=True`` it does read the local HDF5 file without a download, but it then
writes its memory-mapped copy with ``TensorDict.memmap_like``, which allocates the files without
copying the values, so every entry reads back as zero (checked on a Minari-written dataset).
The layout is small, so it is read here directly with h5py (``rfmp_rl[data]``).

Franka Kitchen: `rfmp_rl.envs.kitchen.kitchen_episodes` reads ``D4RL/kitchen`` (and the
kitchen recipe's expert datasets, written in the same layout) through this reader and turns
them into `rfmp_rl.envs.kitchen.FrankaKitchenEnv`'s observations and end-effector pose actions.
"""

from __future__ import annotations

import json
import os
import re
from collections.abc import Sequence
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
from tensordict import TensorDict

from rfmp_rl.data.episodes import DataError, Manifest, key_name, make_episode, step_timestamps
from rfmp_rl.data.quaternions import (
    QuaternionField,
    canonicalize_episode_quaternions,
    parse_quaternion_fields,
)
from rfmp_rl.keys import ACTION, OBSERVATION, TIMESTAMP

__all__ = ["read_minari", "minari_dataset_path"]

_EPISODE_RE = re.compile(r"^episode_(\d+)$")


def minari_dataset_path(source: str | os.PathLike[str]) -> Path:
    """The ``data/`` folder of a Minari dataset given by id or path (see the module docstring).

    Example:
        >>> minari_dataset_path("/no/such/root/toy/counter-v0")
        Traceback (most recent call last):
        ...
        rfmp_rl.data.episodes.DataError: /no/such/root/toy/counter-v0: Minari dataset not found...
    """
    path = Path(source)
    if path.name == "main_data.hdf5":
        path = path.parent
    candidates = [path / "data", path] if path.name != "data" else [path]
    if not path.is_absolute() and not path.exists():
        root = Path(os.environ.get("MINARI_DATASETS_PATH",
                                   Path("~/.minari/datasets").expanduser()))
        candidates.insert(0, root / str(source) / "data")
    for folder in candidates:
        if (folder / "main_data.hdf5").is_file():
            return folder
    looked = ", ".join(str(c / "main_data.hdf5") for c in candidates)
    raise DataError(f"Minari dataset not found on disk (looked for {looked}); nothing is "
                    "downloaded: fetch it first (`minari download <id>`) or set "
                    "MINARI_DATASETS_PATH", file=str(source))


class _NonNumeric(NamedTuple):
    """An observation leaf that is not stored (e.g. MiniGrid's ``mission`` text)."""

    dtype: str


def _read(group, name: str, *, file: str, episode: str, skip_non_numeric: bool = False) -> Any:
    import h5py

    item = group.get(name)
    if item is None:
        raise DataError("missing from the episode", file=file, key=name, episode=episode)
    if isinstance(item, h5py.Group):
        return {k: _read(item, k, file=file, episode=episode,
                         skip_non_numeric=skip_non_numeric) for k in item}
    try:
        values = np.asarray(item[()])
    except (OSError, RuntimeError) as err:
        raise DataError(f"cannot read dataset: {err}", file=file, key=item.name,
                        episode=episode) from err
    if values.dtype.kind not in "biuf":
        if skip_non_numeric:
            return _NonNumeric(str(values.dtype))
        raise DataError(f"non-numeric data ({values.dtype}) is not stored", file=file,
                        key=item.name.lstrip("/"), episode=episode)
    return values


def _flatten(prefix: str, value: Any) -> dict[Any, np.ndarray]:
    if isinstance(value, dict):
        out = {}
        for k, v in value.items():
            for key, arr in _flatten(k, v).items():
                out[(prefix, *key) if isinstance(key, tuple) else (prefix, key)] = arr
        return out
    return {prefix: value}


def read_minari(
    source: str | os.PathLike[str],
    *,
    episodes: Sequence[int] | None = None,
    rate_hz: float | None = None,
    quaternions: str | Sequence[str | QuaternionField] | None = None,
    raw_quaternion_signs: bool = False,
) -> tuple[list[TensorDict], Manifest]:
    """Read a local Minari dataset into episodes aligned as ``(o_i, a_i)``.

    Args:
        source: a dataset id (under ``$MINARI_DATASETS_PATH``) or a local path.
        episodes: episode ids to read, in the given order (default: all, by id).
        rate_hz: the control rate, when known: writes ``timestamp = step / rate_hz``.
        quaternions: further quaternion fields, a spec ``"KEY[a:b][:ORDER],..."`` or a list
            (`rfmp_rl.data.quaternions`): each episode's first sample is put at ``w >= 0``,
            then its signs are made continuous.
        raw_quaternion_signs: keep the recorded quaternion signs.

    Returns:
        ``(episodes, manifest)`` (``format="minari"``; ``extra`` holds the dataset's
        ``metadata.json`` entries ``dataset_id``, ``total_episodes``, ``total_steps``,
        ``observation_space``, ``action_space`` and ``env_spec`` where present).

    Raises:
        DataError: dataset not on disk; an unreadable file; an episode whose observations are
            not one more than its actions (naming key and episode); non-numeric actions,
            rewards or flags; an unknown episode id; NaN/inf.
    """
    import h5py

    quats = parse_quaternion_fields(quaternions)
    folder = minari_dataset_path(source)
    file = str(folder / "main_data.hdf5")
    metadata: dict[str, Any] = {}
    if (folder / "metadata.json").is_file():
        try:
            metadata = json.loads((folder / "metadata.json").read_text())
        except json.JSONDecodeError as err:
            raise DataError(f"not JSON: {err}", file=str(folder / "metadata.json")) from err
    manifest = Manifest(source=str(folder.parent), format="minari", rate_hz=rate_hz)
    manifest.extra.update({k: metadata[k] for k in (
        "dataset_id", "total_episodes", "total_steps", "observation_space", "action_space",
        "env_spec") if k in metadata})
    try:
        f = h5py.File(file, "r")
    except OSError as err:
        raise DataError(f"cannot open as HDF5: {err}", file=file) from err
    out = []
    skipped_keys: dict[str, str] = {}
    with f:
        ids = {int(m.group(1)): name for name in f if (m := _EPISODE_RE.match(name))}
        wanted = sorted(ids) if episodes is None else [int(e) for e in episodes]
        for n, e in enumerate(wanted):
            if e in wanted[:n]:
                raise DataError(f"episode {e} is asked for twice", file=file, episode=e)
            if e not in ids:
                raise DataError(f"no episode {e} (the file holds {len(ids)})", file=file,
                                episode=e)
        if not wanted:
            raise DataError("no episodes", file=file)
        for e in wanted:
            name = ids[e]
            group = f[name]
            actions = _read(group, "actions", file=file, episode=name)
            observations = _read(group, "observations", file=file, episode=name,
                                 skip_non_numeric=True)
            arrays: dict[Any, np.ndarray] = {}
            for key, action in _flatten(ACTION, actions).items():
                arrays[key] = action
            steps = len(next(iter(arrays.values())))
            for key, obs in _flatten(OBSERVATION, observations).items():
                if isinstance(obs, _NonNumeric):
                    skipped_keys[key_name(key)] = f"non-numeric data ({obs.dtype})"
                    continue
                if len(obs) != steps + 1:
                    label = "observations" if isinstance(key, str) else \
                        "observations/" + "/".join(key[1:])
                    raise DataError(f"{len(obs)} observations for {steps} actions (Minari "
                                    "stores one more observation than actions)", file=file,
                                    key=label, episode=name)
                arrays[key] = obs[:-1]  # o_0 .. o_{T-1}: the final observation is dropped
            for src, dst in (("rewards", "reward"), ("terminations", "terminated"),
                             ("truncations", "truncated")):
                values = _read(group, src, file=file, episode=name)
                arrays[dst] = values.reshape(len(values), 1)
            if rate_hz is not None:
                arrays[TIMESTAMP] = step_timestamps(steps, rate_hz)
            episode = make_episode(arrays, file=file, episode=name)
            manifest.add(episode, name=name)
            out.append(episode)
    if skipped_keys:
        manifest.extra["skipped_keys"] = skipped_keys
    if quats:
        canonicalize_episode_quaternions(out, manifest, quats, raw=raw_quaternion_signs)
    return out, manifest
