from __future__ import annotations

import pytest
import torch
from tensordict import TensorDict

from rfmp_rl.data import episode_windows


def episode(length: int, offset: float = 0.0) -> TensorDict:
    t = torch.arange(length, dtype=torch.float32)[:, None] + offset
    return TensorDict({"observation": t.expand(length, 2), "action": t + 0.5}, [length])


def test_windows_follow_the_index_convention_and_pad_the_end():
    w = episode_windows([episode(5), episode(3, offset=100.0)], horizon=4)
    assert w.batch_size == (8,)
    # reference step r=2 of the first episode: window [o_1, o_2], chunk a_2 .. a_5 (a_5 padded)
    torch.testing.assert_close(w["observation"][2, :, 0], torch.tensor([1.0, 2.0]))
    torch.testing.assert_close(w["action"][2, :, 0], torch.tensor([2.5, 3.5, 4.5, 4.5]))
    assert w["action_is_pad"][2].tolist() == [False, False, False, True]
    # the first step repeats o_0 as its context; episodes never mix
    torch.testing.assert_close(w["observation"][5, :, 0], torch.tensor([100.0, 100.0]))
    assert w["episode"].tolist() == [0] * 5 + [1] * 3
    assert (w["action"][5:] >= 100).all()
    # padded entries repeat the last action exactly
    last = w["action"][7, :, 0]
    assert last.tolist() == [102.5] * 4 and w["action_is_pad"][7].tolist() == [False] + [True] * 3


def test_bad_episodes_are_refused():
    with pytest.raises(ValueError, match="horizon"):
        episode_windows([episode(3)], horizon=0)
    with pytest.raises(ValueError, match="episode 0"):
        episode_windows([episode(3).unsqueeze(0)], horizon=2)
