"""`rfmp-convert --out` and `DemonstrationStore.save` never delete what they did not write, and
replace a previous store atomically (a failed write leaves it intact, with no partial folder)."""

from __future__ import annotations

import pytest
import torch
from tensordict import TensorDict

from rfmp_rl.data import DemonstrationStore
from rfmp_rl.data.convert import main
from rfmp_rl.data.episodes import DataError


def _store(n: int = 12, value: float = 0.0) -> DemonstrationStore:
    ep = TensorDict({"observation": torch.full((n, 3), value), "action": torch.zeros(n, 2)}, [n])
    return DemonstrationStore.from_episodes([ep])


def _leftovers(parent):
    return sorted(p.name for p in parent.iterdir() if p.name.startswith("."))


def test_out_refuses_a_folder_that_is_not_a_store_and_keeps_its_files(tmp_path, capsys):
    bags = tmp_path / "bags"  # e.g. the folder of the source recordings
    bags.mkdir()
    (bags / "run1.bag").write_bytes(b"recording")
    (bags / "notes.txt").write_text("mine")
    assert main(["lasa", "LShape", "--out", str(bags)]) == 2
    err = capsys.readouterr()
    assert "refusing to replace a folder that is not a demonstration store" in err.err
    assert "notes.txt, run1.bag" in err.err and str(bags) in err.err
    assert "episodes" not in err.out  # refused before the read
    assert (bags / "run1.bag").read_bytes() == b"recording"
    assert (bags / "notes.txt").read_text() == "mine"


def test_out_naming_a_file_is_refused_before_reading(tmp_path, capsys):
    target = tmp_path / "data.hdf5"
    target.write_bytes(b"precious")
    assert main(["lasa", "LShape", "--out", str(target)]) == 2
    err = capsys.readouterr()
    assert err.err.startswith("rfmp-convert: error: ") and "--out names a file" in err.err
    assert "Traceback" not in err.err and "episodes" not in err.out  # refused before the read
    assert target.read_bytes() == b"precious"


def test_out_writes_into_a_missing_or_empty_folder_and_replaces_its_own_store(tmp_path):
    empty = tmp_path / "empty"
    empty.mkdir()
    assert main(["lasa", "LShape", "--out", str(empty)]) == 0
    assert DemonstrationStore.load(empty).manifest.episodes == 7
    out = tmp_path / "new" / "store"
    assert main(["lasa", "LShape", "--out", str(out)]) == 0
    assert main(["lasa", "LShape,Sine", "--out", str(out)]) == 0  # a store written before
    assert DemonstrationStore.load(out).manifest.episodes == 14
    assert _leftovers(out.parent) == []


def test_a_store_with_the_users_files_beside_it_is_not_replaced(tmp_path, capsys):
    out = tmp_path / "store"
    _store().save(out)
    (out / "my_notes.txt").write_text("mine")
    (out / "raw_videos").mkdir()
    (out / "raw_videos" / "a.mp4").write_bytes(b"video")
    with pytest.raises(DataError, match="also holds files the store did not write"):
        _store(value=1.0).save(out)
    assert main(["lasa", "LShape", "--out", str(out)]) == 2
    assert "my_notes.txt, raw_videos" in capsys.readouterr().err
    assert (out / "my_notes.txt").read_text() == "mine"
    assert (out / "raw_videos" / "a.mp4").read_bytes() == b"video"
    assert float(DemonstrationStore.load(out).storage[0]["observation"][0]) == 0.0


def test_a_failed_write_leaves_the_previous_store_intact(tmp_path, monkeypatch):
    out = tmp_path / "store"
    _store(12, value=1.0).save(out)
    before = {p.relative_to(out): p.read_bytes() for p in out.rglob("*") if p.is_file()}

    real = TensorDict.memmap_

    def disk_full(self, prefix=None, *args, **kwargs):
        real(self[:1], prefix, *args, **kwargs)  # part of the data reaches the disk, then ...
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(TensorDict, "memmap_", disk_full)
    with pytest.raises(OSError, match="No space left"):
        _store(20, value=2.0).save(out)
    monkeypatch.undo()
    after = {p.relative_to(out): p.read_bytes() for p in out.rglob("*") if p.is_file()}
    assert after == before
    assert _leftovers(tmp_path) == []  # no partial folder remains
    loaded = DemonstrationStore.load(out)
    assert len(loaded) == 12 and float(loaded.episode(0)["observation"][0, 0]) == 1.0


def test_check_store_destination_names_the_path(tmp_path):
    from rfmp_rl.data.store import check_store_destination

    (tmp_path / "x").write_text("")
    with pytest.raises(DataError, match="x"):
        check_store_destination(tmp_path)
    check_store_destination(tmp_path / "missing")  # fine: written fresh


# ----- keys in the "a/b" form the manifest prints ---------------------------------------------
def _nested_store() -> DemonstrationStore:
    n = 20
    ep = TensorDict({"obs": TensorDict({"gripper": torch.arange(n * 2.0).reshape(n, 2),
                                        "eef_pos": torch.ones(n, 3)}, [n]),
                     "action": torch.zeros(n, 2)}, [n])
    return DemonstrationStore.from_episodes([ep])


def test_slash_keys_work_in_the_sampler_and_stats():
    store = _nested_store()
    assert "obs/gripper" in store.manifest.keys
    rb = store.replay_buffer(4, observation_keys=["obs/gripper"], batch_size=5,
                             concat={"observation": ["obs/gripper", "obs/eef_pos"]})
    batch = rb.sample()
    assert batch["obs", "gripper"].shape == (5, 2, 2) and batch["observation"].shape == (5, 2, 5)
    lo, hi = store.stats("obs/gripper")
    assert lo.tolist() == [0.0, 1.0] and hi.tolist() == [38.0, 39.0]
    torch.testing.assert_close(store.stats(("obs", "gripper"))[1], hi)


def test_unknown_keys_are_named_in_the_slash_form():
    store = _nested_store()
    with pytest.raises(DataError, match="obs/gripper"):
        store.stats("obs/grip")
    rb = store.replay_buffer(4, observation_keys=["obs/grip"], batch_size=2)
    with pytest.raises(KeyError, match=r"no entry 'obs/grip'.*obs/gripper"):
        rb.sample()


def test_slices_to_chunks_takes_slash_keys_and_names_missing_ones_in_that_form():
    from rfmp_rl.data.slices import SlicesToChunks

    n = 10
    steps = TensorDict({"obs": TensorDict({"gripper": torch.arange(n * 1.0)[:, None]}, [n]),
                        "action": torch.zeros(n, 2)}, [n])
    out = SlicesToChunks(4, observation_keys=["obs/gripper"])(steps)
    assert out["obs", "gripper"].shape == (2, 2, 1)
    assert out["obs", "gripper"][1, :, 0].tolist() == [5.0, 6.0]
    with pytest.raises(KeyError, match=r"no entry 'obs/grip'.*keys: action, obs/gripper"):
        SlicesToChunks(4, observation_keys=["obs/grip"])(steps)


def test_a_missing_action_key_is_named_in_the_slash_form():
    store = _nested_store()
    rb = store.replay_buffer(4, observation_keys=["obs/gripper"], action_key="act/pose",
                             batch_size=2)
    with pytest.raises(KeyError, match=r"no entry 'act/pose'.*obs/eef_pos, obs/gripper"):
        rb.sample()
