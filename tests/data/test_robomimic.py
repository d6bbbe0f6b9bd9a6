"""robomimic HDF5 reader and writer: exact round trips, ordering, splits, manifest, bad input."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest
import torch
from tensordict import TensorDict

h5py = pytest.importorskip("h5py", reason="robomimic tests need h5py (rfmp_rl[data])")

from rfmp_rl.data.episodes import DataError  # noqa: E402
from rfmp_rl.data.robomimic import read_robomimic, write_robomimic  # noqa: E402

ENV_ARGS = {
    "env_name": "Lift",
    "env_type": 1,
    "env_kwargs": {"control_freq": 20, "robots": ["Panda"], "has_renderer": False},
}
IMAGE = "agentview_image"
LOW_DIM = ("object", "robot0_eef_pos", "robot0_eef_quat", "robot0_gripper_qpos")


def demo_arrays(length: int, seed: int) -> dict:
    """One demo as robomimic stores it: float64 low-dim (float32 quat), uint8 image, int dones."""
    rng = np.random.default_rng(seed)
    obs = {
        IMAGE: rng.integers(0, 256, (length + 1, 8, 6, 3), dtype=np.uint8),
        "object": rng.standard_normal((length + 1, 10)),
        "robot0_eef_pos": rng.standard_normal((length + 1, 3)),
        "robot0_eef_quat": rng.standard_normal((length + 1, 4)).astype(np.float32),
        "robot0_gripper_qpos": rng.standard_normal((length + 1, 2)),
    }
    dones = np.zeros(length, dtype=np.int64)
    dones[-1] = 1
    return {
        "actions": rng.uniform(-1, 1, (length, 7)),
        "rewards": rng.standard_normal(length),
        "dones": dones,
        "states": rng.standard_normal((length, 5)),
        "obs": {k: v[:-1].copy() for k, v in obs.items()},
        "next_obs": {k: v[1:].copy() for k, v in obs.items()},
    }


def write_fixture(
    path: Path,
    demos: dict[str, dict],
    *,
    env_args: dict | None = ENV_ARGS,
    mask: dict[str, list[bytes]] | None = None,
    total: int | None = None,
    num_samples: dict[str, int] | None = None,
) -> Path:
    """A robomimic file written with h5py directly (not through write_robomimic)."""
    with h5py.File(path, "w") as f:
        data = f.create_group("data")
        if env_args is not None:
            data.attrs["env_args"] = json.dumps(env_args)
        data.attrs["total"] = (
            sum(len(d["actions"]) for d in demos.values()) if total is None else total
        )
        for name, demo in demos.items():
            grp = data.create_group(name)
            grp.attrs["num_samples"] = (num_samples or {}).get(name, len(demo["actions"]))
            for key, value in demo.items():
                if isinstance(value, dict):
                    sub = grp.create_group(key)
                    for k, v in value.items():
                        sub.create_dataset(k, data=v)
                else:
                    grp.create_dataset(key, data=value)
        if mask is not None:
            grp = f.create_group("mask")
            for split, names in mask.items():
                grp.create_dataset(split, data=np.array(names, dtype="S"))
    return path


def check_demo(ep: TensorDict, demo: dict, *, next_obs: bool = False, images: bool = True):
    length = len(demo["actions"])
    assert ep.batch_size == torch.Size([length])
    np.testing.assert_array_equal(ep["action"].numpy(), demo["actions"])
    assert ep["action"].dtype == torch.float64
    assert ep["reward"].shape == (length, 1) and ep["reward"].dtype == torch.float64
    np.testing.assert_array_equal(ep["reward"][:, 0].numpy(), demo["rewards"])
    assert ep["done"].shape == (length, 1) and ep["done"].dtype == torch.bool
    np.testing.assert_array_equal(ep["done"][:, 0].numpy(), demo["dones"] != 0)
    np.testing.assert_array_equal(ep["states"].numpy(), demo["states"])
    groups = ("obs", "next_obs") if next_obs else ("obs",)
    for group in groups:
        for key, value in demo[group].items():
            if key == IMAGE and not images:
                assert (group, key) not in ep.keys(include_nested=True)
                continue
            got = ep[group, key]
            assert got.dtype == torch.from_numpy(value).dtype
            if key.endswith("quat"):  # the same rotations, w >= 0 first, then continuous
                signs = (got.numpy() * value).sum(-1, keepdims=True) / (value * value).sum(
                    -1, keepdims=True)
                np.testing.assert_allclose(np.abs(signs), 1.0, rtol=1e-6)
                np.testing.assert_array_equal(got.numpy(), np.sign(signs) * value)
                assert got[0, 3] >= 0 and ((got[1:] * got[:-1]).sum(-1) >= 0).all()
                continue
            assert torch.equal(got, torch.from_numpy(value))
    if not next_obs:
        assert "next_obs" not in ep


def assert_message(exc: pytest.ExceptionInfo, path: Path, *parts: str) -> None:
    message = str(exc.value)
    assert str(path) in message, message
    for part in parts:
        assert part in message, (part, message)


# ---------------------------------------------------------------------------------- reading


def test_read_h5py_fixture_exactly(tmp_path):
    demos = {"demo_0": demo_arrays(5, 0), "demo_1": demo_arrays(7, 1)}
    path = write_fixture(tmp_path / "lift.hdf5", demos)
    episodes, manifest = read_robomimic(path)
    assert len(episodes) == 2
    for ep, demo in zip(episodes, demos.values(), strict=True):
        check_demo(ep, demo)
    assert ep["obs", IMAGE].shape == (7, 8, 6, 3) and ep["obs", IMAGE].dtype == torch.uint8
    assert sorted(ep["obs"].keys()) == sorted((IMAGE, *LOW_DIM))


def test_demo_order_is_numeric(tmp_path):
    demos = {
        "demo_10": demo_arrays(3, 10), "demo_2": demo_arrays(4, 2), "demo_1": demo_arrays(5, 1)
    }
    path = write_fixture(tmp_path / "order.hdf5", demos)
    episodes, manifest = read_robomimic(path)
    assert manifest.episode_names == ["demo_1", "demo_2", "demo_10"]
    assert manifest.extra["demos"] == ["demo_1", "demo_2", "demo_10"]
    assert [ep.batch_size[0] for ep in episodes] == [5, 4, 3]
    for ep, name in zip(episodes, ["demo_1", "demo_2", "demo_10"], strict=True):
        check_demo(ep, demos[name])


def test_filter_key_split(tmp_path):
    demos = {f"demo_{i}": demo_arrays(3 + i, i) for i in (0, 1, 2, 10)}
    mask = {"train": [b"demo_10", b"demo_0", b"demo_2"], "valid": [b"demo_1"]}
    path = write_fixture(tmp_path / "split.hdf5", demos, mask=mask)
    train, m_train = read_robomimic(path, filter_key="train")
    valid, m_valid = read_robomimic(path, filter_key="valid")
    assert m_train.episode_names == ["demo_0", "demo_2", "demo_10"]
    assert m_valid.episode_names == ["demo_1"]
    for ep, name in zip(train, m_train.episode_names, strict=True):
        check_demo(ep, demos[name])
    check_demo(valid[0], demos["demo_1"])
    assert m_train.extra["filter_key"] == "train" and m_train.extra["filters"] == ["train", "valid"]
    assert m_train.steps == 3 + 5 + 13 and m_valid.steps == 4
    _, m_all = read_robomimic(path)
    assert m_all.episodes == 4 and m_all.extra["filter_key"] is None
    assert m_all.steps == m_all.extra["total"] == m_train.steps + m_valid.steps


def test_next_obs(tmp_path):
    demos = {"demo_0": demo_arrays(6, 0), "demo_1": demo_arrays(2, 1)}
    path = write_fixture(tmp_path / "next.hdf5", demos)
    episodes, manifest = read_robomimic(path, with_next_obs=True)
    for ep, demo in zip(episodes, demos.values(), strict=True):
        check_demo(ep, demo, next_obs=True)
    assert manifest.keys[f"next_obs/{IMAGE}"] == {"shape": [8, 6, 3], "dtype": "uint8"}


def test_load_images_false(tmp_path):
    demos = {"demo_0": demo_arrays(4, 0), "demo_1": demo_arrays(5, 1)}
    path = write_fixture(tmp_path / "noimg.hdf5", demos)
    episodes, manifest = read_robomimic(path, load_images=False, with_next_obs=True)
    for ep, demo in zip(episodes, demos.values(), strict=True):
        check_demo(ep, demo, next_obs=True, images=False)
    assert not any(IMAGE in k for k in manifest.keys)
    assert manifest.extra["skipped_obs_keys"] == [IMAGE]
    assert manifest.extra["obs_keys"] == list(LOW_DIM)
    # Explicitly requested image keys are skipped too (and listed).
    episodes, manifest = read_robomimic(path, obs_keys=[IMAGE, "object"], load_images=False)
    assert list(episodes[0]["obs"].keys()) == ["object"]
    assert manifest.extra["skipped_obs_keys"] == [IMAGE]


def test_obs_keys_subset_in_given_order(tmp_path):
    demos = {"demo_0": demo_arrays(4, 0)}
    path = write_fixture(tmp_path / "subset.hdf5", demos)
    (ep,), manifest = read_robomimic(path, obs_keys=["robot0_eef_pos", IMAGE])
    assert list(ep["obs"].keys()) == ["robot0_eef_pos", IMAGE]
    assert torch.equal(ep["obs", IMAGE], torch.from_numpy(demos["demo_0"]["obs"][IMAGE]))
    assert manifest.extra["obs_keys"] == ["robot0_eef_pos", IMAGE]
    (ep,), _ = read_robomimic(path, obs_keys="object")
    assert list(ep["obs"].keys()) == ["object"]


def test_manifest(tmp_path):
    demos = {"demo_0": demo_arrays(5, 0), "demo_1": demo_arrays(7, 1)}
    path = write_fixture(tmp_path / "manifest.hdf5", demos)
    _, manifest = read_robomimic(path)
    assert manifest.source == str(path) and manifest.format == "robomimic"
    assert manifest.episodes == 2 and manifest.steps == 12
    assert manifest.episode_lengths == [5, 7]
    assert manifest.rate_hz == 20.0
    assert manifest.extra["env_args"] == ENV_ARGS and manifest.extra["total"] == 12
    assert manifest.keys == {
        "action": {"shape": [7], "dtype": "float64"},
        "reward": {"shape": [1], "dtype": "float64"},
        "done": {"shape": [1], "dtype": "bool"},
        "states": {"shape": [5], "dtype": "float64"},
        f"obs/{IMAGE}": {"shape": [8, 6, 3], "dtype": "uint8"},
        "obs/object": {"shape": [10], "dtype": "float64"},
        "obs/robot0_eef_pos": {"shape": [3], "dtype": "float64"},
        "obs/robot0_eef_quat": {"shape": [4], "dtype": "float32"},
        "obs/robot0_gripper_qpos": {"shape": [2], "dtype": "float64"},
        "timestamp": {"shape": [], "dtype": "float64"},
    }
    json.loads(manifest.to_json())


def test_timestamps_from_control_freq(tmp_path):
    path = write_fixture(tmp_path / "t.hdf5", {"demo_0": demo_arrays(5, 0)})
    (ep,), _ = read_robomimic(path)
    assert ep["timestamp"].dtype == torch.float64
    assert ep["timestamp"].tolist() == [i / 20.0 for i in range(5)]


def test_rate_unknown_without_control_freq(tmp_path):
    demos = {"demo_0": demo_arrays(3, 0)}
    path = write_fixture(tmp_path / "a.hdf5", demos, env_args={"env_name": "X", "env_kwargs": {}})
    (ep,), manifest = read_robomimic(path)
    assert manifest.rate_hz is None
    assert "timestamp" not in ep and "timestamp" not in manifest.keys  # no rate, no clock
    path = write_fixture(tmp_path / "b.hdf5", demos, env_args=None)
    _, manifest = read_robomimic(path)
    assert manifest.rate_hz is None and manifest.extra["env_args"] is None


def test_demo_without_states(tmp_path):
    demo = demo_arrays(4, 0)
    del demo["states"]
    path = write_fixture(tmp_path / "nostates.hdf5", {"demo_0": demo})
    (ep,), manifest = read_robomimic(path)
    assert "states" not in ep and "states" not in manifest.keys


# ---------------------------------------------------------------------------------- writing


def make_episodes() -> list[TensorDict]:
    out = []
    for i, length in enumerate((4, 6, 3)):
        g = torch.Generator().manual_seed(i)
        done = torch.zeros(length, 1, dtype=torch.bool)
        done[-1] = True
        ep = TensorDict(
            {
                "action": torch.rand(length, 7, generator=g, dtype=torch.float64),
                "reward": torch.rand(length, 1, generator=g),
                "done": done,
                "states": torch.rand(length, 5, generator=g),
                "obs": {
                    IMAGE: torch.randint(0, 256, (length, 8, 6, 3), generator=g).to(torch.uint8),
                    "robot0_eef_pos": torch.rand(length, 3, generator=g),
                    "robot0_gripper_qpos": torch.rand(length, 2, generator=g, dtype=torch.float64),
                },
                "episode": torch.full((length,), i),  # not part of the format: not written
            },
            batch_size=[length],
        )
        if i == 1:  # given next_obs for one key; the other keys are shifted
            ep["next_obs", "robot0_eef_pos"] = torch.rand(length, 3, generator=g)
        out.append(ep)
    return out


@pytest.mark.parametrize("compression", [None, "gzip"])
def test_write_read_round_trip(tmp_path, compression):
    episodes = make_episodes()
    path = tmp_path / "sub" / "written.hdf5"
    write_robomimic(path, episodes, env_args=ENV_ARGS, mask={"train": [2, 0], "valid": [1]},
                    compression=compression)
    assert path.exists() and not Path(str(path) + ".tmp").exists()
    back, manifest = read_robomimic(path, with_next_obs=True)
    assert manifest.episodes == 3 and manifest.steps == 13 and manifest.rate_hz == 20.0
    assert manifest.extra["env_args"] == ENV_ARGS
    for src, got in zip(episodes, back, strict=True):
        for key in ("action", "reward", "done", "states"):
            assert got[key].dtype == src[key].dtype and torch.equal(got[key], src[key]), key
        for key, value in src["obs"].items():
            assert torch.equal(got["obs", key], value), key
            expected = src.get(("next_obs", key), None)
            if expected is None:
                expected = torch.cat([value[1:], value[-1:]])
            assert torch.equal(got["next_obs", key], expected), key
        assert "episode" not in got
    train, m_train = read_robomimic(path, filter_key="train")
    assert m_train.episode_names == ["demo_0", "demo_2"]
    assert torch.equal(train[1]["action"], episodes[2]["action"])
    with h5py.File(path, "r") as f:
        assert f["data"].attrs["total"] == 13
        assert json.loads(f["data"].attrs["env_args"]) == ENV_ARGS
        assert [f[f"data/demo_{i}"].attrs["num_samples"] for i in range(3)] == [4, 6, 3]
        assert f["data/demo_0/dones"].dtype == np.int64
        assert f["data/demo_0/dones"][()].tolist() == [0, 0, 0, 1]
        assert f["data/demo_0/rewards"].shape == (4,)
        assert sorted(f["mask/train"][()].tolist()) == [b"demo_0", b"demo_2"]
        assert f["data/demo_0/obs"][IMAGE].compression == compression


def test_write_obs_keys_and_flat_flags(tmp_path):
    ep = TensorDict(
        {"action": torch.zeros(3, 2), "reward": torch.arange(3.0), "done": torch.tensor([0, 0, 1]),
         "obs": {"a": torch.ones(3, 1), "b": torch.zeros(3, 2)}},
        batch_size=[3],
    )
    path = tmp_path / "keys.hdf5"
    write_robomimic(path, [ep], env_args={"env_name": "Toy"}, obs_keys=["b"])
    (back,), manifest = read_robomimic(path)
    assert list(back["obs"].keys()) == ["b"]
    assert back["reward"][:, 0].tolist() == [0.0, 1.0, 2.0]
    assert back["done"][:, 0].tolist() == [False, False, True]


def test_write_is_atomic(tmp_path):
    path = tmp_path / "atomic.hdf5"
    episodes = make_episodes()
    write_robomimic(path, episodes[:1], env_args=ENV_ARGS)
    before = path.read_bytes()
    bad = make_episodes()
    bad[2]["obs", "robot0_eef_pos"][1, 2] = float("nan")
    with pytest.raises(DataError) as exc:
        write_robomimic(path, bad, env_args=ENV_ARGS)
    assert_message(exc, path, "key obs/robot0_eef_pos", "episode demo_2", "step 1")
    assert path.read_bytes() == before
    assert not Path(str(path) + ".tmp").exists()


def test_write_bad_input(tmp_path):
    path = tmp_path / "bad.hdf5"
    ep = make_episodes()[0]
    with pytest.raises(DataError) as exc:
        write_robomimic(path, [ep, ep.exclude("reward")], env_args=ENV_ARGS)
    assert_message(exc, path, "key reward", "episode demo_1", "missing")
    with pytest.raises(DataError) as exc:
        write_robomimic(path, [ep], env_args=ENV_ARGS, obs_keys=["nope"])
    assert_message(exc, path, "key obs/nope", "episode demo_0")
    with pytest.raises(DataError) as exc:
        write_robomimic(path, [ep], env_args=ENV_ARGS, mask={"train": [0, 1]})
    assert_message(exc, path, "key mask/train", "index 1")
    with pytest.raises(DataError) as exc:
        write_robomimic(path, [], env_args=ENV_ARGS)
    assert_message(exc, path, "no episodes")
    with pytest.raises(TypeError):
        write_robomimic(path, [ep], env_args={"bad": object()})
    assert not path.exists() and not Path(str(path) + ".tmp").exists()


# ------------------------------------------------------------------------------- bad input


def test_missing_file(tmp_path):
    path = tmp_path / "nope.hdf5"
    with pytest.raises(DataError) as exc:
        read_robomimic(path)
    assert_message(exc, path, "no such file")


def test_missing_data_group(tmp_path):
    path = tmp_path / "nodata.hdf5"
    with h5py.File(path, "w") as f:
        f.create_group("mask")
    with pytest.raises(DataError) as exc:
        read_robomimic(path)
    assert_message(exc, path, "key data")


def test_requested_obs_key_absent(tmp_path):
    path = write_fixture(tmp_path / "absent.hdf5", {"demo_0": demo_arrays(3, 0)})
    with pytest.raises(DataError) as exc:
        read_robomimic(path, obs_keys=["robot0_eef_pos", "robot0_joint_pos"])
    assert_message(exc, path, "key obs/robot0_joint_pos", "episode demo_0", "robot0_eef_pos")


def test_obs_key_absent_from_a_later_demo(tmp_path):
    late = demo_arrays(3, 1)
    del late["obs"]["object"]
    path = write_fixture(tmp_path / "late.hdf5", {"demo_0": demo_arrays(3, 0), "demo_7": late})
    with pytest.raises(DataError) as exc:
        read_robomimic(path)
    assert_message(exc, path, "key obs/object", "episode demo_7")


def test_next_obs_key_absent(tmp_path):
    demo = demo_arrays(3, 0)
    del demo["next_obs"]["robot0_eef_pos"]
    path = write_fixture(tmp_path / "nonext.hdf5", {"demo_4": demo})
    read_robomimic(path)  # fine without next_obs
    with pytest.raises(DataError) as exc:
        read_robomimic(path, with_next_obs=True)
    assert_message(exc, path, "key next_obs/robot0_eef_pos", "episode demo_4")


def test_required_dataset_absent(tmp_path):
    demo = demo_arrays(3, 0)
    del demo["rewards"]
    path = write_fixture(tmp_path / "norewards.hdf5", {"demo_0": demo_arrays(3, 1), "demo_1": demo})
    with pytest.raises(DataError) as exc:
        read_robomimic(path)
    assert_message(exc, path, "key rewards", "episode demo_1")


def test_unknown_filter_key(tmp_path):
    mask = {"train": [b"demo_0"], "valid": [b"demo_1"]}
    demos = {"demo_0": demo_arrays(3, 0), "demo_1": demo_arrays(3, 1)}
    path = write_fixture(tmp_path / "filter.hdf5", demos, mask=mask)
    with pytest.raises(DataError) as exc:
        read_robomimic(path, filter_key="test")
    assert_message(exc, path, "key mask/test", "train", "valid")
    path = write_fixture(tmp_path / "nomask.hdf5", demos)
    with pytest.raises(DataError) as exc:
        read_robomimic(path, filter_key="train")
    assert_message(exc, path, "key mask/train", "no mask group")


def test_filter_names_missing_demo(tmp_path):
    demos = {"demo_0": demo_arrays(3, 0), "demo_1": demo_arrays(3, 1)}
    path = write_fixture(tmp_path / "f.hdf5", demos, mask={"train": [b"demo_0", b"demo_99"]})
    with pytest.raises(DataError) as exc:
        read_robomimic(path, filter_key="train")
    assert_message(exc, path, "key mask/train", "episode demo_99")


@pytest.mark.parametrize("damage", ["truncated", "garbage"])
def test_unreadable_file(tmp_path, damage):
    path = write_fixture(tmp_path / "broken.hdf5", {"demo_0": demo_arrays(20, 0)})
    raw = path.read_bytes()
    path.write_bytes(raw[: len(raw) // 2] if damage == "truncated" else os.urandom(4096))
    with pytest.raises(DataError) as exc:
        read_robomimic(path)
    assert_message(exc, path, "cannot open as HDF5")
    assert isinstance(exc.value.__cause__, OSError)


@pytest.mark.parametrize(
    ("group", "key", "value"),
    [("obs", "robot0_eef_pos", np.nan), ("", "actions", np.inf), ("next_obs", "object", -np.inf)],
)
def test_non_finite_value(tmp_path, group, key, value):
    bad = demo_arrays(6, 1)
    (bad[group] if group else bad)[key][4, 1] = value
    path = write_fixture(tmp_path / "nan.hdf5", {"demo_0": demo_arrays(6, 0), "demo_3": bad})
    with pytest.raises(DataError) as exc:
        read_robomimic(path, with_next_obs=True)
    name = f"{group}/{key}" if group else key
    assert_message(exc, path, f"key {name}", "episode demo_3", "step 4", "non-finite")


def test_mismatched_lengths(tmp_path):
    demo = demo_arrays(50, 0)
    demo["obs"]["robot0_eef_pos"] = demo["obs"]["robot0_eef_pos"][:49]
    path = write_fixture(tmp_path / "len.hdf5", {"demo_0": demo_arrays(5, 1), "demo_1": demo})
    with pytest.raises(DataError) as exc:
        read_robomimic(path)
    assert_message(exc, path, "key obs/robot0_eef_pos", "episode demo_1", "49 steps",
                   "actions has 50 steps")


def test_short_actions_are_named_not_the_rewards(tmp_path):
    demo = demo_arrays(50, 0)
    demo["actions"] = demo["actions"][:48]
    path = write_fixture(tmp_path / "len.hdf5", {"demo_0": demo})
    with pytest.raises(DataError) as exc:
        read_robomimic(path)
    assert_message(exc, path, "key actions", "episode demo_0", "step 48", "48 steps",
                   "rewards has 50 steps")


def test_empty_demo(tmp_path):
    demo = demo_arrays(3, 0)
    empty = {k: ({kk: vv[:0] for kk, vv in v.items()} if isinstance(v, dict) else v[:0])
             for k, v in demo.items()}
    path = write_fixture(tmp_path / "empty.hdf5", {"demo_0": demo, "demo_1": empty})
    with pytest.raises(DataError) as exc:
        read_robomimic(path)
    assert_message(exc, path, "key actions", "episode demo_1", "empty episode")


def test_num_samples_disagrees(tmp_path):
    demos = {"demo_0": demo_arrays(50, 0), "demo_1": demo_arrays(4, 1)}
    path = write_fixture(tmp_path / "ns.hdf5", demos, num_samples={"demo_0": 51})
    with pytest.raises(DataError) as exc:
        read_robomimic(path)
    assert_message(exc, path, "key num_samples", "episode demo_0", "51", "50 steps")


def test_total_disagrees(tmp_path):
    demos = {"demo_0": demo_arrays(5, 0), "demo_1": demo_arrays(4, 1)}
    path = write_fixture(tmp_path / "total.hdf5", demos, total=10)
    with pytest.raises(DataError) as exc:
        read_robomimic(path)
    assert_message(exc, path, "key total", "10", "9 steps")


def test_no_demos(tmp_path):
    path = write_fixture(tmp_path / "nodemos.hdf5", {})
    with pytest.raises(DataError) as exc:
        read_robomimic(path)
    assert_message(exc, path, "no demos")


def test_convert_command_writes_a_store(tmp_path, capsys):
    from rfmp_rl.data.convert import main as convert_main
    from rfmp_rl.data.store import DemonstrationStore

    rng = np.random.default_rng(0)
    episodes = []
    for n in (6, 4):
        episodes.append(TensorDict({
            "action": torch.from_numpy(rng.normal(size=(n, 7))),
            "reward": torch.zeros(n), "done": torch.arange(n) == n - 1,
            "obs": {"robot0_eef_pos": torch.from_numpy(rng.normal(size=(n, 3))),
                    "agentview_image": torch.from_numpy(
                        rng.integers(0, 256, (n, 8, 8, 3), dtype=np.uint8))},
        }, [n]))
    path = tmp_path / "demo.hdf5"
    write_robomimic(path, episodes, env_args={"env_name": "Lift", "env_kwargs":
                                              {"control_freq": 20}}, mask={"train": [1]})
    assert convert_main(["robomimic", str(path), "--filter", "train", "--out",
                         str(tmp_path / "store")]) == 0
    out = capsys.readouterr().out
    assert "1 episodes, 4 steps, 20 Hz" in out and "obs/agentview_image" in out
    store = DemonstrationStore.load(tmp_path / "store")
    assert type(store.storage._storage["obs", "agentview_image"]).__name__ == "MemoryMappedTensor"
    want, _ = read_robomimic(path, filter_key="train")
    for key in want[0].keys(include_nested=True, leaves_only=True):
        assert torch.equal(store.episode(0)[key], want[0][key]), key
