"""rfmp_rl/data/README.md, "Bad input": every case listed there is run through `rfmp-convert`
and must exit 2 with ``rfmp-convert: error: <the listed message>`` and no traceback; every case
run here is listed there (so the catalogue cannot drift from the code)."""

from __future__ import annotations

import re
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import yaml

pytest.importorskip("h5py")
pytest.importorskip("zarr")
pytest.importorskip("rosbags")

from lerobot_fixture import make_episodes, write_lerobot  # noqa: E402
from test_robomimic import demo_arrays, write_fixture  # noqa: E402
from test_rosbag import SMALL, Bag, bad_bags, gap_bag, pose_gripper_bag, small_bag  # noqa: E402

from rfmp_rl.data.convert import main  # noqa: E402
from rfmp_rl.data.dp_zarr import write_dp_zarr  # noqa: E402

CATALOGUE = Path(__file__).resolve().parents[2] / "rfmp_rl" / "data" / "README.md"


def _zarr(tmp: Path) -> str:
    write_dp_zarr(tmp / "d.zarr", {"action": np.zeros((6, 2), np.float32)}, [3, 6])
    return str(tmp / "d.zarr")


def _config(tmp: Path, config: dict) -> str:
    (tmp / "topics.yaml").write_text(yaml.safe_dump(config))
    return str(tmp / "topics.yaml")


def _robomimic(tmp: Path, **change) -> str:
    demo = demo_arrays(6, 0)
    for key, value in change.items():
        demo[key] = value(demo[key])
    return str(write_fixture(tmp / "demo.hdf5", {"demo_0": demo}))


def _not_hdf5(tmp: Path) -> str:
    (tmp / "demo.hdf5").write_bytes(b"not an HDF5 file")
    return str(tmp / "demo.hdf5")


def _nan_actions(actions: np.ndarray) -> np.ndarray:
    actions = actions.copy()
    actions[2, 1] = np.nan
    return actions


def _lerobot(tmp: Path) -> str:
    write_lerobot(tmp / "ds", make_episodes([4, 3], 10.0), version="v3.0", fps=10.0)
    return str(tmp / "ds")


def _not_a_store(tmp: Path) -> str:
    (tmp / "bags").mkdir()
    (tmp / "bags" / "run1.bag").write_bytes(b"recording")
    return str(tmp / "bags")


def _a_file(tmp: Path) -> str:
    (tmp / "data.hdf5").write_bytes(b"precious")
    return str(tmp / "data.hdf5")


def _corrupt_bag(tmp: Path) -> str:
    folder, (_, corrupt, _) = bad_bags(tmp)
    return str(corrupt)


def _all_bad(tmp: Path) -> str:
    folder, (good, _, _) = bad_bags(tmp)
    good.unlink()
    return str(folder)


def _pose_bag(tmp: Path) -> str:
    return str(pose_gripper_bag("mcap").write(tmp / "teleop"))


def _missing_topic_bag(tmp: Path) -> str:
    bag = Bag("mcap")
    bag.scalar("/other", 0, 1.0)
    return str(bag.write(tmp / "b"))


LASA = ["lasa", "LShape"]
OUT = ["--dry-run"]
#: case -> argv builder (tmp folder -> the rfmp-convert arguments)
CASES: dict[str, Callable[[Path], list[str]]] = {
    # rfmp-convert
    "--out names a file": lambda t: [*LASA, "--out", _a_file(t)],
    "--out names a folder that is not a store": lambda t: [*LASA, "--out", _not_a_store(t)],
    "no --out": lambda t: LASA,
    "--skip-bad outside ros": lambda t: [*LASA, *OUT, "--skip-bad"],
    "--episodes outside lerobot/minari": lambda t: [*LASA, *OUT, "--episodes", "0"],
    "--episodes not integers": lambda t: ["lerobot", str(t), *OUT, "--episodes", "a,b"],
    "--rate on a source that records its rate": lambda t: [*LASA, *OUT, "--rate", "5"],
    "--keys on minari": lambda t: ["minari", "x", *OUT, "--keys", "a"],
    # quaternions
    "--quaternions: not 4 columns": lambda t: ["dp_zarr", _zarr(t), *OUT,
                                               "--quaternions", "action[0:3]"],
    "--quaternions: bad syntax": lambda t: ["dp_zarr", _zarr(t), *OUT,
                                            "--quaternions", "action(0:4)"],
    "--quaternions: unknown order": lambda t: ["dp_zarr", _zarr(t), *OUT,
                                               "--quaternions", "action:zyxw"],
    "--quaternions: no such key": lambda t: ["dp_zarr", _zarr(t), *OUT,
                                             "--quaternions", "obs/quat"],
    "--quaternions: field not 4 wide": lambda t: ["dp_zarr", _zarr(t), *OUT,
                                                  "--quaternions", "action"],
    "--quaternions: columns outside": lambda t: ["dp_zarr", _zarr(t), *OUT,
                                                 "--quaternions", "action[1:5]"],
    "--quaternions on ros": lambda t: ["ros", str(t), *OUT, "--config", "c.yaml",
                                       "--quaternions", "action[3:7]"],
    "--quaternions on lasa": lambda t: [*LASA, *OUT, "--quaternions", "action"],
    # dp_zarr
    "dp_zarr: missing store": lambda t: ["dp_zarr", str(t / "none.zarr"), *OUT],
    "dp_zarr: missing array": lambda t: ["dp_zarr", _zarr(t), *OUT, "--keys", "state"],
    # robomimic
    "robomimic: no such file": lambda t: ["robomimic", str(t / "none.hdf5"), *OUT],
    "robomimic: not HDF5": lambda t: ["robomimic", _not_hdf5(t), *OUT],
    "robomimic: unknown filter": lambda t: ["robomimic", _robomimic(t), *OUT,
                                            "--filter", "train"],
    "robomimic: missing obs key": lambda t: ["robomimic", _robomimic(t), *OUT,
                                             "--keys", "eef_pos"],
    "robomimic: short actions": lambda t: ["robomimic",
                                           _robomimic(t, actions=lambda a: a[:5]), *OUT],
    "robomimic: NaN": lambda t: ["robomimic", _robomimic(t, actions=_nan_actions), *OUT],
    # lerobot
    "lerobot: no dataset folder": lambda t: ["lerobot", str(t / "none"), *OUT],
    "lerobot: unknown feature": lambda t: ["lerobot", _lerobot(t), *OUT, "--keys", "state"],
    "lerobot: unknown episode": lambda t: ["lerobot", _lerobot(t), *OUT, "--episodes", "7"],
    # minari
    "minari: not on disk": lambda t: ["minari", str(t / "none"), *OUT],
    # ros
    "ros: no --config": lambda t: ["ros", str(t), *OUT],
    "ros: unknown config field": lambda t: ["ros", str(t), *OUT, "--config",
                                            _config(t, {**SMALL, "rate": 10})],
    "ros: no such bag": lambda t: ["ros", str(t / "none.bag"), *OUT, "--config",
                                   _config(t, SMALL)],
    "ros: topic not in the bag": lambda t: ["ros", _missing_topic_bag(t), *OUT, "--config",
                                            _config(t, SMALL)],
    "ros: corrupt bag": lambda t: ["ros", _corrupt_bag(t), *OUT, "--config", _config(t, SMALL)],
    "ros: no readable bag (--skip-bad)": lambda t: ["ros", _all_bad(t), *OUT, "--skip-bad",
                                                    "--config", _config(t, SMALL)],
    "ros: a gap": lambda t: ["ros", str(gap_bag("mcap", camera_until=2.0).write(t / "cam")),
                             *OUT, "--config", _config(t, {"rate_hz": 10, "topics": {
                                 "/joint_states": "joints", "/camera/image": "image"}})],
    "ros: vector layout vs manifold": lambda t: [
        "ros", _pose_bag(t), *OUT, "--config",
        _config(t, {"rate_hz": 10, "action": ["/cmd_pose", "/gripper_cmd"],
                    "action_manifold": "R3 x S3"})],
    "ros: no rate": lambda t: ["ros", str(small_bag().write(t / "b")), *OUT, "--config",
                               _config(t, {"topics": {"/joint_states": "joints"}})],
    # lasa
    "lasa: unknown shape": lambda t: ["lasa", "Circle", *OUT],
}


def catalogue() -> dict[str, str]:
    """case -> message, from the tables of the catalogue."""
    rows = {}
    for line in CATALOGUE.read_text().split("## Bad input", 1)[1].splitlines():
        match = re.match(r"^\| `?(.+?)`? \| `(.+)` \|$", line)
        if match:
            rows[match.group(1)] = match.group(2)
    return rows


def test_every_case_is_catalogued_and_every_catalogued_case_is_run():
    assert sorted(catalogue()) == sorted(CASES)


@pytest.mark.parametrize("case", list(CASES))
def test_bad_input_ends_in_the_catalogued_message(case, tmp_path, capsys):
    argv = CASES[case](tmp_path)
    capsys.readouterr()
    try:
        code = main(argv)
    except SystemExit as exit_:  # argparse's own errors
        code = exit_.code
    err = capsys.readouterr().err
    assert code == 2, err
    assert "Traceback" not in err
    last = err.strip().splitlines()[-1]
    assert last.startswith("rfmp-convert: error: "), err
    message = last.removeprefix("rfmp-convert: error: ").replace(str(tmp_path), "<tmp>")
    expected = catalogue()[case]
    pattern = ".*".join(re.escape(part) for part in expected.split("..."))
    assert re.fullmatch(pattern, message), f"\n  code:      {message}\n  catalogue: {expected}"


def test_help_points_to_the_topic_config_the_worked_path_and_this_catalogue(capsys):
    with pytest.raises(SystemExit) as exit_:
        main(["--help"])
    assert exit_.value.code == 0
    text = " ".join(capsys.readouterr().out.split())
    readme = CATALOGUE.read_text()  # rfmp_rl/data/README.md holds both sections
    for section in ("ROS bags: the topic config", "From a bag to a controller"):
        assert f'section "{section}"' in text
        assert re.search(rf"^#+ {re.escape(section)}$", readme, re.MULTILINE), section
    assert "rfmp_rl/data/README.md" in text and CATALOGUE.is_file()
    assert "--quaternions KEY[a:b][:ORDER],..." in text and "--raw-quaternion-signs" in text
