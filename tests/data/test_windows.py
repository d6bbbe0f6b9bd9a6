"""The (window, chunk) samples of the one chunk builder: `DemonstrationStore`'s sampler, and
`SlicesToChunks`, which builds its windows with the store's index maths."""

from __future__ import annotations

import pytest
import torch
from tensordict import TensorDict
from torchrl.data import LazyTensorStorage, SliceSampler, TensorDictReplayBuffer

from rfmp_rl.data import DataError, DemonstrationStore, SlicesToChunks


def episode(length: int, offset: float = 0.0) -> TensorDict:
    t = torch.arange(length, dtype=torch.float32)[:, None] + offset
    return TensorDict({"observation": t.expand(length, 2), "action": t + 0.5}, [length])


def store_samples(episodes, horizon: int, batch: int = 400) -> dict[int, TensorDict]:
    """One sample per reference step (storage index), drawn through the store's buffer."""
    store = DemonstrationStore.from_episodes(episodes)
    rb = store.replay_buffer(horizon, observation_keys=["observation"], batch_size=batch,
                             generator=torch.Generator().manual_seed(0))
    samples = rb.sample()
    return {int(r): samples[int(i)] for i, r in reversed(list(enumerate(samples["index"][:, 1])))}


def test_windows_follow_the_index_convention_and_pad_the_end():
    by_ref = store_samples([episode(5), episode(3, offset=100.0)], horizon=4)
    assert sorted(by_ref) == list(range(8))  # every step of every episode is a reference
    # reference step r=2 of the first episode: window [o_1, o_2], chunk a_2 .. a_5 (a_5 padded)
    torch.testing.assert_close(by_ref[2]["observation"][:, 0], torch.tensor([1.0, 2.0]))
    torch.testing.assert_close(by_ref[2]["action"][:, 0], torch.tensor([2.5, 3.5, 4.5, 4.5]))
    assert by_ref[2]["action_is_pad"].tolist() == [False, False, False, True]
    # the first step repeats o_0 as its context; episodes never mix
    torch.testing.assert_close(by_ref[5]["observation"][:, 0], torch.tensor([100.0, 100.0]))
    for r, sample in by_ref.items():
        in_second = r >= 5
        assert bool((sample["observation"] >= 100).all()) == in_second, r
        assert bool((sample["action"] >= 100).all()) == in_second, r
        assert bool((sample["observation"] < 100).all()) != in_second, r
    # padded entries repeat the last action exactly
    last = by_ref[7]
    assert last["action"][:, 0].tolist() == [102.5] * 4
    assert last["action_is_pad"].tolist() == [False] + [True] * 3


def test_bad_episodes_are_refused():
    store = DemonstrationStore.from_episodes([episode(3)])
    with pytest.raises(ValueError, match="horizon"):
        store.replay_buffer(0, observation_keys=["observation"])
    with pytest.raises(DataError, match="episode 0"):
        DemonstrationStore.from_episodes([episode(3).unsqueeze(0)])
    with pytest.raises(DataError, match="episode 1"):
        DemonstrationStore.from_episodes([episode(3), episode(3)[:0]])


def test_slices_give_the_samples_the_store_gives():
    """A slice [o/a_{r-1} .. a_{r+T_p-1}] of a SliceSampler buffer becomes the store's sample of
    reference step r."""
    episodes = [episode(9), episode(7, offset=100.0)]
    horizon = 4
    by_ref = store_samples(episodes, horizon)
    data = torch.cat([ep.clone().set("episode", torch.full((len(ep),), i))
                      for i, ep in enumerate(episodes)])
    rb = TensorDictReplayBuffer(
        storage=LazyTensorStorage(len(data)), batch_size=6 * (horizon + 1),
        sampler=SliceSampler(slice_len=horizon + 1, traj_key="episode", strict_length=True))
    rb.extend(data)
    steps = rb.sample()
    chunks = SlicesToChunks(horizon)(steps)
    assert chunks.batch_size == (6,)
    assert set(chunks.keys()) == {"observation", "action", "action_is_pad"}
    assert not chunks["action_is_pad"].any()  # strict slices never cross an episode end
    starts = steps["index"].reshape(6, horizon + 1)[:, 0]  # storage index of o_{r-1}
    for i, start in enumerate(starts.tolist()):
        expected = by_ref[start + 1]  # the reference step is the slice's second
        torch.testing.assert_close(chunks["observation"][i], expected["observation"])
        torch.testing.assert_close(chunks["action"][i], expected["action"])


def test_slices_of_the_wrong_length_or_keys_are_refused():
    steps = TensorDict({"observation": torch.zeros(10, 2), "action": torch.zeros(10, 1)}, [10])
    with pytest.raises(ValueError, match="slice_len=5"):
        SlicesToChunks(horizon=4)(steps[:7])
    with pytest.raises(KeyError, match="'obs'"):
        SlicesToChunks(horizon=4, observation_keys=["obs"])(steps)
