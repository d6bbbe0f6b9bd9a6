"""The demonstration store and the paper's (context, reference, chunk) sampler, index by index."""

from __future__ import annotations

import pytest
import torch
from tensordict import TensorDict

from rfmp_rl.data.episodes import DataError, Manifest, make_episode
from rfmp_rl.data.store import DemonstrationStore, HorizonContextSampler, sample_indices

# Two hand-built episodes: o_i = 10 * episode + i (as a 1-D observation), a_i = 1000 + o_i.
LENGTHS = (7, 5)


def _episodes() -> list[TensorDict]:
    eps = []
    for e, n in enumerate(LENGTHS):
        obs = (10.0 * e + torch.arange(n, dtype=torch.float32))[:, None]
        eps.append(TensorDict({"observation": obs, "action": 1000.0 + obs}, [n]))
    return eps


def _paper_sample(episode: TensorDict, s: int, c: int, horizon: int):
    """The paper's sample for index s (reference o^{s-1}) and context c, with edge padding, built
    independently from the definitions (stored step i holds o_i and the action a_i commanded
    after it, i.e. the paper's a^{i+1})."""
    n = episode.batch_size[0]
    obs, act = episode["observation"][:, 0], episode["action"][:, 0]
    ref = obs[s - 1]
    ctx = obs[max(c, 0)]
    chunk = torch.stack([act[min(s - 1 + j, n - 1)] for j in range(horizon)])
    pad = torch.tensor([s - 1 + j > n - 1 for j in range(horizon)])
    return ctx, ref, chunk, pad


@pytest.mark.parametrize("horizon", [1, 4, 9])
def test_every_reference_step_matches_the_paper_with_t_o_2(horizon):
    eps = _episodes()
    store = DemonstrationStore.from_episodes(eps)
    for e, ep in enumerate(eps):
        start = int(store.episode_starts[e])
        n = ep.batch_size[0]
        for s in range(1, n + 1):  # every reference o^{s-1}: first to last step of the episode
            r = torch.tensor([start + s - 1])
            index, pad = sample_indices(
                r, torch.tensor([2]), torch.tensor([start]), torch.tensor([start + n - 1]), horizon
            )
            data = store.storage.get(index)  # (1, 2 + T_p)
            ctx, ref, chunk, want_pad = _paper_sample(ep, s, s - 2, horizon)
            assert data["observation"][0, 0, 0] == ctx
            assert data["observation"][0, 1, 0] == ref
            torch.testing.assert_close(data["action"][0, 2:, 0], chunk, rtol=0, atol=0)
            assert pad[0].tolist() == want_pad.tolist()


def test_first_and_last_steps_are_edge_padded():
    eps = _episodes()
    store = DemonstrationStore.from_episodes(eps)
    # Second episode starts at storage index 7, ends at 11 (values 10..14).
    start, end = torch.tensor([7]), torch.tensor([11])
    index, pad = sample_indices(torch.tensor([7]), torch.tensor([2]), start, end, horizon=4)
    assert index.tolist() == [[7, 7, 7, 8, 9, 10]]  # context before the start repeats o_start
    assert pad.tolist() == [[False, False, False, False]]
    index, pad = sample_indices(torch.tensor([11]), torch.tensor([2]), start, end, horizon=4)
    assert index.tolist() == [[10, 11, 11, 11, 11, 11]]  # chunk past the end repeats a_end
    assert pad.tolist() == [[False, True, True, True]]
    rows = store.storage.get(index)
    assert rows["action"][0, 2:, 0].tolist() == [1014.0] * 4


def test_replay_buffer_samples_obey_the_definition_with_random_context():
    """T_o = 4: c ~ U{s-4, ..., s-2}; every batch row is checked against the definition."""
    eps = _episodes()
    store = DemonstrationStore.from_episodes(eps)
    rb = store.replay_buffer(
        horizon=3, observation_keys=["observation"], obs_horizon=4, batch_size=512,
        generator=torch.Generator().manual_seed(0),
    )
    batch = rb.sample()
    assert batch.batch_size == torch.Size([512])
    gaps = batch["obs_gap"]
    assert set(gaps.long().tolist()) == {2, 3, 4}
    for i in range(512):
        ref_value = batch["observation"][i, 1, 0].item()
        e = int(ref_value // 10)
        s = int(ref_value - 10 * e) + 1
        ctx, ref, chunk, pad = _paper_sample(eps[e], s, s - int(gaps[i]), 3)
        assert batch["observation"][i, 0, 0] == ctx
        assert torch.equal(batch["action"][i, :, 0], chunk)
        assert batch["action_is_pad"][i].tolist() == pad.tolist()
    # Every reference step of every episode is reachable (12 steps in all).
    assert len(set(batch["observation"][:, 1, 0].tolist())) == sum(LENGTHS)


def test_sampler_is_uniform_over_steps_and_reproducible():
    starts, lengths = torch.tensor([0, 100]), torch.tensor([100, 300])
    a = HorizonContextSampler(starts, lengths, 4, generator=torch.Generator().manual_seed(3))
    b = HorizonContextSampler(starts, lengths, 4, generator=torch.Generator().manual_seed(3))
    ia, _ = a.sample(None, 40000)
    ib, _ = b.sample(None, 40000)
    assert torch.equal(ia, ib)
    share_second = (ia[:, 1] >= 100).float().mean().item()
    assert abs(share_second - 0.75) < 0.015  # 300 of 400 steps


def test_sampler_rejects_bad_arguments():
    with pytest.raises(ValueError, match="horizon"):
        HorizonContextSampler(torch.tensor([0]), torch.tensor([3]), horizon=0)
    with pytest.raises(ValueError, match="obs_horizon"):
        HorizonContextSampler(torch.tensor([0]), torch.tensor([3]), horizon=2, obs_horizon=1)
    with pytest.raises(ValueError, match="each >= 1 step"):
        HorizonContextSampler(torch.tensor([0, 3]), torch.tensor([3, 0]), horizon=2)


def test_images_go_to_memmap_and_come_out_channels_first(tmp_path):
    eps = []
    for n in (6, 4):
        img = torch.randint(0, 255, (n, 8, 6, 3), dtype=torch.uint8)
        eps.append(TensorDict({"img": img, "state": torch.randn(n, 2), "action": torch.randn(n, 2)},
                              [n]))
    store = DemonstrationStore.from_episodes(eps, scratch_dir=tmp_path / "scratch")
    assert type(store.storage).__name__ == "LazyMemmapStorage"
    assert type(store.storage._storage["img"]).__name__ == "MemoryMappedTensor"
    rb = store.replay_buffer(2, ["state"], camera_keys=["img"], batch_size=16)
    batch = rb.sample()
    assert batch["img"].shape == (16, 2, 3, 8, 6) and batch["img"].dtype == torch.uint8
    flat = torch.cat(eps)
    for i in range(16):
        c, r = batch["index"][i, :2].tolist()
        assert torch.equal(batch["img"][i, 0], flat["img"][c].permute(2, 0, 1))
        assert torch.equal(batch["img"][i, 1], flat["img"][r].permute(2, 0, 1))


def test_concat_builds_one_observation_vector():
    n = 5
    ep = TensorDict({"kp": torch.arange(n * 4.0).reshape(n, 2, 2), "pos": -torch.ones(n, 2),
                     "action": torch.zeros(n, 2)}, [n])
    store = DemonstrationStore.from_episodes([ep])
    batch = store.replay_buffer(2, concat={"observation": ["kp", "pos"]}, batch_size=4).sample()
    assert batch["observation"].shape == (4, 2, 6)
    r = batch["index"][:, 1]
    assert torch.equal(batch["observation"][:, 1, :4], ep["kp"][r].reshape(4, 4))
    assert torch.equal(batch["observation"][:, 1, 4:], -torch.ones(4, 2))
    # concat into the action would be overwritten by the action chunk: refused
    with pytest.raises(ValueError, match="cannot build the action 'action'"):
        store.replay_buffer(2, concat={"action": ["kp", "pos"]})


def test_save_and_load_round_trip(tmp_path):
    eps = _episodes()
    manifest = Manifest(source="hand", format="episodes", rate_hz=10.0)
    for i, ep in enumerate(eps):
        manifest.add(ep, name=f"ep{i}")
    store = DemonstrationStore.from_episodes(eps, manifest)
    store.save(tmp_path / "store")
    loaded = DemonstrationStore.load(tmp_path / "store")
    assert loaded.manifest == manifest
    assert loaded.episode_lengths.tolist() == list(LENGTHS)
    for e in range(2):
        assert torch.equal(loaded.episode(e)["observation"], eps[e]["observation"])
    lo, hi = loaded.stats("action")
    assert lo.tolist() == [1000.0] and hi.tolist() == [1014.0]


def test_load_names_the_missing_part(tmp_path):
    (tmp_path / "store").mkdir()
    with pytest.raises(DataError, match=r"store: not a demonstration store: storage is missing"):
        DemonstrationStore.load(tmp_path / "store")


def test_stats_names_an_unknown_key():
    store = DemonstrationStore.from_episodes(_episodes())
    with pytest.raises(DataError, match="key state: no such key"):
        store.stats("state")


def test_episodes_with_different_keys_are_refused():
    a = make_episode({"action": torch.zeros(3, 2), "state": torch.zeros(3, 4)}, file="f", episode=0)
    b = make_episode({"action": torch.zeros(3, 2), "state": torch.zeros(3, 5)}, file="f", episode=1)
    manifest = Manifest(source="f", format="x")
    manifest.add(a, name=0)
    with pytest.raises(DataError, match=r"f: key state, episode 1: per-step shape"):
        manifest.add(b, name=1)


@pytest.mark.parametrize("memmap", [False, True])
def test_timestamps_stay_float64_through_save_and_load(tmp_path, memmap):
    # values a float32 cast would change: 1/3, 1e-9 steps, a large offset
    ts = [torch.tensor([0.0, 1.0 / 3.0, 0.5 + 1e-9, 12345.678901234567], dtype=torch.float64),
          torch.tensor([0.0, 0.1, 0.2], dtype=torch.float64)]
    eps = [make_episode({"action": torch.zeros(len(t), 2), "timestamp": t}, file="m", episode=i)
           for i, t in enumerate(ts)]
    store = DemonstrationStore.from_episodes(eps, memmap=memmap)
    assert store.manifest.keys["timestamp"] == {"shape": [], "dtype": "float64"}
    back = DemonstrationStore.load(store.save(tmp_path / "store"))
    for i, t in enumerate(ts):
        got = back.episode(i)["timestamp"]
        assert got.dtype == torch.float64
        assert torch.equal(got, t)
    assert back.manifest.keys["timestamp"] == {"shape": [], "dtype": "float64"}


def test_timestamps_are_not_sampled_as_observations():
    eps = [TensorDict({"observation": torch.zeros(6, 1), "action": torch.zeros(6, 1),
                       "timestamp": torch.arange(6, dtype=torch.float64) / 10}, [6])]
    batch = DemonstrationStore.from_episodes(eps).replay_buffer(
        3, ["observation"], batch_size=4).sample()
    assert "timestamp" not in batch


@pytest.mark.parametrize(("values", "message"), [
    (torch.tensor([0.0, 0.1, 0.1], dtype=torch.float64), "step 2: timestamps not increasing"),
    (torch.tensor([0.5, 0.6, 0.7], dtype=torch.float64), "first timestamp must be 0.0"),
    (torch.tensor([0.0, 0.1, 0.2], dtype=torch.float32), "must be float64"),
])
def test_bad_timestamps_refused(values, message):
    with pytest.raises(DataError, match=message):
        make_episode({"action": torch.zeros(3, 1), "timestamp": values}, file="f", episode=0)
