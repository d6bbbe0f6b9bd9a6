"""The demonstration store and the paper's horizon/context sampler, from TorchRL buffer parts.

`DemonstrationStore` keeps every step of every episode in one TorchRL storage (a
``LazyMemmapStorage`` when the episodes hold images, so a 25k-step image set is memory-mapped from
disk; a ``LazyTensorStorage`` otherwise) together with the episode boundaries and the reader's
`Manifest`. Its `DemonstrationStore.replay_buffer` assembles a ``TensorDictReplayBuffer`` from

- that storage,
- `HorizonContextSampler` (a TorchRL ``Sampler``) that draws the paper's samples as storage indices,
- `ContextChunk` (a TorchRL ``Transform``) that turns the gathered steps into training samples.

Index convention (as in `rfmp_rl.data.slices`): step ``i`` stores the observation ``o_i`` and the
action ``a_i`` commanded after observing it. For a sample index ``s`` of the paper (Sec. "Fast and
Robust RFMP"), the reference observation is ``o^{s-1}``, so with ``r = s - 1`` stored steps:

- action chunk ``a[r], ..., a[r + T_p - 1]`` (the paper's ``a^s ... a^{s+T_p-1}``),
- reference observation ``o[r]`` (the paper's ``o^{s-1}``),
- context observation ``o[c]`` with ``c ~ U{s - T_o, ..., s - 2}``, i.e.
  ``U{r + 1 - T_o, ..., r - 1}`` (T_o = 2 always gives ``o^{s-2}`` = ``o[r - 1]``),
- gap ``s - c`` in ``{2, ..., T_o}``.

At the episode boundaries the edge frame is repeated: a context before the first step reads the
first step, chunk steps past the last step repeat the last action and are ``True`` in
``action_is_pad``. The gap stays the drawn one (the repeated first frame stands for the robot at
rest before the episode started).
"""

from __future__ import annotations

import json
import os
import shutil
from collections.abc import Sequence
from pathlib import Path

import torch
from tensordict import TensorDict, TensorDictBase
from tensordict.utils import NestedKey
from torchrl.data import (
    LazyMemmapStorage,
    LazyTensorStorage,
    TensorDictReplayBuffer,
    TensorStorage,
)
from torchrl.data.replay_buffers.samplers import Sampler
from torchrl.data.replay_buffers.storages import Storage
from torchrl.envs.transforms import Transform

from rfmp_rl import keys
from rfmp_rl.data.episodes import DataError, Manifest, key_name, parse_key

__all__ = ["DemonstrationStore", "HorizonContextSampler", "ContextChunk", "sample_indices",
           "check_store_destination"]

_EPISODE_KEY = "episode"


def sample_indices(
    reference: torch.Tensor,
    gap: torch.Tensor,
    episode_start: torch.Tensor,
    episode_end: torch.Tensor,
    horizon: int,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Storage indices of the paper's samples, with edge padding.

    Args:
        reference: ``(B,)`` reference steps ``r = s - 1`` (storage indices).
        gap: ``(B,)`` gaps ``s - c`` (>= 2).
        episode_start, episode_end: ``(B,)`` first and last storage index of each sample's episode.
        horizon: T_p.

    Returns:
        ``index (B, 2 + T_p)`` = ``[c, r, r, r + 1, ..., r + T_p - 1]`` clamped to the episode, and
        ``action_is_pad (B, T_p)``.

    Example:
        >>> idx, pad = sample_indices(torch.tensor([10, 0]), torch.tensor([2, 2]),
        ...                           torch.tensor([0, 0]), torch.tensor([11, 11]), horizon=3)
        >>> idx.tolist(), pad.tolist()
        ([[9, 10, 10, 11, 11], [0, 0, 0, 1, 2]], [[False, False, True], [False, False, False]])
    """
    context = torch.maximum(reference + 1 - gap, episode_start)  # (B,)
    steps = reference[:, None] + torch.arange(horizon, device=reference.device)  # (B, T_p)
    pad = steps > episode_end[:, None]
    steps = torch.minimum(steps, episode_end[:, None])
    index = torch.cat([context[:, None], reference[:, None], steps], dim=1)  # (B, 2 + T_p)
    return index, pad


class HorizonContextSampler(Sampler):
    """TorchRL sampler of (context, reference, chunk) step indices over whole episodes.

    Every step of every episode is equally likely as the reference ``r = s - 1`` (as Diffusion
    Policy's sequence sampler). ``sample`` returns the ``(B, 2 + T_p)`` index of `sample_indices`
    and an info dict holding ``obs_gap (B,)`` (float, ``s - c``) and ``action_is_pad (B, T_p)``;
    ``TensorDictReplayBuffer`` writes both into the sampled batch.

    Args:
        episode_starts: ``(E,)`` first storage index of each episode.
        episode_lengths: ``(E,)`` steps per episode (>= 1).
        horizon: T_p.
        obs_horizon: T_o >= 2 (the context is drawn from the last T_o - 1 steps before ``s - 1``).
        generator: optional ``torch.Generator`` for reproducible batches.

    Example:
        >>> sampler = HorizonContextSampler(torch.tensor([0, 5]), torch.tensor([5, 3]), horizon=4)
        >>> index, info = sampler.sample(None, 6)
        >>> index.shape, info["action_is_pad"].shape, sorted(set(info["obs_gap"].tolist()))
        (torch.Size([6, 6]), torch.Size([6, 4]), [2.0])
    """

    def __init__(
        self,
        episode_starts: torch.Tensor,
        episode_lengths: torch.Tensor,
        horizon: int,
        obs_horizon: int = 2,
        generator: torch.Generator | None = None,
    ) -> None:
        super().__init__()
        if horizon < 1:
            raise ValueError(f"HorizonContextSampler: horizon must be >= 1, got {horizon}")
        if obs_horizon < 2:
            raise ValueError(f"HorizonContextSampler: obs_horizon must be >= 2, got {obs_horizon}")
        lengths = torch.as_tensor(episode_lengths, dtype=torch.long)
        if lengths.numel() == 0 or bool((lengths < 1).any()):
            raise ValueError("HorizonContextSampler: needs at least one episode, each >= 1 step")
        starts = torch.as_tensor(episode_starts, dtype=torch.long)
        self.horizon, self.obs_horizon, self.generator = int(horizon), int(obs_horizon), generator
        # Per-step lookup tables (one entry per stored step): its episode's first and last index.
        self._step_start = torch.repeat_interleave(starts, lengths)
        self._step_end = torch.repeat_interleave(starts + lengths - 1, lengths)
        self._steps = torch.cat(
            [s + torch.arange(n) for s, n in zip(starts.tolist(), lengths.tolist(), strict=True)]
        )

    def sample(self, storage: Storage | None, batch_size: int) -> tuple[torch.Tensor, dict]:
        pick = torch.randint(len(self._steps), (batch_size,), generator=self.generator)
        reference = self._steps[pick]
        gap = torch.randint(2, self.obs_horizon + 1, (batch_size,), generator=self.generator)
        index, pad = sample_indices(
            reference, gap, self._step_start[pick], self._step_end[pick], self.horizon
        )
        return index, {keys.OBS_GAP: gap.to(torch.float32), keys.ACTION_IS_PAD: pad}

    def _empty(self) -> None:
        pass

    def dumps(self, path) -> None:  # stateless apart from its constructor arguments
        pass

    def loads(self, path) -> None:
        pass

    def state_dict(self) -> dict:
        return {}

    def load_state_dict(self, state_dict: dict) -> None:
        pass

    def extend(self, index: torch.Tensor) -> None:
        pass

    def update_priority(self, *args, **kwargs) -> None:
        pass

    def add(self, index: int) -> None:
        pass


class ContextChunk(Transform):
    """``(B, 2 + T_p)`` gathered steps -> ``(B,)`` training samples.

    Observation and camera keys keep their first two columns, ``[o^c, o^{s-1}]`` -> ``(B, 2, ...)``
    (camera images stored ``(H, W, C)`` become ``(B, 2, C, H, W)``); the action keeps the last T_p
    columns -> ``(B, T_p, D)``. Other keys are dropped. Optionally, several per-step keys are
    flattened and concatenated into one observation vector (``concat``).

    Args:
        horizon: T_p.
        observation_keys: low-dim keys windowed as they are.
        camera_keys: image keys stored ``(H, W, C)``; output ``(B, 2, C, H, W)``.
        action_key: the action entry.
        concat: optional ``{out_key: [in_key, ...]}``: each in_key's per-step array is flattened
            and concatenated (in order) into ``out_key`` (then windowed like an observation key).

    Example:
        >>> steps = TensorDict({"a": torch.arange(10.0).reshape(2, 5, 1),
        ...                     "b": torch.zeros(2, 5, 2, 2)}, [2, 5])
        >>> out = ContextChunk(3, concat={"observation": ["a", "b"]}, action_key="a")(steps)
        >>> out["observation"].shape, out["a"][0, :, 0].tolist()
        (torch.Size([2, 2, 5]), [2.0, 3.0, 4.0])
    """

    def __init__(
        self,
        horizon: int,
        observation_keys: Sequence[NestedKey] = (),
        camera_keys: Sequence[NestedKey] = (),
        action_key: NestedKey = keys.ACTION,
        concat: dict[NestedKey, Sequence[NestedKey]] | None = None,
    ) -> None:
        super().__init__()
        self.horizon = int(horizon)
        self.observation_keys = [parse_key(k) for k in observation_keys]
        self.camera_keys = [parse_key(k) for k in camera_keys]
        self.action_key = parse_key(action_key)
        self.concat = {parse_key(k): [parse_key(i) for i in v] for k, v in (concat or {}).items()}
        if self.action_key in self.concat:
            raise ValueError(
                f"ContextChunk: concat builds observation windows and cannot build the action "
                f"{key_name(self.action_key)!r}; build a flat action when reading the data "
                "(e.g. action: [topics] in a ROS topic config)"
            )

    @staticmethod
    def _get(tensordict: TensorDictBase, key: NestedKey) -> torch.Tensor:
        value = tensordict.get(key, None)
        if value is None:
            present = ", ".join(sorted(key_name(k) for k in tensordict.keys(True, True)))
            raise KeyError(f"ContextChunk: no entry {key_name(key)!r} in the stored steps "
                           f"(keys: {present})")
        return value

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        if tensordict.batch_dims != 2 or tensordict.shape[1] != 2 + self.horizon:
            raise ValueError(
                f"ContextChunk: expected a batch of shape (B, 2 + T_p = {2 + self.horizon}), got "
                f"{tuple(tensordict.shape)}; use it with HorizonContextSampler(horizon="
                f"{self.horizon})"
            )
        batch = tensordict.shape[0]
        out = TensorDict({}, batch_size=[batch])
        get = self._get
        for key in self.observation_keys:
            out.set(key, get(tensordict, key)[:, :2])
        for out_key, in_keys in self.concat.items():
            parts = [get(tensordict, k)[:, :2].reshape(batch, 2, -1) for k in in_keys]
            out.set(out_key, torch.cat(parts, dim=-1))
        for key in self.camera_keys:
            out.set(key, get(tensordict, key)[:, :2].permute(0, 1, 4, 2, 3))  # (B, 2, C, H, W)
        out.set(self.action_key, get(tensordict, self.action_key)[:, 2:])  # (B, T_p, D)
        return out


STORE_FILES = ("manifest.json", "episodes.json", "storage")


def check_store_destination(path: str | Path) -> None:
    """Refuse a destination `DemonstrationStore.save` must not replace: a file, or a folder that
    holds anything but exactly a store written by `save` (an empty folder is fine; a store with
    files added beside it is refused, since replacing it would delete them).

    Raises:
        DataError: naming the path and what is in it.
    """
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise DataError("--out names a file; give a folder for the store (missing, empty, or "
                        "a store written before)", file=str(path))
    if not path.is_dir():
        return
    entries = sorted(p.name for p in path.iterdir())
    if not entries:
        return
    others = [name for name in entries if name not in STORE_FILES]
    if not others and all((path / name).exists() for name in STORE_FILES):
        return  # exactly a store: replacing it deletes nothing else
    shown = ", ".join(others[:5]) + (", ..." if len(others) > 5 else "")
    if all((path / name).exists() for name in STORE_FILES):
        raise DataError(f"refusing to replace this store: the folder also holds files the store "
                        f"did not write ({shown}), which replacing it would delete; move them "
                        "or give another folder", file=str(path))
    raise DataError(f"refusing to replace a folder that is not a demonstration store (it holds "
                    f"{shown}); give a new or empty folder", file=str(path))


def _sync_tree(folder: Path) -> None:
    """fsync every file below ``folder`` and the folders themselves."""
    for item in sorted(folder.rglob("*"), key=lambda p: len(p.parts), reverse=True):
        if item.is_file():
            with open(item, "rb+") as f:
                os.fsync(f.fileno())
    for directory in [*(p for p in folder.rglob("*") if p.is_dir()), folder]:
        fd = os.open(directory, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


class DemonstrationStore:
    """Every step of a set of episodes in one TorchRL storage, with boundaries and a manifest.

    Args:
        storage: a filled TorchRL ``TensorStorage`` (batch of all steps, episode after episode).
        episode_lengths: steps per episode, in storage order.
        manifest: what the reader read.

    Example:
        >>> eps = [TensorDict({"observation": torch.randn(n, 3), "action": torch.randn(n, 2)}, [n])
        ...        for n in (30, 20)]
        >>> store = DemonstrationStore.from_episodes(eps)
        >>> len(store), store.num_episodes
        (50, 2)
        >>> rb = store.replay_buffer(horizon=16, observation_keys=["observation"], batch_size=8)
        >>> batch = rb.sample()
        >>> batch["observation"].shape, batch["action"].shape, batch["action_is_pad"].shape
        (torch.Size([8, 2, 3]), torch.Size([8, 16, 2]), torch.Size([8, 16]))
    """

    def __init__(
        self, storage: TensorStorage, episode_lengths: Sequence[int], manifest: Manifest
    ) -> None:
        self.storage = storage
        self.episode_lengths = torch.as_tensor(list(episode_lengths), dtype=torch.long)
        self.episode_starts = torch.cumsum(self.episode_lengths, 0) - self.episode_lengths
        self.manifest = manifest
        if int(self.episode_lengths.sum()) != len(storage):
            raise ValueError(
                f"DemonstrationStore: episode lengths sum to {int(self.episode_lengths.sum())} "
                f"but the storage holds {len(storage)} steps"
            )

    # ----------------------------------------------------------------------------- building
    @classmethod
    def from_episodes(
        cls,
        episodes: Sequence[TensorDict],
        manifest: Manifest | None = None,
        *,
        memmap: bool | None = None,
        scratch_dir: str | Path | None = None,
    ) -> DemonstrationStore:
        """Write ``episodes`` (TensorDicts of batch ``[T]``) into a new storage.

        Args:
            episodes: the episodes, all with the same keys, per-step shapes and dtypes.
            manifest: the reader's manifest; built here (format ``"episodes"``) when None.
            memmap: use ``LazyMemmapStorage``; default: when any leaf is an image
                (``uint8`` with at least 3 per-step dims).
            scratch_dir: where the memory-mapped files go (default: a temporary folder).
        """
        if not episodes:
            raise DataError("no episodes to store")
        for i, ep in enumerate(episodes):
            if ep.batch_dims != 1 or ep.batch_size[0] < 1:
                raise DataError(f"an episode must have batch size [T] with T >= 1, got "
                                f"{tuple(ep.batch_size)}", episode=i)
        if manifest is None:
            manifest = Manifest(source="<episodes>", format="episodes")
            for i, ep in enumerate(episodes):
                manifest.add(ep, name=i)
        if manifest.episodes != len(episodes):
            raise ValueError(
                f"DemonstrationStore: the manifest counts {manifest.episodes} episodes but "
                f"{len(episodes)} were given"
            )
        lengths = [int(ep.batch_size[0]) for ep in episodes]
        total = sum(lengths)
        if memmap is None:
            memmap = any(
                v.dtype == torch.uint8 and v.ndim >= 4
                for v in episodes[0].values(include_nested=True, leaves_only=True)
            )
        if memmap:
            storage = LazyMemmapStorage(total, scratch_dir=scratch_dir, existsok=True)
        else:
            storage = LazyTensorStorage(total)
        start = 0
        for i, ep in enumerate(episodes):
            ep = ep.clone(False)
            ep.set(_EPISODE_KEY, torch.full((lengths[i],), i, dtype=torch.long))
            try:
                storage.set(torch.arange(start, start + lengths[i]), ep)
            except (RuntimeError, KeyError, ValueError) as err:
                raise DataError(
                    f"does not match the keys/shapes of episode 0: {err}",
                    file=manifest.source, episode=manifest.episode_names[i],
                ) from err
            start += lengths[i]
        return cls(storage, lengths, manifest)

    def save(self, path: str | Path) -> Path:
        """Write the store to a folder: ``storage/`` (memory-mapped tensors), ``manifest.json``,
        ``episodes.json`` (lengths).

        ``path`` must be missing, an empty folder, or a store written here before (its
        ``manifest.json``, ``episodes.json`` and ``storage/`` present); anything else is refused
        (`check_store_destination`), so a mistaken path never deletes a user's files. The
        replacement is atomic: the new store is written and synced beside the old one, then
        swapped in by rename; if anything fails, the previous store is intact and no partial
        folder remains."""
        path = Path(path)
        check_store_destination(path)
        tmp = path.parent / f".{path.name}.writing-{os.getpid()}"
        old = path.parent / f".{path.name}.replaced-{os.getpid()}"
        path.parent.mkdir(parents=True, exist_ok=True)
        try:
            tmp.mkdir()
            data = self.storage.get(slice(0, len(self.storage)))
            data.memmap_(tmp / "storage")
            (tmp / "manifest.json").write_text(self.manifest.to_json())
            (tmp / "episodes.json").write_text(
                json.dumps({"lengths": self.episode_lengths.tolist()}))
            _sync_tree(tmp)
            if path.exists():
                os.replace(path, old)  # the previous store, kept until the new one is in place
            try:
                os.replace(tmp, path)
            except BaseException:
                if old.exists() and not path.exists():
                    os.replace(old, path)
                raise
        finally:
            shutil.rmtree(tmp, ignore_errors=True)
        shutil.rmtree(old, ignore_errors=True)
        return path

    @classmethod
    def load(cls, path: str | Path) -> DemonstrationStore:
        """Open a folder written by `save`; tensors stay memory-mapped (nothing is read eagerly)."""
        path = Path(path)
        for name in ("storage", "manifest.json", "episodes.json"):
            if not (path / name).exists():
                raise DataError(f"not a demonstration store: {name} is missing", file=str(path))
        data = TensorDict.load_memmap(path / "storage")
        manifest = Manifest.from_dict(json.loads((path / "manifest.json").read_text()))
        lengths = json.loads((path / "episodes.json").read_text())["lengths"]
        return cls(TensorStorage(data), lengths, manifest)

    # ------------------------------------------------------------------------------ access
    def __len__(self) -> int:
        return len(self.storage)

    @property
    def num_episodes(self) -> int:
        return len(self.episode_lengths)

    def episode(self, i: int) -> TensorDictBase:
        """Episode ``i`` as a TensorDict of batch ``[T]`` (memory-mapped storages stay lazy)."""
        if not -self.num_episodes <= i < self.num_episodes:
            raise IndexError(f"episode {i} out of range for {self.num_episodes} episodes")
        start, length = int(self.episode_starts[i]), int(self.episode_lengths[i])
        return self.storage.get(slice(start, start + length))

    def stats(self, key: NestedKey, chunk: int = 65536) -> tuple[torch.Tensor, torch.Tensor]:
        """Per-dimension min and max of ``key`` over every stored step (flattened per step);
        feeds `rfmp_rl.modules.Normalizer.set_stats`."""
        key = parse_key(key)  # "obs/gripper" as the manifest prints it, or ("obs", "gripper")
        data = self.storage.get(slice(0, len(self.storage)))
        if key not in data.keys(include_nested=True):
            raise DataError(
                f"no such key in the store (keys: {', '.join(self.manifest.keys)})",
                file=self.manifest.source, key=key_name(key),
            )
        lo = hi = None
        for start in range(0, len(self), chunk):
            block = data.get(key)[start:start + chunk]
            block = block.reshape(block.shape[0], -1).to(torch.float64)
            bmin, bmax = block.min(0).values, block.max(0).values
            lo = bmin if lo is None else torch.minimum(lo, bmin)
            hi = bmax if hi is None else torch.maximum(hi, bmax)
        return lo.float(), hi.float()

    def replay_buffer(
        self,
        horizon: int,
        observation_keys: Sequence[NestedKey] = (),
        *,
        camera_keys: Sequence[NestedKey] = (),
        action_key: NestedKey = keys.ACTION,
        concat: dict[NestedKey, Sequence[NestedKey]] | None = None,
        obs_horizon: int = 2,
        batch_size: int = 256,
        generator: torch.Generator | None = None,
        prefetch: int | None = None,
    ) -> TensorDictReplayBuffer:
        """A ``TensorDictReplayBuffer`` over this store that samples the paper's training samples.

        Each ``rb.sample()`` holds the windowed observation / camera keys ``(B, 2, ...)``
        ``[o^c, o^{s-1}]``, ``action (B, T_p, D)``, ``action_is_pad (B, T_p)``, ``obs_gap (B,)``
        and ``index (B, 2 + T_p)`` (the storage indices read). See `ContextChunk` for ``concat``.
        """
        sampler = HorizonContextSampler(
            self.episode_starts, self.episode_lengths, horizon, obs_horizon, generator
        )
        transform = ContextChunk(horizon, observation_keys, camera_keys, action_key, concat)
        return TensorDictReplayBuffer(
            storage=self.storage,
            sampler=sampler,
            transform=transform,
            batch_size=batch_size,
            prefetch=prefetch,
        )
