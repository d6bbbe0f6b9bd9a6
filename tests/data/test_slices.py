"""`SlicesToChunks`: its output key map."""

from __future__ import annotations

import pytest
import torch
from tensordict import TensorDict

from rfmp_rl.data import SlicesToChunks


def _steps(n: int = 10) -> TensorDict:
    return TensorDict({"observation": torch.arange(n * 1.0)[:, None].expand(n, 3),
                       ("obs", "gripper"): torch.arange(n * 1.0)[:, None],
                       "action": torch.arange(n * 2.0).reshape(n, 2)}, [n])


def test_key_map_renames_every_output_and_keeps_the_values():
    steps = _steps()
    plain = SlicesToChunks(4, observation_keys=["observation", "obs/gripper"])(steps)
    renamed = SlicesToChunks(
        4, observation_keys=["observation", "obs/gripper"],
        key_map={"observation": "obs_window", "obs/gripper": ("window", "gripper"),
                 "action": ("chunk", "action"), "action_is_pad": "pad"},
    )(steps)
    assert set(renamed.keys(True, True)) == {"obs_window", ("window", "gripper"),
                                             ("chunk", "action"), "pad"}
    torch.testing.assert_close(renamed["obs_window"], plain["observation"])
    torch.testing.assert_close(renamed["window", "gripper"], plain["obs", "gripper"])
    torch.testing.assert_close(renamed["chunk", "action"], plain["action"])
    assert renamed["obs_window"][1, :, 0].tolist() == [5.0, 6.0]  # [o_{r-1}, o_r]
    assert renamed["chunk", "action"][1, :, 0].tolist() == [12.0, 14.0, 16.0, 18.0]
    assert not renamed["pad"].any()


def test_key_map_refuses_keys_it_does_not_write_and_clashes():
    with pytest.raises(KeyError, match=r"renames \['pixels'\]"):
        SlicesToChunks(4, key_map={"pixels": "pixels_window"})
    with pytest.raises(ValueError, match="two entries to one key"):
        SlicesToChunks(4, key_map={"observation": "action"})
