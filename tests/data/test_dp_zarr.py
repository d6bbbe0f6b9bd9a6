"""Diffusion Policy zarr reader: the real Push-T set, exact round trips and every bad input."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
import torch

from rfmp_rl.data.convert import main as convert_main
from rfmp_rl.data.dp_zarr import read_dp_zarr, write_dp_zarr
from rfmp_rl.data.episodes import DataError
from rfmp_rl.data.store import DemonstrationStore

PUSHT = Path(os.environ.get("RFMP_PUSHT_ZARR", Path(__file__).parents[3] / "shared/data/pusht/"
                            "pusht_cchi_v7_replay.zarr"))


def _fixture(tmp_path, **overrides):
    rng = np.random.default_rng(0)
    arrays = {
        "action": rng.normal(size=(9, 2)).astype(np.float32),
        "state": rng.normal(size=(9, 5)).astype(np.float32),
        "keypoint": rng.normal(size=(9, 9, 2)).astype(np.float32),
        "img": rng.integers(0, 256, size=(9, 6, 6, 3)).astype(np.float32),
    }
    ends = overrides.pop("episode_ends", [4, 9])
    arrays.update(overrides)
    path = tmp_path / "demo.zarr"
    write_dp_zarr(path, arrays, ends)
    return path, arrays


@pytest.mark.skipif(not PUSHT.exists(), reason=f"Push-T zarr not found at {PUSHT}: place Diffusion "
                    "Policy's pusht_cchi_v7_replay.zarr there or set RFMP_PUSHT_ZARR")
def test_real_pusht_loads_206_episodes_25650_steps_into_memmap(tmp_path):
    episodes, manifest = read_dp_zarr(PUSHT)
    assert manifest.episodes == len(episodes) == 206
    assert manifest.steps == sum(ep.batch_size[0] for ep in episodes) == 25650
    assert manifest.keys["img"] == {"shape": [96, 96, 3], "dtype": "uint8"}
    assert manifest.keys["keypoint"] == {"shape": [9, 2], "dtype": "float32"}
    assert manifest.rate_hz == 10.0
    store = DemonstrationStore.from_episodes(episodes, manifest, scratch_dir=tmp_path / "mm")
    assert type(store.storage).__name__ == "LazyMemmapStorage"
    img = store.storage._storage["img"]
    assert type(img).__name__ == "MemoryMappedTensor" and img.dtype == torch.uint8
    assert img.shape == (25650, 96, 96, 3)
    assert store.episode_lengths[:3].tolist() == [161, 118, 141]  # meta/episode_ends 161, 279, 420
    batch = store.replay_buffer(16, ["state"], camera_keys=["img"], batch_size=8).sample()
    assert batch["img"].shape == (8, 2, 3, 96, 96)


def test_round_trip_is_exact(tmp_path):
    path, arrays = _fixture(tmp_path)
    episodes, manifest = read_dp_zarr(path)
    assert [ep.batch_size[0] for ep in episodes] == [4, 5]
    assert manifest.episodes == 2 and manifest.steps == 9
    for name, values in arrays.items():
        got = torch.cat([ep[name] for ep in episodes]).numpy()
        want = values.astype(np.uint8) if name == "img" else values
        np.testing.assert_array_equal(got, want)
    assert episodes[0]["img"].dtype == torch.uint8


def test_selected_keys_always_include_action(tmp_path):
    path, _ = _fixture(tmp_path)
    episodes, manifest = read_dp_zarr(path, keys=["state"])
    assert sorted(manifest.keys) == ["action", "state", "timestamp"]


def test_convert_command_writes_a_loadable_store(tmp_path, capsys):
    path, arrays = _fixture(tmp_path)
    assert convert_main(["dp_zarr", str(path), "--out", str(tmp_path / "store")]) == 0
    out = capsys.readouterr().out
    assert "2 episodes, 9 steps, 10 Hz" in out and "img" in out and "uint8" in out
    store = DemonstrationStore.load(tmp_path / "store")
    np.testing.assert_array_equal(store.episode(1)["state"].numpy(), arrays["state"][4:])


def test_missing_file(tmp_path):
    with pytest.raises(DataError, match=r"nope\.zarr: no such zarr store"):
        read_dp_zarr(tmp_path / "nope.zarr")


def test_missing_key(tmp_path):
    path, _ = _fixture(tmp_path)
    with pytest.raises(DataError, match=r"demo\.zarr: key data/velocity: missing array"):
        read_dp_zarr(path, keys=["velocity"])


def test_missing_episode_ends(tmp_path):
    path, _ = _fixture(tmp_path)
    import shutil

    shutil.rmtree(path / "meta" / "episode_ends")
    with pytest.raises(DataError, match=r"demo\.zarr: key meta/episode_ends: missing array"):
        read_dp_zarr(path)


def test_corrupt_chunk(tmp_path):
    path, _ = _fixture(tmp_path)
    chunk = path / "data" / "state" / "0.0"
    chunk.write_bytes(chunk.read_bytes()[:7])  # truncated
    with pytest.raises(DataError, match=r"demo\.zarr: key data/state, episode 0, step 0: cannot "):
        read_dp_zarr(path)


def test_not_a_zarr_store(tmp_path):
    bad = tmp_path / "bad.zarr"
    bad.mkdir()
    (bad / ".zgroup").write_text("{not json")
    with pytest.raises(DataError, match=r"bad\.zarr: cannot open"):
        read_dp_zarr(bad)


@pytest.mark.parametrize("value", [np.nan, np.inf])
def test_non_finite_value(tmp_path, value):
    state = np.zeros((9, 5), np.float32)
    state[6, 2] = value  # episode 1, step 2
    path, _ = _fixture(tmp_path, state=state)
    with pytest.raises(DataError, match=r"key data/state, episode 1, step 2: non-finite value"):
        read_dp_zarr(path)


def test_mismatched_lengths(tmp_path):
    path, _ = _fixture(tmp_path, keypoint=np.zeros((8, 9, 2), np.float32))
    with pytest.raises(DataError, match=r"key data/keypoint, episode 1, step 4: 8 steps, but"):
        read_dp_zarr(path)


def test_empty_episode(tmp_path):
    path, _ = _fixture(tmp_path, episode_ends=[4, 4, 9])
    with pytest.raises(DataError, match=r"key meta/episode_ends, episode 1: .*\(empty or reversed"):
        read_dp_zarr(path)


def test_image_value_out_of_range(tmp_path):
    img = np.zeros((9, 6, 6, 3), np.float32)
    img[5, 1, 1, 0] = 255.5  # episode 1, step 1
    path, _ = _fixture(tmp_path, img=img)
    with pytest.raises(DataError, match=r"key data/img, episode 1, step 1: image value 255.5"):
        read_dp_zarr(path)


def test_timestamps_from_the_rate(tmp_path):
    path, _ = _fixture(tmp_path)
    episodes, _ = read_dp_zarr(path, keys=["state"], rate_hz=10.0)
    ts = episodes[1]["timestamp"]
    assert ts.dtype == torch.float64
    assert ts.tolist() == [i / 10.0 for i in range(episodes[1].batch_size[0])]
    episodes, manifest = read_dp_zarr(path, keys=["state"], rate_hz=None)
    assert "timestamp" not in episodes[0] and "timestamp" not in manifest.keys
