"""robomimic HDF5 demonstration files: read them into episodes, write them from episodes.

Layout (as in the released robomimic datasets)::

    data                     attrs: env_args (JSON string), total (steps in all demos)
    data/demo_<i>            attrs: num_samples (its steps T)
        actions (T, A)  rewards (T,)  dones (T,)  [states (T, S)]
        obs/<key> (T, ...)   next_obs/<key> (T, ...)
    mask/<filter>            byte strings naming demos, e.g. b"demo_0" (splits: train, valid)

Images are ``uint8 (T, H, W, 3)`` (``agentview_image``, ``robot0_eye_in_hand_image``); low-dim
keys are float vectors (``robot0_eef_pos (T, 3)``, ``object (T, 10)``, ...). Demos are ordered by
their integer index (``demo_2`` before ``demo_10``), filtered or not.

An episode read by `read_robomimic` (and accepted by `write_robomimic`) has

* ``action`` — the ``actions`` dataset, dtype as stored;
* ``reward (T, 1)`` — dtype as stored; ``done (T, 1)`` bool (``dones != 0``). Both carry the
  trailing singleton dimension of TorchRL (as in `rfmp_rl.data.lasa_episodes`);
* ``("obs", key)`` and, on request, ``("next_obs", key)`` — dtype and shape as stored;
* ``states`` when the demo has it;
* ``timestamp`` float64 ``(T,)`` = ``step / control_freq`` when ``env_args`` gives the control
  rate (``env_kwargs.control_freq``, 20 Hz in the released sets); none when it does not.

Bad input raises `DataError` (a ``ValueError``) whose message names the file and, where it
applies, the key (as its path inside the demo: ``actions``, ``obs/robot0_eef_pos``,
``num_samples``, ``mask/train``), the demo (``demo_3``) and the step. This includes a missing
file: the reader raises ``DataError`` rather than ``FileNotFoundError`` so that callers catch
one exception type for every unusable input. An unreadable (truncated, corrupt, non-HDF5) file
is a ``DataError`` too.

h5py is needed (``pip install rfmp_rl[data]``); it is imported on first use.
"""

from __future__ import annotations

import json
import operator
import os
import re
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import torch
from tensordict import TensorDict, TensorDictBase

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
    robomimic_quaternion_fields,
)
from rfmp_rl.keys import ACTION, TIMESTAMP

if TYPE_CHECKING:  # pragma: no cover
    import h5py

__all__ = ["read_robomimic", "write_robomimic"]

_DEMO_RE = re.compile(r"^demo_(\d+)$")


def _h5py() -> Any:
    try:
        import h5py
    except ImportError as exc:  # pragma: no cover - h5py ships with rfmp_rl[data]
        raise ImportError(
            "robomimic files need h5py: pip install 'rfmp_rl[data]' (h5py==3.16.0)"
        ) from exc
    return h5py


def _demo_order(name: str) -> tuple[int, int, str]:
    """Sort key: ``demo_<i>`` by ``i``, then any other names alphabetically."""
    match = _DEMO_RE.match(name)
    return (0, int(match.group(1)), name) if match else (1, 0, name)


def _decode(value: Any) -> str:
    return value.decode("utf-8") if isinstance(value, bytes | np.bytes_) else str(value)


def _is_image(dataset: h5py.Dataset) -> bool:
    """Per-step rank >= 3, ``(H, W, C)``: RGB images and depth maps."""
    return dataset.ndim >= 4


def _read(dataset: h5py.Dataset, *, file: str, key: str, episode: str | None) -> np.ndarray:
    try:
        return np.asarray(dataset[()])
    except (OSError, RuntimeError) as exc:
        raise DataError(f"cannot read dataset: {exc}", file=file, key=key, episode=episode) from exc


def _parse_env_args(data: h5py.Group, file: str) -> dict[str, Any] | None:
    if "env_args" not in data.attrs:
        return None
    try:
        env_args = json.loads(_decode(data.attrs["env_args"]))
    except json.JSONDecodeError as exc:
        raise DataError(f"attribute is not valid JSON: {exc}", file=file, key="env_args") from exc
    if not isinstance(env_args, dict):
        raise DataError(
            f"attribute must be a JSON object, got {type(env_args).__name__}",
            file=file, key="env_args",
        )
    return env_args


def _control_rate(env_args: dict[str, Any] | None) -> float | None:
    kwargs = (env_args or {}).get("env_kwargs")
    if isinstance(kwargs, dict) and kwargs.get("control_freq") is not None:
        return float(kwargs["control_freq"])
    return None


def _select_demos(
    f: h5py.File, data: h5py.Group, filter_key: str | None, file: str
) -> tuple[list[str], list[str]]:
    """(selected demo names in index order, available filter names)."""
    h5py = _h5py()
    demos = sorted((k for k, v in data.items() if isinstance(v, h5py.Group)), key=_demo_order)
    mask = f.get("mask")
    filters = sorted(mask.keys()) if isinstance(mask, h5py.Group) else []
    if filter_key is None:
        return demos, filters
    key = f"mask/{filter_key}"
    if filter_key not in filters:
        available = ", ".join(filters) if filters else "none (the file has no mask group)"
        raise DataError(f"unknown filter key; available filters: {available}", file=file, key=key)
    raw = mask[filter_key]
    if not isinstance(raw, h5py.Dataset):
        raise DataError("filter is not a dataset of demo names", file=file, key=key)
    names = [_decode(v) for v in np.asarray(_read(raw, file=file, key=key, episode=None)).ravel()]
    present = set(demos)
    seen: set[str] = set()
    for name in names:
        if name not in present:
            raise DataError(
                f"filter {filter_key!r} names a demo that is not in the data group",
                file=file, key=key, episode=name,
            )
        if name in seen:
            raise DataError(
                f"filter {filter_key!r} names this demo twice", file=file, key=key, episode=name
            )
        seen.add(name)
    return sorted(names, key=_demo_order), filters


def _obs_datasets(
    demo: h5py.Group, group: str, keys: Sequence[str], *, file: str, name: str
) -> dict[str, h5py.Dataset]:
    h5py = _h5py()
    grp = demo.get(group)
    available = sorted(grp.keys()) if isinstance(grp, h5py.Group) else []
    out = {}
    for key in keys:
        ds = grp.get(key) if isinstance(grp, h5py.Group) else None
        if not isinstance(ds, h5py.Dataset):
            listed = ", ".join(available) if available else f"none (no {group} group)"
            raise DataError(
                f"{group} key {key!r} not in the demo; available: {listed}",
                file=file, key=f"{group}/{key}", episode=name,
            )
        out[key] = ds
    return out


def _flag(values: torch.Tensor, *, file: str, key: str, episode: str) -> torch.Tensor:
    """``(T,)`` or ``(T, 1)`` -> ``(T, 1)``."""
    if values.ndim == 1:
        return values.unsqueeze(-1)
    if values.ndim == 2 and values.shape[1] == 1:
        return values
    raise DataError(
        f"expected shape (T,) or (T, 1), got {tuple(values.shape)}",
        file=file, key=key, episode=episode,
    )


def read_robomimic(
    path: str | os.PathLike[str],
    *,
    obs_keys: Sequence[str] | None = None,
    filter_key: str | None = None,
    with_next_obs: bool = False,
    load_images: bool = True,
    quaternions: str | Sequence[str | QuaternionField] | None = None,
    raw_quaternion_signs: bool = False,
) -> tuple[list[TensorDict], Manifest]:
    """Read the demos of a robomimic HDF5 file, in index order, as episodes.

    Args:
        path: the ``.hdf5`` file.
        obs_keys: observation keys to read (a single string is one key). ``None`` reads every
            key of the first selected demo, and then every demo must hold the same keys.
        filter_key: a split under the file's ``mask`` group (``"train"``, ``"valid"``, ...);
            ``None`` reads every demo.
        with_next_obs: also read ``next_obs/<key>`` for the selected keys.
        load_images: ``False`` skips image keys (per-step rank >= 3, ``(H, W, C)``), also when
            ``obs_keys`` names them; the skipped keys are listed in
            ``manifest.extra["skipped_obs_keys"]``.
        quaternions: quaternion fields besides the observed ``*quat`` keys, which are always
            canonicalised (xyzw, robosuite's order) — e.g. ``"action[3:7]"`` for absolute-pose
            actions with an xyzw quaternion. A spec ``"KEY[a:b][:ORDER],..."`` or a list
            (`rfmp_rl.data.quaternions`): each episode's first sample is put at ``w >= 0``,
            then its signs are made continuous.
        raw_quaternion_signs: keep the recorded quaternion signs.

    Returns:
        ``(episodes, manifest)``. Each episode is a TensorDict of batch ``[T]`` holding
        ``action``, ``reward (T, 1)``, ``done (T, 1)`` bool, ``("obs", key)``, optionally
        ``("next_obs", key)`` and ``states`` (see the module docstring). The manifest has
        ``format="robomimic"``, ``rate_hz`` = ``env_args["env_kwargs"]["control_freq"]`` when
        present (else ``None``) and ``extra`` = ``env_args`` (parsed, or ``None``),
        ``filter_key``, ``filters`` (available), ``demos`` (names read), ``total`` (the file's
        attribute), ``obs_keys`` (read) and ``skipped_obs_keys``.

    Raises:
        DataError: missing or unreadable file; no ``data`` group; unknown filter (the message
            lists the available ones) or a filter naming a demo not in ``data``; a demo without
            a requested dataset or obs key; arrays of different lengths; an empty demo; a
            NaN/inf value (naming the step); ``num_samples`` disagreeing with the demo's length;
            the ``total`` attribute disagreeing with the steps of all demos (checked when no
            filter is used); per-step shapes or dtypes differing between demos.

    Example:
        >>> import os, tempfile
        >>> image = torch.zeros(4, 8, 8, 3, dtype=torch.uint8)
        >>> ep = TensorDict({"action": torch.zeros(4, 7), "reward": torch.zeros(4, 1),
        ...                  "done": torch.tensor([[False], [False], [False], [True]]),
        ...                  "obs": {"robot0_eef_pos": torch.ones(4, 3), "agentview_image": image}},
        ...                 batch_size=[4])
        >>> env_args = {"env_name": "Lift", "env_type": 1, "env_kwargs": {"control_freq": 20}}
        >>> with tempfile.TemporaryDirectory() as tmp:
        ...     path = os.path.join(tmp, "lift.hdf5")
        ...     write_robomimic(path, [ep, ep, ep], env_args=env_args,
        ...                     mask={"train": [0, 2], "valid": [1]})
        ...     eps, manifest = read_robomimic(path, filter_key="train", load_images=False)
        >>> manifest.episodes, manifest.steps, manifest.rate_hz, manifest.extra["demos"]
        (2, 8, 20.0, ['demo_0', 'demo_2'])
        >>> eps[0]["obs", "robot0_eef_pos"].shape, eps[0]["done"][:, 0].tolist()
        (torch.Size([4, 3]), [False, False, False, True])
        >>> manifest.extra["skipped_obs_keys"]
        ['agentview_image']
    """
    h5py = _h5py()
    file = str(path)
    if isinstance(obs_keys, str):
        obs_keys = [obs_keys]
    if obs_keys is not None:
        obs_keys = list(dict.fromkeys(obs_keys))
    extra_quats = parse_quaternion_fields(quaternions)
    if not os.path.exists(file):
        raise DataError("no such file", file=file)
    try:
        f = h5py.File(file, "r")
    except OSError as exc:  # truncated, corrupt, not HDF5, a directory, no permission
        raise DataError(f"cannot open as HDF5: {exc}", file=file) from exc
    with f:
        data = f.get("data")
        if not isinstance(data, h5py.Group):
            raise DataError("no 'data' group (not a robomimic file?)", file=file, key="data")
        env_args = _parse_env_args(data, file)
        total = int(data.attrs["total"]) if "total" in data.attrs else None
        demos, filters = _select_demos(f, data, filter_key, file)
        if not demos:
            where = f"filter {filter_key!r} selects" if filter_key is not None else "the file has"
            raise DataError(f"no demos to read: {where} none", file=file, key="data")
        manifest = Manifest(source=file, format="robomimic", rate_hz=_control_rate(env_args))
        episodes: list[TensorDict] = []
        keys: list[str] | None = None
        skipped: list[str] = []
        for name in demos:
            demo = data[name]
            if keys is None:  # fix the key selection on the first demo
                if obs_keys is None:
                    obs_grp = demo.get("obs")
                    all_keys = list(obs_grp.keys()) if isinstance(obs_grp, h5py.Group) else []
                else:
                    all_keys = obs_keys
                found = _obs_datasets(demo, "obs", all_keys, file=file, name=name)
                keys = [k for k in all_keys if load_images or not _is_image(found[k])]
                skipped = [k for k in all_keys if k not in keys]
            elif obs_keys is None:
                obs_grp = demo.get("obs")
                here = set(obs_grp.keys()) if isinstance(obs_grp, h5py.Group) else set()
                extra = sorted(here - set(keys) - set(skipped))
                if extra:
                    raise DataError(
                        f"obs key {extra[0]!r} is not in the first demo {demos[0]!r}",
                        file=file, key=f"obs/{extra[0]}", episode=name,
                    )
            episodes.append(_read_demo(demo, name, keys, with_next_obs, file=file))
            if manifest.rate_hz is not None:
                length = int(episodes[-1].batch_size[0])
                episodes[-1].set(TIMESTAMP, torch.from_numpy(
                    step_timestamps(length, manifest.rate_hz)))
            manifest.add(episodes[-1], name=name)
        if filter_key is None and total is not None and total != manifest.steps:
            raise DataError(
                f"attribute total = {total}, but the demos hold {manifest.steps} steps",
                file=file, key="total",
            )
    known = robomimic_quaternion_fields(episodes[0])
    fields = known + [q for q in extra_quats if q.key not in {k.key for k in known}]
    canonicalize_episode_quaternions(episodes, manifest, fields, raw=raw_quaternion_signs)
    manifest.extra.update(
        env_args=env_args,
        filter_key=filter_key,
        filters=filters,
        demos=list(demos),
        total=total,
        obs_keys=list(keys or obs_keys or []),
        skipped_obs_keys=skipped,
    )
    return episodes, manifest


def _read_demo(
    demo: h5py.Group, name: str, keys: Sequence[str], with_next_obs: bool, *, file: str
) -> TensorDict:
    h5py = _h5py()
    arrays: dict[Any, np.ndarray] = {}
    for key in ("actions", "rewards", "dones", "states"):
        ds = demo.get(key)
        if isinstance(ds, h5py.Dataset):
            arrays[key] = _read(ds, file=file, key=key, episode=name)
        elif key != "states":
            raise DataError("required dataset missing from the demo", file=file, key=key,
                            episode=name)
    groups = ("obs", "next_obs") if with_next_obs else ("obs",)
    for group in groups:
        for key, ds in _obs_datasets(demo, group, keys, file=file, name=name).items():
            arrays[group, key] = _read(ds, file=file, key=f"{group}/{key}", episode=name)
    # Validates lengths (>= 1, equal) and finiteness, naming the datasets as the file does.
    raw = make_episode(arrays, file=file, episode=name)
    length = int(raw.batch_size[0])
    if "num_samples" in demo.attrs and int(demo.attrs["num_samples"]) != length:
        raise DataError(
            f"attribute num_samples = {int(demo.attrs['num_samples'])}, but the demo has "
            f"{length} steps",
            file=file, key="num_samples", episode=name,
        )
    out = TensorDict(
        {
            ACTION: raw["actions"],
            "reward": _flag(raw["rewards"], file=file, key="rewards", episode=name),
            "done": _flag(raw["dones"], file=file, key="dones", episode=name) != 0,
        },
        batch_size=[length],
    )
    if "states" in arrays:
        out["states"] = raw["states"]
    for group in groups:
        if keys:
            out[group] = raw[group]
    return out


def _numpy(value: torch.Tensor | np.ndarray) -> np.ndarray:
    if isinstance(value, torch.Tensor):
        return value.detach().cpu().numpy()
    return np.asarray(value)


def _leaf(ep: TensorDictBase, key: Any, *, file: str, name: str, label: str) -> np.ndarray:
    value = ep.get(key, None)
    if value is None:
        raise DataError("missing from the episode", file=file, key=label, episode=name)
    if isinstance(value, TensorDictBase):
        raise DataError("is a TensorDict, expected a tensor", file=file, key=label, episode=name)
    arr = _numpy(value)
    check_finite(arr, file=file, key=label, episode=name)
    return arr


def write_robomimic(
    path: str | os.PathLike[str],
    episodes: Sequence[TensorDictBase],
    *,
    env_args: dict[str, Any],
    obs_keys: Sequence[str] | None = None,
    mask: dict[str, list[int]] | None = None,
    compression: str | None = None,
) -> None:
    """Write episodes as a robomimic HDF5 file (``data/demo_<i>`` for ``episodes[i]``).

    The file is written to ``path + ".tmp"`` and moved over ``path`` only when complete, so an
    error (or a crash) never leaves a partial file at ``path``. Parent folders are created.

    Args:
        path: the ``.hdf5`` file to (over)write.
        episodes: TensorDicts of batch ``[T]`` (T >= 1) shaped like `read_robomimic`'s output:
            ``action``, ``reward`` and ``done`` (each ``(T,)`` or ``(T, 1)``), ``("obs", key)``,
            optionally ``("next_obs", key)`` and ``states``. Other entries are not written.
            Each selected key's ``next_obs`` is taken from the episode when it has it, else it is
            ``obs`` shifted by one step with the last step repeated (as robomimic does).
        env_args: the environment description (``env_name``, ``env_type``, ``env_kwargs``), stored
            as the JSON attribute ``data.attrs["env_args"]``.
        obs_keys: observation keys to write; ``None`` writes every ``obs`` key of the first
            episode. Every episode must hold every selected key.
        mask: split name -> episode indices, written as ``mask/<name>`` (``b"demo_<i>"``).
        compression: an h5py filter for the per-step datasets (``"gzip"``, ``"lzf"``) or ``None``.

    Written dtypes: ``actions``, ``rewards``, ``states`` and observations as given; ``dones`` as
    int64 0/1; ``rewards`` and ``dones`` with shape ``(T,)``. Attributes ``num_samples`` per demo
    and ``total`` (all steps) are set.

    Raises:
        DataError: no episodes, an episode that is not batch ``[T]`` with T >= 1, a missing key,
            a NaN/inf value (naming key, demo and step), ``reward``/``done`` not ``(T,)`` or
            ``(T, 1)``, a mask index out of range or repeated.
        TypeError: ``env_args`` is not JSON-serialisable.

    Example:
        >>> import os, tempfile
        >>> ep = TensorDict({"action": torch.randn(5, 2), "reward": torch.zeros(5),
        ...                  "done": torch.arange(5) == 4,
        ...                  "obs": {"pos": torch.arange(5.0)[:, None]}}, batch_size=[5])
        >>> with tempfile.TemporaryDirectory() as tmp:
        ...     path = os.path.join(tmp, "demo.hdf5")
        ...     write_robomimic(path, [ep], env_args={"env_name": "Toy", "env_type": 1,
        ...                                           "env_kwargs": {}})
        ...     (back,), manifest = read_robomimic(path, with_next_obs=True)
        >>> torch.equal(back["action"], ep["action"]), back["next_obs", "pos"][:, 0].tolist()
        (True, [1.0, 2.0, 3.0, 4.0, 4.0])
        >>> manifest.rate_hz is None, manifest.extra["env_args"]["env_name"]
        (True, 'Toy')
    """
    h5py = _h5py()
    file = str(path)
    env_json = json.dumps(env_args)
    episodes = list(episodes)
    if not episodes:
        raise DataError("no episodes to write", file=file)
    first_obs = episodes[0].get("obs", None)
    if obs_keys is None:
        keys = list(first_obs.keys()) if isinstance(first_obs, TensorDictBase) else []
    else:
        keys = list(dict.fromkeys([obs_keys] if isinstance(obs_keys, str) else obs_keys))
    names = [f"demo_{i}" for i in range(len(episodes))]
    masks: dict[str, np.ndarray] = {}
    for split, indices in (mask or {}).items():
        chosen: list[str] = []
        for index in indices:
            try:
                i = operator.index(index)
            except TypeError:
                i = -1
            if isinstance(index, bool) or not 0 <= i < len(episodes):
                raise DataError(
                    f"index {index!r} is not an episode index (0 to {len(episodes) - 1})",
                    file=file, key=f"mask/{split}",
                )
            if names[i] in chosen:
                raise DataError("episode listed twice", file=file, key=f"mask/{split}",
                                episode=names[i])
            chosen.append(names[i])
        masks[split] = np.array([n.encode() for n in chosen], dtype="S")

    def dataset(group: h5py.Group, key: str, value: np.ndarray) -> None:
        group.create_dataset(key, data=value, compression=compression if value.ndim else None)

    target = Path(file)
    target.parent.mkdir(parents=True, exist_ok=True)
    tmp = file + ".tmp"
    try:
        with h5py.File(tmp, "w") as f:
            data = f.create_group("data")
            data.attrs["env_args"] = env_json
            total = 0
            for ep, name in zip(episodes, names, strict=True):
                total += _write_demo(data, ep, name, keys, dataset, file=file)
            data.attrs["total"] = total
            if masks:
                mask_grp = f.create_group("mask")
                for split, values in masks.items():
                    mask_grp.create_dataset(split, data=values)
        os.replace(tmp, file)
    except BaseException:
        if os.path.exists(tmp):
            os.remove(tmp)
        raise


def _write_demo(
    data: h5py.Group, ep: TensorDictBase, name: str, keys: Sequence[str], dataset: Any, *,
    file: str,
) -> int:
    if not isinstance(ep, TensorDictBase):
        raise DataError(f"expected a TensorDict, got {type(ep).__name__}", file=file, episode=name)
    if ep.batch_dims != 1 or ep.batch_size[0] < 1:
        raise DataError(
            f"expected batch size [T] with T >= 1, got {list(ep.batch_size)}",
            file=file, episode=name,
        )
    length = int(ep.batch_size[0])
    action = _leaf(ep, ACTION, file=file, name=name, label="action")
    reward = _leaf(ep, "reward", file=file, name=name, label="reward")
    done = _leaf(ep, "done", file=file, name=name, label="done")
    flags = {}
    for label, arr in (("reward", reward), ("done", done)):
        if arr.shape not in ((length,), (length, 1)):
            raise DataError(
                f"expected shape (T,) or (T, 1) with T = {length}, got {arr.shape}",
                file=file, key=label, episode=name,
            )
        flags[label] = arr.reshape(length)
    obs = {k: _leaf(ep, ("obs", k), file=file, name=name, label=f"obs/{k}") for k in keys}
    next_obs = {}
    for k, value in obs.items():
        if ep.get(("next_obs", k), None) is not None:
            next_obs[k] = _leaf(ep, ("next_obs", k), file=file, name=name, label=f"next_obs/{k}")
        else:
            next_obs[k] = np.concatenate([value[1:], value[-1:]], axis=0)
    demo = data.create_group(name)
    demo.attrs["num_samples"] = length
    dataset(demo, "actions", action)
    dataset(demo, "rewards", flags["reward"])
    dataset(demo, "dones", (flags["done"] != 0).astype(np.int64))
    if ep.get("states", None) is not None:
        dataset(demo, "states", _leaf(ep, "states", file=file, name=name, label="states"))
    for group, values in (("obs", obs), ("next_obs", next_obs)):
        grp = demo.create_group(group)
        for k, value in values.items():
            dataset(grp, k, value)
    return length
