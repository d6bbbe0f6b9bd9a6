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


def test_the_fallback_runs_under_run_without_a_rate(tmp_path):
    controller = open_controller(tmp_path / "missing.onnx", safe_action=SAFE)
    ticks = iter(np.arange(0.0, 10.0, 0.01))
    robot = FakeRobot()
    stats = run(controller, robot, max_steps=3, clock=lambda: float(next(ticks)),
                sleep=lambda s: None)  # no rate: the fallback's own (10 Hz)
    assert stats.steps == 3 and controller.control_rate_hz == 10.0
    assert open_controller(tmp_path / "missing.onnx", safe_action=SAFE,
                           control_rate_hz=50.0).control_rate_hz == 50.0


SPHERE = ToySpec(manifold={"type": "sphere", "n": 2})


@pytest.mark.parametrize("safe,message", [
    (np.zeros(3), "safe_action is off the manifold: its S2 component at 0:3 has norm 0"),
    (np.array([0.0, 0.0, 2.0]), "off the manifold.*norm 2"),
    (np.array([0.0, 0.0, 0.0, 1.0]), r"safe_action has shape \(4,\), expected \(3,\)"),
    (np.array([np.nan, 0.0, 1.0]), r"safe_action has non-finite coordinate\(s\) \[0\]"),
])
def test_a_bad_safe_action_for_a_good_model_is_the_callers_error(make_model, safe, message):
    path = make_model(SPHERE)
    with pytest.raises(ValueError, match=message):
        open_controller(path, safe_action=safe)  # never a FaultController blaming the model


def test_a_safe_action_outside_the_limits_is_refused(make_model):
    path = make_model(ToySpec(manifold={"type": "euclidean", "dim": 2}, low=[-1.0, -1.0],
                              high=[1.0, 1.0]))
    with pytest.raises(ValueError, match="safe_action is outside the action limits"):
        open_controller(path, safe_action=np.array([0.0, 3.0]))
    assert open_controller(path, safe_action=np.array([0.0, 0.5])).meta is not None


# ----- implausible metadata and a failing send_action -------------------------------------------
@pytest.mark.parametrize("overrides,key,message", [
    ({"control_rate_hz": "1e-9"}, "control_rate_hz", "implausible"),
    ({"control_rate_hz": "50000"}, "control_rate_hz", "implausible"),
    ({"horizon": "100000", "action_steps": "2"}, "horizon", "implausible"),
])
def test_implausible_metadata_is_refused_at_load(make_model, overrides, key, message):
    from rfmp_deploy import Policy

    with pytest.raises(ValueError, match=f"{key}.*{message}"):
        Policy(make_model(ToySpec(), overrides=overrides))


def test_limits_on_a_sphere_component_are_refused_at_load(make_model):
    from rfmp_deploy import Policy

    low = [-1.0] * 3 + [-0.1] * 4 + [0.0]
    high = [1.0] * 3 + [0.1] * 4 + [0.08]
    with pytest.raises(ValueError, match=r"action_low.*S3 component at 3:7.*not enforced"):
        Policy(make_model(ToySpec(low=low, high=high)))


class FlakyRobot(FakeRobot):
    def __init__(self, fail_at) -> None:
        super().__init__()
        self.fail_at, self.calls = set(fail_at), 0

    def send_action(self, action: np.ndarray) -> None:
        self.calls += 1
        if self.calls in self.fail_at:
            raise ConnectionError(f"driver dropped command {self.calls}")
        super().send_action(action)


def test_send_action_failures_are_counted_and_the_loop_holds_then_stops(tmp_path):
    from rfmp_deploy import SendActionError

    controller = open_controller(tmp_path / "missing.onnx", safe_action=SAFE)
    robot = FlakyRobot(fail_at={2, 4})  # isolated failures: the loop goes on
    stats = run(controller, robot, rate_hz=1000.0, max_steps=6)
    assert stats.steps == 6 and stats.send_errors == 2 and len(robot.sent) == 4
    assert "driver dropped command 4" in stats.summary()
    robot = FlakyRobot(fail_at={3, 4, 5})  # three in a row: stop
    with pytest.raises(SendActionError, match="failed 3 times in a row.*command 5"):
        run(controller, robot, rate_hz=1000.0, max_steps=10, max_send_errors=3)
