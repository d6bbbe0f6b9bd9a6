"""All (observation window, action chunk) training samples of a set of episodes, precomputed.

For every step ``r`` of every episode (index convention of `rfmp_rl.data.slices`): the window
``[o_{r-1}, o_r]`` (T_o = 2; the first step repeats ``o_0``) and the chunk
``[a_r, ..., a_{r+T_p-1}]``; steps past the episode end repeat the last action and are marked in
``action_is_pad``. Small data sets (LASA, toy tasks) fit in memory this way; the samples go into
a TorchRL ``TensorDictReplayBuffer`` with a ``LazyTensorStorage`` and a random sampler.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from tensordict import TensorDict
from tensordict.utils import NestedKey

from rfmp_rl import keys

__all__ = ["episode_windows"]


def episode_windows(
    episodes: Sequence[TensorDict],
    horizon: int,
    observation_keys: Sequence[NestedKey] = (keys.OBSERVATION,),
    action_key: NestedKey = keys.ACTION,
) -> TensorDict:
    """Stack every training sample of ``episodes`` (each a TensorDict with batch size ``[T]``).

    Returns:
        A TensorDict with batch size ``[N]`` (N = total steps): each observation key
        ``(N, 2, D)``, ``action (N, T_p, D_a)``, ``action_is_pad (N, T_p)``, and ``episode (N,)``
        (position of the source episode in ``episodes``).

    Example:
        >>> ep = TensorDict({"observation": torch.arange(3.0)[:, None],
        ...                  "action": torch.arange(1.0, 4.0)[:, None]}, [3])
        >>> w = episode_windows([ep], horizon=2)
        >>> w["observation"][0, :, 0].tolist(), w["action"][2, :, 0].tolist()
        ([0.0, 0.0], [3.0, 3.0])
        >>> w["action_is_pad"][2].tolist()
        [False, True]
    """
    if horizon < 1:
        raise ValueError(f"episode_windows: horizon must be >= 1, got {horizon}")
    out = []
    for i, ep in enumerate(episodes):
        if ep.batch_dims != 1 or ep.batch_size[0] < 1:
            raise ValueError(
                f"episode_windows: episode {i} must have batch size [T] with T >= 1, "
                f"got {tuple(ep.batch_size)}"
            )
        length = ep.batch_size[0]
        steps = torch.arange(length)
        obs_idx = (steps[:, None] + torch.tensor([-1, 0])).clamp(0, length - 1)  # (T, 2)
        act_idx = steps[:, None] + torch.arange(horizon)  # (T, T_p)
        pad = act_idx > length - 1
        act_idx = act_idx.clamp(max=length - 1)
        sample = TensorDict({}, batch_size=[length])
        for key in observation_keys:
            sample.set(key, ep.get(key)[obs_idx])
        sample.set(action_key, ep.get(action_key)[act_idx])
        sample.set(keys.ACTION_IS_PAD, pad)
        sample.set("episode", torch.full((length,), i, dtype=torch.long))
        out.append(sample)
    return torch.cat(out)
