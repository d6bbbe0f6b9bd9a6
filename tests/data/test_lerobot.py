"""`rfmp-convert lerobot`: LeRobot datasets (v2.1 and v3.0) written here -> a DemonstrationStore,
compared value by value with what was written; bad input -> DataError naming the file."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
import torch

pytest.importorskip("pyarrow", reason="LeRobot datasets need pyarrow (pip install rfmp_rl[data])")
pytest.importorskip("av", reason="LeRobot videos need PyAV (pip install rfmp_rl[data])")

import pyarrow.parquet as pq  # noqa: E402
from lerobot_fixture import make_episodes, write_lerobot  # noqa: E402

from rfmp_rl.data import DemonstrationStore  # noqa: E402
from rfmp_rl.data.convert import main  # noqa: E402
from rfmp_rl.data.episodes import DataError  # noqa: E402
from rfmp_rl.data.lerobot import lerobot_store_key, read_lerobot  # noqa: E402

FPS = 10
LENGTHS = (20, 17, 23)
VIDEO, IMAGE = "observation.images.top", "observation.image"
VERSIONS = ("v2.1", "v3.0")


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = float(np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2))
    return float("inf") if mse == 0 else 10 * np.log10(255.0**2 / mse)


@pytest.fixture(scope="module")
def written(tmp_path_factory):
    """{version: (root, source episodes)}; timestamps jittered so they are not step / fps."""
    out = {}
    for version in VERSIONS:
        episodes = make_episodes(LENGTHS, FPS, video_key=VIDEO, image_key=IMAGE, jitter=True)
        root = tmp_path_factory.mktemp(version) / "ds"
        write_lerobot(root, episodes, version=version, fps=FPS, video_keys=[VIDEO],
                      image_keys=[IMAGE])
        out[version] = (root, episodes)
    return out


@pytest.fixture(params=VERSIONS)
def dataset(request, written, tmp_path):
    """A private copy of one version's dataset (tests may damage it)."""
    root, episodes = written[request.param]
    copy = tmp_path / "ds"
    shutil.copytree(root, copy)
    return request.param, copy, episodes


def test_store_keys():
    assert lerobot_store_key("observation.state") == ("obs", "state")
    assert lerobot_store_key("observation.images.top") == ("obs", "images", "top")
    assert lerobot_store_key("action") == "action"
    assert lerobot_store_key("next.reward") == "reward"


def test_v3_fixture_packs_episodes_into_one_parquet_and_one_mp4(written):
    root, _ = written["v3.0"]
    assert len(list((root / "data").rglob("*.parquet"))) == 1
    assert len(list((root / "videos").rglob("*.mp4"))) == 1
    assert len(pq.read_table(root / "data" / "chunk-000" / "file-000.parquet")) == sum(LENGTHS)


def test_convert_matches_what_was_written(dataset, tmp_path, capsys):
    version, root, source = dataset
    assert main(["lerobot", str(root), "--out", str(tmp_path / "store")]) == 0
    store = DemonstrationStore.load(tmp_path / "store")
    assert store.episode_lengths.tolist() == list(LENGTHS)
    assert store.manifest.format == "lerobot" and store.manifest.rate_hz == FPS
    assert store.manifest.extra["codebase_version"] == version
    assert store.manifest.keys["obs/images/top"] == {"shape": [32, 32, 3], "dtype": "uint8"}
    assert store.manifest.keys["timestamp"] == {"shape": [], "dtype": "float64"}
    worst = np.inf
    for e, src in enumerate(source):
        ep = store.episode(e)
        ts = ep["timestamp"]
        assert ts.dtype == torch.float64
        # LeRobot's float32 column, exactly (the fixture's timestamps are not step / fps)
        assert np.array_equal(ts.numpy(), src["timestamp"].astype(np.float64))
        assert np.array_equal(ep["obs", "state"].numpy(), src["observation.state"])
        assert np.array_equal(ep["action"].numpy(), src["action"])
        assert np.array_equal(ep["reward"].numpy()[:, 0], src["next.reward"])
        assert np.array_equal(ep["obs", "image"].numpy(), src[IMAGE])  # PNG: lossless
        frames = ep["obs", "images", "top"].numpy()
        for i in range(len(frames)):
            value = psnr(frames[i], src[VIDEO][i])
            assert value >= 35.0, (e, i, value)
            worst = min(worst, value)
            # the nearest other frame of the episode is far off (so 35 dB picks the right one)
            others = [psnr(frames[i], src[VIDEO][j]) for j in (i - 1, i + 1)
                      if 0 <= j < len(frames)]
            assert max(others) < 30.0
    print(f"{version}: worst video frame PSNR {worst:.1f} dB")


def test_episode_subset_and_renames(dataset):
    _, root, source = dataset
    episodes, manifest = read_lerobot(root, episodes=[2, 0],
                                      keys="observation.state=obs/agent_pos")
    assert manifest.episode_lengths == [LENGTHS[2], LENGTHS[0]]
    assert sorted(manifest.keys) == ["action", "obs/agent_pos", "timestamp"]  # no video read
    assert np.array_equal(episodes[0]["obs", "agent_pos"].numpy(), source[2]["observation.state"])
    assert np.array_equal(episodes[1]["action"].numpy(), source[0]["action"])
    with pytest.raises(DataError, match="episode 7 is not in the dataset"):
        read_lerobot(root, episodes=[7])


def test_cli_episodes_and_keys(dataset, capsys):
    _, root, _ = dataset
    assert main(["lerobot", str(root), "--dry-run", "--episodes", "2,0",
                 "--keys", "observation.state=obs/agent_pos,observation.image"]) == 0
    printed = capsys.readouterr().out
    assert "2 episodes, 43 steps, 10 Hz" in printed
    assert "obs/agent_pos" in printed and "obs/image " in printed and "obs/images" not in printed
    assert main(["lerobot", str(root), "--dry-run", "--episodes", "one"]) == 2
    assert "--episodes takes comma-separated integers" in capsys.readouterr().err
    assert main(["lerobot", str(root), "--dry-run", "--keys", "observation.nope"]) == 2
    assert "no feature 'observation.nope'" in capsys.readouterr().err


def _data_file(version, root, episode=1):
    if version == "v3.0":
        return root / "data" / "chunk-000" / "file-000.parquet"
    return root / "data" / "chunk-000" / f"episode_{episode:06d}.parquet"


def _video_file(version, root, episode=1):
    if version == "v3.0":
        return root / "videos" / VIDEO / "chunk-000" / "file-000.mp4"
    return root / "videos" / "chunk-000" / VIDEO / f"episode_{episode:06d}.mp4"


def _edit_info(root, change):
    path = root / "meta" / "info.json"
    info = json.loads(path.read_text())
    change(info)
    path.write_text(json.dumps(info))


def test_missing_info_json(dataset):
    _, root, _ = dataset
    (root / "meta" / "info.json").unlink()
    with pytest.raises(DataError, match="missing meta/info.json") as err:
        read_lerobot(root)
    assert err.value.file == str(root / "meta" / "info.json")


def test_unknown_codebase_version(dataset):
    _, root, _ = dataset
    _edit_info(root, lambda info: info.update(codebase_version="v9.9"))
    with pytest.raises(DataError, match="unknown codebase_version 'v9.9'") as err:
        read_lerobot(root)
    assert err.value.file == str(root / "meta" / "info.json")
    assert err.value.key == "codebase_version"


def test_missing_parquet(dataset):
    version, root, _ = dataset
    _data_file(version, root).unlink()
    with pytest.raises(DataError, match="missing parquet file") as err:
        read_lerobot(root)
    assert err.value.file == str(_data_file(version, root))


def test_missing_mp4(dataset):
    version, root, _ = dataset
    _video_file(version, root).unlink()
    with pytest.raises(DataError, match="missing video file") as err:
        read_lerobot(root)
    assert err.value.file == str(_video_file(version, root))
    assert err.value.key == VIDEO


def test_feature_shape_mismatch(dataset):
    version, root, _ = dataset
    _edit_info(root, lambda info: info["features"]["observation.state"].update(shape=[4]))
    with pytest.raises(DataError, match=r"feature shape \[4\]") as err:
        read_lerobot(root)
    assert err.value.file == str(_data_file(version, root, 0))
    assert err.value.key == "observation.state"


def test_image_shape_mismatch(dataset):
    version, root, _ = dataset
    _edit_info(root, lambda info: info["features"][IMAGE].update(shape=[32, 30, 3]))
    with pytest.raises(DataError, match="disagrees with the feature shape") as err:
        read_lerobot(root)
    assert err.value.file == str(_data_file(version, root, 0)) and err.value.key == IMAGE


def test_timestamps_not_increasing(dataset):
    version, root, source = dataset
    path = _data_file(version, root)
    table = pq.read_table(path)
    ts = table.column("timestamp").to_numpy().copy()
    first = 0 if version == "v2.1" else LENGTHS[0]  # episode 1's rows
    ts[first + 5] = ts[first + 3]
    import pyarrow as pa

    table = table.set_column(table.column_names.index("timestamp"), "timestamp", pa.array(ts))
    pq.write_table(table, path)
    with pytest.raises(DataError, match=r"step 5: timestamps not increasing") as err:
        read_lerobot(root)
    assert err.value.file == str(path) and err.value.episode == 1


def test_no_video_frame_near_the_timestamp(dataset):
    version, root, _ = dataset
    if version == "v3.0":  # episode 1 claimed to start after the end of the shared file
        path = root / "meta" / "episodes" / "chunk-000" / "file-000.parquet"
        table = pq.read_table(path)
        column = f"videos/{VIDEO}/from_timestamp"
        values = table.column(column).to_pylist()
        values[1] = 100.0
        import pyarrow as pa

        pq.write_table(table.set_column(table.column_names.index(column), column,
                                        pa.array(values)), path)
        timestamp = "100.000000"
    else:  # episode 1's video is shorter than its table: the last steps have no frame
        from lerobot_fixture import encode_video, frame

        encode_video(_video_file(version, root), np.stack([frame(1, i) for i in range(10)]),
                     FPS)
        timestamp = ""
    with pytest.raises(DataError, match=f"no frame within half a frame period .*timestamp "
                                        f"{timestamp}") as err:
        read_lerobot(root)
    assert err.value.file == str(_video_file(version, root)) and err.value.episode == 1


def test_cli_prints_the_error_without_a_traceback(dataset, tmp_path, capsys):
    version, root, _ = dataset
    _data_file(version, root).unlink()
    assert main(["lerobot", str(root), "--out", str(tmp_path / "store")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("rfmp-convert: error: ") and str(_data_file(version, root)) in err
    assert "Traceback" not in err and not (tmp_path / "store").exists()


def test_a_lasa_policy_trains_from_a_lerobot_copy_of_its_data(tmp_path):
    """LASA demonstrations on S^2 -> LeRobot v3.0 folder -> rfmp-convert -> store -> the
    library's Trainer: a tiny SRFMP policy trains a few steps and its loss goes down."""
    from rfmp_rl.data import read_lasa
    from rfmp_rl.modules import ModelConfig, build_model
    from rfmp_rl.training import LoggerConfig, OptimConfig, TrainConfig, Trainer, setup_runtime
    from rfmp_rl.training.engine import validation_loss

    lasa, _ = read_lasa("LShape", downsample=25)  # 7 demonstrations x 40 steps
    source = [{"observation.state": ep["observation"].numpy(),
               "action": ep["action"].numpy(),
               "timestamp": ep["timestamp"].numpy().astype(np.float32)} for ep in lasa[:4]]
    write_lerobot(tmp_path / "lasa", source, version="v3.0", fps=10)
    assert main(["lerobot", str(tmp_path / "lasa"), "--out", str(tmp_path / "store")]) == 0
    store = DemonstrationStore.load(tmp_path / "store")
    assert store.episode_lengths.tolist() == [40] * 4
    for e in range(4):
        assert torch.equal(store.episode(e)["obs", "state"], lasa[e]["observation"])
        assert torch.equal(store.episode(e)["action"], lasa[e]["action"])

    horizon = 4
    rb = store.replay_buffer(horizon, concat={"observation": ["obs/state"]}, batch_size=32,
                             generator=torch.Generator().manual_seed(0))
    torch.manual_seed(0)
    model = build_model(ModelConfig("srfmp", "S2", obs_dim=3, horizon=horizon, action_steps=2,
                                    down_dims=[16, 32], time_embed_dim=32, tau_hidden_dim=32))
    model.action_normalizer.set_stats(*store.stats("action"))
    model.obs_normalizer.set_stats(*store.stats("obs/state"))
    steps = 40
    trainer = Trainer(model, rb, rb, runtime=setup_runtime("cpu"), run_dir=tmp_path / "run",
                      recipe="lerobot_lasa", optim=OptimConfig(lr=3e-3, warmup_steps=1,
                                                               ema_decay=0.5),
                      train=TrainConfig(steps=steps, batch_size=32, val_every=steps,
                                        val_batches=4, checkpoint_every=steps),
                      logger=LoggerConfig("none"), progress=False)
    before = validation_loss(trainer.val_loss_fn, rb, 4, seed=0)
    result = trainer.fit()
    after = result.history[-1]["val"]
    assert result.steps == steps and np.isfinite(after)
    print(f"validation loss {before:.3f} -> {after:.3f} in {steps} steps")
    assert after < 0.8 * before, (before, after)
    assert (tmp_path / "run" / "best.pt").is_file()


def test_timestamps_not_starting_at_zero_are_moved_to_zero(tmp_path):
    source = make_episodes([6, 5], FPS)
    for ep in source:  # a recording whose clock did not restart at each episode
        ep["timestamp"] = (ep["timestamp"] + np.float32(2.5)).astype(np.float32)
    write_lerobot(tmp_path / "ds", source, version="v3.0", fps=FPS)
    episodes, _ = read_lerobot(tmp_path / "ds")
    for ep, src in zip(episodes, source, strict=True):
        recorded = src["timestamp"].astype(np.float64)
        assert ep["timestamp"][0] == 0.0
        assert np.array_equal(ep["timestamp"].numpy(), recorded - recorded[0])


def test_16_bit_png_images_are_refused_not_wrapped(tmp_path):
    import io

    import pyarrow as pa
    from PIL import Image

    episodes = make_episodes([4], FPS, image_key=IMAGE, size=16)
    root = write_lerobot(tmp_path / "depth", episodes, version="v2.1", fps=FPS,
                         image_keys=[IMAGE])
    _edit_info(root, lambda info: info["features"][IMAGE].update(shape=[16, 16, 1]))
    path = _data_file("v2.1", root, episode=0)
    table = pq.read_table(path)
    depth = (np.arange(16 * 16).reshape(16, 16) * 200 + 300).astype(np.uint16)
    png = io.BytesIO()
    Image.fromarray(depth).save(png, format="PNG")
    column = pa.array([{"bytes": png.getvalue(), "path": None}] * 4,
                      type=table.schema.field(IMAGE).type)
    pq.write_table(table.set_column(table.column_names.index(IMAGE), IMAGE, column), path)
    with pytest.raises(DataError, match="8-bit") as err:
        read_lerobot(root)
    assert str(path) in str(err.value) and IMAGE in str(err.value)
    assert "episode 0" in str(err.value) and "step 0" in str(err.value)


def test_tasks_jsonl_row_without_task(tmp_path, capsys):
    root = write_lerobot(tmp_path / "tasks", make_episodes([3], FPS), version="v2.1", fps=FPS)
    (root / "meta" / "tasks.jsonl").write_text(json.dumps({"task_index": 0}) + "\n")
    with pytest.raises(DataError, match=r"tasks.jsonl: task row 1 \(\{\"task_index\": 0\}\)"):
        read_lerobot(root)
    assert main(["lerobot", str(root), "--dry-run"]) == 2
    assert "tasks.jsonl" in capsys.readouterr().err


@pytest.mark.parametrize("keys", [None, "observation.state=obs,action=obs/state/vel"])
def test_a_store_key_nested_under_another_is_refused(tmp_path, keys):
    episodes = make_episodes([3], FPS)
    episodes[0]["observation.state.vel"] = episodes[0]["observation.state"].copy()
    root = write_lerobot(tmp_path / "nested", episodes, version="v2.1", fps=FPS)
    with pytest.raises(DataError, match="nested under") as err:
        read_lerobot(root, keys=keys)
    outer = "'obs/state'" if keys is None else "'obs'"
    assert "'obs/state/vel'" in str(err.value) and outer in str(err.value)


def test_image_feature_names_as_a_dict(tmp_path):
    episodes = make_episodes([3], FPS, image_key=IMAGE, size=16)
    root = write_lerobot(tmp_path / "names", episodes, version="v2.1", fps=FPS,
                         image_keys=[IMAGE])
    _edit_info(root, lambda info: info["features"][IMAGE].update(
        names={"axes": ["height", "width", "channels"]}))
    out, _ = read_lerobot(root)
    np.testing.assert_array_equal(out[0]["obs", "image"].numpy(), episodes[0][IMAGE])
    # channel-first, said by the dict's axes
    _edit_info(root, lambda info: info["features"][IMAGE].update(
        shape=[3, 16, 16], names={"axes": ["channels", "height", "width"]}))
    out, _ = read_lerobot(root)
    np.testing.assert_array_equal(out[0]["obs", "image"].numpy(), episodes[0][IMAGE])


def test_cli_turns_reader_key_errors_into_one_line(tmp_path, monkeypatch, capsys):
    import rfmp_rl.data.lerobot as lerobot

    def broken(*args, **kwargs):
        raise KeyError("features")

    monkeypatch.setattr(lerobot, "read_lerobot", broken)
    assert main(["lerobot", str(tmp_path), "--dry-run"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("rfmp-convert: error:") and "features" in err and len(
        err.strip().splitlines()) == 1


def test_duplicate_episode_indices_are_refused(tmp_path, capsys):
    root = write_lerobot(tmp_path / "d", make_episodes([3, 4], FPS), version="v2.1", fps=FPS)
    with pytest.raises(DataError, match="episode 1 is asked for twice"):
        read_lerobot(root, episodes=[1, 0, 1])
    assert main(["lerobot", str(root), "--episodes", "1,1", "--dry-run"]) == 2
    assert "--episodes" in capsys.readouterr().err


@pytest.mark.parametrize("version", VERSIONS)
def test_non_integer_episode_length_names_file_and_field(version, tmp_path):
    root = write_lerobot(tmp_path / version, make_episodes([3, 4], FPS), version=version,
                         fps=FPS)
    if version == "v2.1":
        path = root / "meta" / "episodes.jsonl"
        rows = [json.loads(line) for line in path.read_text().splitlines()]
        rows[1]["length"] = "four"
        path.write_text("".join(json.dumps(r) + "\n" for r in rows))
    else:
        import pyarrow as pa

        path = root / "meta" / "episodes" / "chunk-000" / "file-000.parquet"
        table = pq.read_table(path)
        i = table.column_names.index("length")
        table = table.set_column(i, "length", pa.array(["3", "four"]))
        pq.write_table(table, path)
    with pytest.raises(DataError, match="length") as err:
        read_lerobot(root)
    assert str(path) in str(err.value)
    assert "'four'" in str(err.value)


def test_only_the_selected_columns_are_read(tmp_path, monkeypatch):
    import rfmp_rl.data.lerobot as lerobot

    episodes = make_episodes([3], FPS, image_key=IMAGE, size=8)
    root = write_lerobot(tmp_path / "d", episodes, version="v2.1", fps=FPS, image_keys=[IMAGE])
    asked = []
    real = lerobot._read_table

    def spy(path, columns=None):
        asked.append((path.name, columns))
        return real(path, columns)

    monkeypatch.setattr(lerobot, "_read_table", spy)
    (ep,), _ = read_lerobot(root, keys="observation.state")
    data = [columns for name, columns in asked if name.startswith("episode_")]
    assert data and IMAGE not in data[0] and "observation.state" in data[0]
    np.testing.assert_array_equal(ep["obs", "state"].numpy(), episodes[0]["observation.state"])
