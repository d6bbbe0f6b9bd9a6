"""`rfmp-convert minari`: a Minari dataset written with Minari's own API -> a DemonstrationStore,
aligned as (o_i, a_i) with the final observation dropped; never a download."""

from __future__ import annotations

import h5py
import numpy as np
import pytest
import torch

minari = pytest.importorskip("minari", reason="the fixture is written with minari==0.5.4")

import gymnasium as gym  # noqa: E402
from minari.data_collector.episode_buffer import EpisodeBuffer  # noqa: E402

from rfmp_rl.data import DemonstrationStore  # noqa: E402
from rfmp_rl.data.convert import main  # noqa: E402
from rfmp_rl.data.episodes import DataError  # noqa: E402
from rfmp_rl.data.minari import read_minari  # noqa: E402

DATASET_ID = "toy/counter-v0"
LENGTHS = (5, 7, 4)


def _observations(e: int, n: int) -> np.ndarray:
    """``(n + 1, 3)``: o_t = (episode, t, t / 2)."""
    t = np.arange(n + 1, dtype=np.float64)
    return np.stack([np.full_like(t, e), t, 0.5 * t], axis=1)


@pytest.fixture
def minari_root(tmp_path, monkeypatch):
    """A Minari dataset (Box observations, one more than actions) under MINARI_DATASETS_PATH;
    a_t = 100 e + t, r_t = 10 e + t, terminated at the last step."""
    root = tmp_path / "minari"
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(root))
    buffers = []
    for e, n in enumerate(LENGTHS):
        buffers.append(EpisodeBuffer(
            id=e, observations=_observations(e, n),
            actions=(100.0 * e + np.arange(n, dtype=np.float32))[:, None],
            rewards=list(10.0 * e + np.arange(n, dtype=np.float64)),
            terminations=[False] * (n - 1) + [True], truncations=[False] * n, infos={},
        ))
    with pytest.warns(UserWarning):  # Minari warns that no environment is given
        minari.create_dataset_from_buffers(
            DATASET_ID, buffers,
            action_space=gym.spaces.Box(-1e3, 1e3, (1,), np.float32),
            observation_space=gym.spaces.Box(-1e3, 1e3, (3,), np.float64),
            algorithm_name="counter", author="rfmp_rl tests", author_email="tests@example.org",
            code_permalink="tests/data/test_minari.py", description="counter fixture",
        )
    return root


def test_convert_aligns_o_i_with_a_i(minari_root, tmp_path):
    assert (minari_root / DATASET_ID / "data" / "main_data.hdf5").is_file()
    assert main(["minari", DATASET_ID, "--out", str(tmp_path / "store")]) == 0
    store = DemonstrationStore.load(tmp_path / "store")
    assert store.episode_lengths.tolist() == list(LENGTHS)  # T actions, not T + 1 observations
    assert store.manifest.format == "minari"
    assert store.manifest.extra["dataset_id"] == DATASET_ID
    assert store.manifest.rate_hz is None and "timestamp" not in store.manifest.keys
    for e, n in enumerate(LENGTHS):
        ep = store.episode(e)
        obs = ep["observation"]
        assert obs.dtype == torch.float64
        assert torch.equal(obs, torch.from_numpy(_observations(e, n)[:-1]))  # o_0 .. o_{T-1}
        assert ep["action"][:, 0].tolist() == [100.0 * e + t for t in range(n)]
        # step i holds the action taken after o_i and the reward it produced
        assert torch.equal(ep["observation"][:, 1].float(), ep["action"][:, 0] - 100.0 * e)
        assert ep["reward"][:, 0].tolist() == [10.0 * e + t for t in range(n)]
        assert ep["terminated"][:, 0].tolist() == [False] * (n - 1) + [True]
        assert not ep["truncated"].any()


def test_local_path_episode_subset_and_rate(minari_root):
    episodes, manifest = read_minari(minari_root / DATASET_ID, episodes=[2, 0], rate_hz=20.0)
    assert manifest.episode_names == ["episode_2", "episode_0"]
    assert manifest.episode_lengths == [LENGTHS[2], LENGTHS[0]]
    ts = episodes[0]["timestamp"]
    assert ts.dtype == torch.float64 and ts.tolist() == [t / 20.0 for t in range(LENGTHS[2])]
    with pytest.raises(DataError, match="no episode 9"):
        read_minari(minari_root / DATASET_ID, episodes=[9])


def test_dict_observations_become_nested_keys(tmp_path, monkeypatch):
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path))
    n = 4
    buffer = EpisodeBuffer(
        id=0,
        observations={"pos": _observations(0, n)[:, :2],
                      "goal": np.tile(np.array([[1.0, 2.0]]), (n + 1, 1))},
        actions=np.zeros((n, 2), np.float32), rewards=[0.0] * n,
        terminations=[False] * n, truncations=[False] * (n - 1) + [True], infos={},
    )
    space = gym.spaces.Dict({"pos": gym.spaces.Box(-9, 9, (2,), np.float64),
                             "goal": gym.spaces.Box(-9, 9, (2,), np.float64)})
    with pytest.warns(UserWarning):
        minari.create_dataset_from_buffers(
            "toy/dict-v0", [buffer], action_space=gym.spaces.Box(-1, 1, (2,), np.float32),
            observation_space=space, algorithm_name="x", author="x",
            author_email="x@example.org", code_permalink="x", description="x")
    (ep,), manifest = read_minari("toy/dict-v0")
    assert sorted(k for k in manifest.keys if k.startswith("observation")) == [
        "observation/goal", "observation/pos"]
    assert ep["observation", "pos"][:, 1].tolist() == [0.0, 1.0, 2.0, 3.0]
    assert ep["truncated"][:, 0].tolist() == [False, False, False, True]


def test_dataset_not_on_disk_is_refused_without_download(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path / "empty"))
    with pytest.raises(DataError, match="not found on disk .*nothing is downloaded"):
        read_minari("D4RL/door/human-v2")
    assert main(["minari", "D4RL/door/human-v2", "--out", str(tmp_path / "store")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("rfmp-convert: error: D4RL/door/human-v2: Minari dataset not found")
    assert str(tmp_path / "empty" / "D4RL" / "door" / "human-v2") in err
    assert "Traceback" not in err


def test_observation_count_must_exceed_actions_by_one(minari_root):
    path = minari_root / DATASET_ID / "data" / "main_data.hdf5"
    with h5py.File(path, "r+") as f:
        obs = f["episode_1/observations"][()]
        del f["episode_1/observations"]
        f["episode_1/observations"] = obs[:-1]  # T observations for T actions
    with pytest.raises(DataError, match="7 observations for 7 actions") as err:
        read_minari(DATASET_ID)
    assert err.value.file == str(path) and err.value.key == "observations"
    assert err.value.episode == "episode_1"


def test_torchrl_minari_replay_still_reads_zeros(minari_root, tmp_path):
    """Why `read_minari` reads the HDF5 file itself: TorchRL 0.14.1's MinariExperienceReplay
    (local load) copies the data with ``memmap_like``, which keeps shapes but not values. When
    this fails, TorchRL reads the values again and the reader could use it."""
    from torchrl.data.datasets import MinariExperienceReplay

    rb = MinariExperienceReplay(DATASET_ID, batch_size=4, root=tmp_path / "torchrl",
                                download=False, load_from_local_minari=True)
    data = rb[:]
    assert data["action"].shape == (sum(LENGTHS), 1)
    # the file holds actions 100 e + t and observations (e, t, t / 2), mostly non-zero
    assert not data["action"].any() and not data["observation"].any()


def test_text_observations_are_skipped_and_listed(tmp_path, capsys):
    """MiniGrid-like: observations/mission is text; the numeric entries are still converted."""
    folder = tmp_path / "minigrid" / "text-v0" / "data"
    folder.mkdir(parents=True)
    n = 4
    with h5py.File(folder / "main_data.hdf5", "w") as f:
        group = f.create_group("episode_0")
        obs = group.create_group("observations")
        obs["image"] = np.arange((n + 1) * 27, dtype=np.uint8).reshape(n + 1, 3, 3, 3)
        obs["direction"] = np.arange(n + 1, dtype=np.int64)
        obs.create_dataset("mission", data=["go to the ball"] * (n + 1),
                           dtype=h5py.string_dtype())
        group["actions"] = np.arange(n, dtype=np.int64)
        group["rewards"] = np.zeros(n)
        group["terminations"] = np.zeros(n, bool)
        group["truncations"] = np.zeros(n, bool)
        group.create_group("infos")
    (ep,), manifest = read_minari(folder.parent)
    assert ep["observation", "direction"].tolist() == [0, 1, 2, 3]
    assert "observation/mission" not in manifest.keys
    assert manifest.extra["skipped_keys"] == {"observation/mission": "non-numeric data (object)"}
    assert "observation/mission: not stored (non-numeric data (object))" in str(manifest)
    assert main(["minari", str(folder.parent), "--out", str(tmp_path / "store")]) == 0
    assert "observation/mission: not stored" in capsys.readouterr().out
    stored = DemonstrationStore.load(tmp_path / "store")
    assert stored.manifest.extra["skipped_keys"] == manifest.extra["skipped_keys"]


def test_duplicate_episode_ids_are_refused(minari_root):
    with pytest.raises(DataError, match="episode 1 is asked for twice"):
        read_minari(DATASET_ID, episodes=[1, 1])
