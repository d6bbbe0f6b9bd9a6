"""Turn trajectory slices from a TorchRL `SliceSampler` into RFMP training samples.

Index convention (used throughout `rfmp_rl.data`): a demonstration step ``i`` stores the
observation ``o_i`` and the action ``a_i`` executed after observing it. For a reference step
``r`` (the paper's ``s - 1``), a training sample is the observation window ``[o_{r-1}, o_r]``
(context, reference; T_o = 2) and the chunk ``[a_r, ..., a_{r + T_p - 1}]`` — at run time the
latest observation ``o_r`` yields the chunk whose first action is executed now.
"""

from __future__ import annotations

from collections.abc import Mapping

import torch
from tensordict import TensorDictBase
from tensordict.utils import NestedKey
from torchrl.envs.transforms import Transform

from rfmp_rl import keys
from rfmp_rl.data.episodes import key_name, parse_key
from rfmp_rl.data.store import ContextChunk, sample_indices

__all__ = ["SlicesToChunks"]


class SlicesToChunks(Transform):
    """``(B * (T_p + 1))`` trajectory slices -> ``(B,)`` training samples.

    Apply it to batches of a ``TensorDictReplayBuffer`` with
    ``SliceSampler(slice_len=T_p + 1, ...)``: ``to_chunks(rb.sample())``. (It changes the batch
    size, so it cannot sit inside a ``TensorDictReplayBuffer``, which writes the sampled indices
    back into the batch after its transforms.) Each slice ``[o/a_{r-1}, ..., a_{r+T_p-1}]``
    becomes ``observation (B, 2, D_obs)`` = ``[o_{r-1}, o_r]``, ``action (B, T_p, D)`` and
    ``action_is_pad (B, T_p)`` (all False: strict slices never cross an episode end). The
    windows are built as `rfmp_rl.data.DemonstrationStore`'s sampler builds them
    (`rfmp_rl.data.sample_indices` within each slice, then `rfmp_rl.data.ContextChunk`).

    Args:
        horizon: T_p.
        observation_keys: keys stacked into windows (each ``(..., D)`` -> ``(B, 2, D)``);
            ``"a/b"`` (the manifest's form) or ``("a", "b")``.
        action_key: the action entry, in either form.
        key_map: renames of the output entries, ``{input key: output key}`` (an observation key,
            the action key or ``"action_is_pad"``); e.g. ``{"observation": "obs_window"}``
            writes the windows where a policy reading ``obs_window`` finds them.

    Example:
        >>> from tensordict import TensorDict
        >>> from torchrl.data import LazyTensorStorage, SliceSampler, TensorDictReplayBuffer
        >>> data = TensorDict({"observation": torch.randn(40, 3), "action": torch.randn(40, 2),
        ...                    "episode": torch.arange(40) // 20}, [40])
        >>> rb = TensorDictReplayBuffer(storage=LazyTensorStorage(40), batch_size=5 * 5,
        ...     sampler=SliceSampler(slice_len=5, traj_key="episode", strict_length=True))
        >>> _ = rb.extend(data)
        >>> SlicesToChunks(horizon=4)(rb.sample())["action"].shape
        torch.Size([5, 4, 2])
        >>> SlicesToChunks(horizon=4, key_map={"observation": "obs_window"})(
        ...     rb.sample())["obs_window"].shape
        torch.Size([5, 2, 3])
    """

    def __init__(
        self,
        horizon: int,
        observation_keys: list[NestedKey] | None = None,
        action_key: NestedKey = keys.ACTION,
        key_map: Mapping[NestedKey, NestedKey] | None = None,
    ) -> None:
        super().__init__()
        self.horizon = int(horizon)
        self.observation_keys = [parse_key(k) for k in observation_keys or [keys.OBSERVATION]]
        self.action_key = parse_key(action_key)
        self.key_map = {parse_key(k): parse_key(v) for k, v in dict(key_map or {}).items()}
        written = [*self.observation_keys, self.action_key, keys.ACTION_IS_PAD]
        unknown = [key_name(k) for k in self.key_map if k not in written]
        if unknown:
            raise KeyError(f"SlicesToChunks: key_map renames {unknown}, which it does not write "
                           f"(it writes {[key_name(k) for k in written]})")
        targets = [self.key_map.get(k, k) for k in written]
        if len(set(targets)) != len(targets):
            raise ValueError(f"SlicesToChunks: key_map writes two entries to one key "
                             f"({[key_name(k) for k in targets]})")
        self._chunk = ContextChunk(self.horizon, self.observation_keys, action_key=self.action_key)

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        length = self.horizon + 1
        if tensordict.numel() % length:
            raise ValueError(
                f"SlicesToChunks: a batch of {tensordict.numel()} steps is not a whole number of "
                f"slices of length T_p + 1 = {length}; set SliceSampler(slice_len={length})"
            )
        present = tensordict.keys(include_nested=True, leaves_only=True)
        for key in [*self.observation_keys, self.action_key]:
            if key not in present:
                listed = ", ".join(sorted(key_name(k) for k in present))
                raise KeyError(f"SlicesToChunks: no entry {key_name(key)!r} in the sampled "
                               f"steps (keys: {listed})")
        slices = tensordict.reshape(-1, length)  # (B, T_p + 1), one episode segment each
        batch = slices.shape[0]
        # Within a slice, the reference step r is step 1 and the segment is the episode: the
        # store's index maths give [o_{r-1}, o_r, a_r .. a_{r+T_p-1}] and the padding (none).
        index, pad = sample_indices(
            reference=torch.ones(batch, dtype=torch.long),
            gap=torch.full((batch,), 2, dtype=torch.long),
            episode_start=torch.zeros(batch, dtype=torch.long),
            episode_end=torch.full((batch,), length - 1, dtype=torch.long),
            horizon=self.horizon,
        )
        steps = slices[torch.arange(batch)[:, None], index]  # (B, 2 + T_p)
        chunk = self._chunk(steps)
        chunk.set(keys.ACTION_IS_PAD, pad)
        out = chunk.empty()
        for key in [*self.observation_keys, self.action_key, keys.ACTION_IS_PAD]:
            out.set(self.key_map.get(key, key), chunk.get(key))
        return out
