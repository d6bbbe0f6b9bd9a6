"""A model that cannot be loaded (corrupted file, metadata mismatch, missing file) gives the
documented error, and with a configured safe action the loop keeps running and holds it."""

from __future__ import annotations

import numpy as np
import pytest
from rfmp_deploy import FaultController, open_controller, run
from toy_policy import ToySpec

SAFE = np.array([0.1, -0.2], np.float32)


class FakeRobot:
    def __init__(self) -> None:
        self.sent: list[np.ndarray] = []

    def read_observation(self) -> dict:
        return {"state": np.zeros(3)}

    def send_action(self, action: np.ndarray) -> None:
        self.sent.append(np.asarray(action))


def _corrupted(make_model, tmp_path):
    path = tmp_path / "corrupted.onnx"
    path.write_bytes(make_model(ToySpec()).read_bytes()[:200])  # truncated protobuf
    return path


def _mismatch(make_model, tmp_path):
    return make_model(ToySpec(), overrides={"horizon": "7"})  # graph says T_p = 16


@pytest.mark.parametrize("make_bad", [_corrupted, _mismatch, lambda m, t: t / "missing.onnx"])
def test_unloadable_model_holds_the_safe_action_and_the_loop_keeps_running(make_model, tmp_path,
                                                                           make_bad):
    path = make_bad(make_model, tmp_path)
    with pytest.raises((ValueError, FileNotFoundError), match=path.name):
        open_controller(path)  # no safe action: the documented error, naming the file
    controller = open_controller(path, safe_action=SAFE)
    assert isinstance(controller, FaultController)
    robot = FakeRobot()
    stats = run(controller, robot, rate_hz=500.0, max_steps=5)
    assert stats.steps == 5 and len(robot.sent) == 5
    for action in robot.sent:
        np.testing.assert_array_equal(action, SAFE)
    assert controller.event_counts["model_error"] == 5
    assert path.name in controller.events[0].message
