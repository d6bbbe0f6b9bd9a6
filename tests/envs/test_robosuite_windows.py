"""robosuite with T_o > 2: the state and camera windows ``[o^{s-T_o}, o^{s-1}]`` and the gap."""

from __future__ import annotations

import pytest
import torch

pytest.importorskip("robosuite")

from rfmp_rl import keys  # noqa: E402
from rfmp_rl.envs.robosuite import make_robosuite_env  # noqa: E402


@pytest.mark.slow
def test_robosuite_emits_oldest_and_latest_of_the_last_t_o_with_cameras():
    env = make_robosuite_env("Lift", [1], cameras=True, seeds=[0], obs_horizon=3)
    try:
        torch.manual_seed(0)
        out = env.rollout(4, break_when_any_done=False)
    finally:
        env.close()
    assert not torch.equal(out[keys.OBSERVATION][:, 0], out[keys.OBSERVATION][:, 3])  # it moved
    assert (out[keys.OBS_GAP] == 3).all() and out[keys.OBS_GAP].shape == (1, 4)
    for window, step in ((keys.OBS_WINDOW, keys.OBSERVATION),
                         ("agentview_image_window", "agentview_image"),
                         ("robot0_eye_in_hand_image_window", "robot0_eye_in_hand_image")):
        assert out[window].shape[:3] == (1, 4, 2)
        for t in range(4):
            torch.testing.assert_close(out[window][:, t, 0], out[step][:, max(t - 2, 0)])
            torch.testing.assert_close(out[window][:, t, 1], out[step][:, t])
