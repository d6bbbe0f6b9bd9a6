"""Quaternion signs: each episode's first sample at w >= 0, then continuity; raw signs on request;
the readers that know quaternion fields (robomimic ``obs/*quat``) and the ``--quaternions``
spec for those that cannot."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from tensordict import TensorDict

from rfmp_rl.data.convert import main as convert_main
from rfmp_rl.data.episodes import DataError, Manifest
from rfmp_rl.data.quaternions import (
    QuaternionField,
    canonicalize_episode_quaternions,
    parse_quaternion_fields,
)


def about_z(angles: torch.Tensor) -> torch.Tensor:
    """xyzw quaternions of rotations about z, w = cos(a/2) > 0 for |a| < pi."""
    half = angles / 2
    zeros = torch.zeros_like(half)
    return torch.stack([zeros, zeros, torch.sin(half), torch.cos(half)], dim=-1)


def episodes_with_a_negated_one() -> tuple[list[TensorDict], torch.Tensor]:
    """Three episodes of pose actions (xyz, quaternion xyzw, gripper); the second is recorded
    entirely as -q, the third switches sign at step 3."""
    q = about_z(torch.linspace(0.1, 1.0, 6, dtype=torch.float64))
    eps = []
    for k in range(3):
        qk = q.clone()
        if k == 1:
            qk = -qk
        if k == 2:
            qk[3:] = -qk[3:]
        action = torch.cat([torch.full((6, 3), float(k)), qk, torch.ones(6, 1)], dim=-1)
        eps.append(TensorDict({"action": action.float(), "obs": {"q": qk.float()}}, [6]))
    return eps, q.float()


def test_an_episode_recorded_as_minus_q_becomes_plus_q_and_others_are_untouched():
    eps, q = episodes_with_a_negated_one()
    before = [ep.clone() for ep in eps]
    manifest = Manifest(source="d", format="toy", episode_names=["a", "b", "c"])
    canonicalize_episode_quaternions(eps, manifest, parse_quaternion_fields("action[3:7]"))
    for ep in eps:
        torch.testing.assert_close(ep["action"][:, 3:7], q)
    torch.testing.assert_close(eps[0]["action"], before[0]["action"])  # already canonical
    for ep, old in zip(eps, before, strict=True):  # other columns and fields unchanged
        torch.testing.assert_close(ep["action"][:, :3], old["action"][:, :3])
        torch.testing.assert_close(ep["action"][:, 7:], old["action"][:, 7:])
        torch.testing.assert_close(ep["obs", "q"], old["obs", "q"])
    assert manifest.extra["quaternions"] == {"raw_signs": False, "fields": [
        {"key": "action", "columns": [3, 7], "order": "xyzw", "w_index": 3,
         "first_flipped": 1, "continuity_flipped": 1}]}


def test_continuity_within_an_episode_starting_with_negative_w():
    q = about_z(torch.linspace(0.0, 3.0, 20, dtype=torch.float64))
    recorded = q * torch.where(torch.arange(20) % 3 == 0, -1.0, 1.0).double()[:, None]
    recorded[0] = -q[0]  # first sample w < 0
    ep = TensorDict({"q": recorded}, [20])
    manifest = Manifest(source="d", format="toy", episode_names=["e"])
    canonicalize_episode_quaternions([ep], manifest, parse_quaternion_fields("q"))
    out = ep["q"]
    assert out[0, 3] >= 0
    assert ((out[1:] * out[:-1]).sum(-1) > 0).all()
    torch.testing.assert_close(out, q)


def test_wxyz_order_puts_w_first():
    q = about_z(torch.tensor([0.3, 0.4]))[:, [3, 0, 1, 2]]  # wxyz
    ep = TensorDict({"obs": {"q": -q}}, [2])
    canonicalize_episode_quaternions([ep], Manifest(source="d", format="toy"),
                                     parse_quaternion_fields("obs/q:wxyz"))
    torch.testing.assert_close(ep["obs", "q"], q)


def test_raw_signs_keep_the_recording_and_the_manifest_says_so():
    eps, _ = episodes_with_a_negated_one()
    before = [ep.clone() for ep in eps]
    manifest = Manifest(source="d", format="toy")
    canonicalize_episode_quaternions(eps, manifest, [QuaternionField("action", (3, 7))], raw=True)
    for ep, old in zip(eps, before, strict=True):
        torch.testing.assert_close(ep["action"], old["action"])
    record = manifest.extra["quaternions"]
    assert record["raw_signs"] is True and record["fields"][0]["first_flipped"] == 1


@pytest.mark.parametrize(("spec", "message"), [
    ("action[3:6]", "action[3:6]:xyzw: a quaternion spans 4 columns"),
    ("action[3:7]:zyxw", "quaternion field 'action[3:7]:zyxw' is not KEY"),
    ("action[3-7]", "quaternion field 'action[3-7]' is not KEY"),
])
def test_bad_field_spec_is_a_data_error_naming_it(spec, message):
    with pytest.raises(DataError, match=message.replace("[", r"\[").replace("]", r"\]")):
        parse_quaternion_fields(spec)


def test_field_errors_name_the_field_and_list_keys_in_a_b_form():
    eps, _ = episodes_with_a_negated_one()
    manifest = Manifest(source="d.zarr", format="toy", episode_names=["e0", "e1", "e2"])
    with pytest.raises(DataError, match=r"key obs/p:xyzw, episode e0: quaternion field not in "
                       r"the episode; its keys: action, obs/q"):
        canonicalize_episode_quaternions(eps, manifest, parse_quaternion_fields("obs/p"))
    with pytest.raises(DataError, match=r"columns \[6:10\] are outside"):
        canonicalize_episode_quaternions(eps, manifest, parse_quaternion_fields("action[6:10]"))
    with pytest.raises(DataError, match=r"needs 4 values per step, the field has per-step shape "
                       r"\[8\]"):
        canonicalize_episode_quaternions(eps, manifest, parse_quaternion_fields("action"))


def robomimic_file(tmp_path, negate_second: bool = True):
    from rfmp_rl.data.robomimic import write_robomimic

    q = about_z(torch.linspace(0.2, 0.8, 5))
    eps = []
    for k in range(3):
        sign = -1.0 if (negate_second and k == 1) else 1.0
        action = torch.cat([torch.zeros(5, 3), sign * q, torch.zeros(5, 1)], -1)
        eps.append(TensorDict({
            "action": action, "reward": torch.zeros(5, 1), "done": torch.zeros(5, 1, dtype=bool),
            "obs": {"robot0_eef_quat": sign * q, "robot0_eef_pos": torch.ones(5, 3)},
        }, [5]))
    path = tmp_path / "lift.hdf5"
    write_robomimic(path, eps, env_args={"env_name": "Lift", "env_type": 1, "env_kwargs": {}})
    return path, q


def test_robomimic_eef_quat_is_canonicalised_and_named_actions_on_request(tmp_path):
    pytest.importorskip("h5py")
    from rfmp_rl.data.robomimic import read_robomimic

    path, q = robomimic_file(tmp_path)
    eps, manifest = read_robomimic(path)
    for ep in eps:
        torch.testing.assert_close(ep["obs", "robot0_eef_quat"], q)
    torch.testing.assert_close(eps[1]["action"][:, 3:7], -q)  # actions: not known to be poses
    fields = manifest.extra["quaternions"]["fields"]
    assert [(f["key"], f["first_flipped"]) for f in fields] == [("obs/robot0_eef_quat", 1)]
    eps, manifest = read_robomimic(path, quaternions="action[3:7]")
    torch.testing.assert_close(eps[1]["action"][:, 3:7], q)
    assert [f["key"] for f in manifest.extra["quaternions"]["fields"]] == [
        "obs/robot0_eef_quat", "action"]
    eps, manifest = read_robomimic(path, quaternions="action[3:7]", raw_quaternion_signs=True)
    torch.testing.assert_close(eps[1]["obs", "robot0_eef_quat"], -q)
    torch.testing.assert_close(eps[1]["action"][:, 3:7], -q)


def test_convert_command_quaternions_and_raw_signs(tmp_path, capsys):
    pytest.importorskip("zarr")
    from rfmp_rl.data.dp_zarr import write_dp_zarr
    from rfmp_rl.data.store import DemonstrationStore

    q = about_z(torch.linspace(0.2, 0.8, 4)).numpy()
    action = np.concatenate([np.concatenate([np.zeros((4, 2)), s * q], 1) for s in (1, -1)])
    write_dp_zarr(tmp_path / "d.zarr", {"action": action.astype(np.float32)}, [4, 8])
    out = tmp_path / "store"
    assert convert_main(["dp_zarr", str(tmp_path / "d.zarr"), "--out", str(out),
                         "--quaternions", "action[2:6]"]) == 0
    store = DemonstrationStore.load(out)
    assert store.manifest.extra["quaternions"]["fields"][0]["first_flipped"] == 1
    assert "quaternions action[2:6]:xyzw" in capsys.readouterr().out
    assert convert_main(["dp_zarr", str(tmp_path / "d.zarr"), "--dry-run",
                         "--quaternions", "action[2:6]", "--raw-quaternion-signs"]) == 0
    assert "raw signs kept" in capsys.readouterr().out
    assert convert_main(["dp_zarr", str(tmp_path / "d.zarr"), "--dry-run",
                         "--quaternions", "action[2:5]"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("rfmp-convert: error: key action[2:5]:xyzw: a quaternion spans 4")
    assert "Traceback" not in err
    assert convert_main(["lasa", "LShape", "--dry-run", "--quaternions", "action"]) == 2
    assert "lasa: --quaternions is not read" in capsys.readouterr().err
