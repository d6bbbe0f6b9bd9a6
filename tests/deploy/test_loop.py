"""`run`: fixed-rate ticks on a grid (no drift), overrun accounting, stopping."""

from __future__ import annotations

import time

import numpy as np
import pytest
from rfmp_deploy import Controller, RobotInterface, run
from toy_policy import ToySpec, make_observation

SPEC = ToySpec(horizon=4, action_steps=2)


class FakeTime:
    """A clock that only moves when someone sleeps or works; sleeps may overshoot."""

    def __init__(self, overshoot: float = 0.0) -> None:
        self.now = 100.0
        self.overshoot = overshoot

    def clock(self) -> float:
        return self.now

    def sleep(self, seconds: float) -> None:
        assert seconds > 0
        self.now += seconds + self.overshoot


class TimedRobot:
    """Records when each step started; each read costs ``work[k]`` fake seconds."""

    def __init__(self, fake: FakeTime, work) -> None:
        self.fake, self.work = fake, list(work)
        self.starts: list[float] = []
        self.sent: list[np.ndarray] = []

    def read_observation(self) -> dict:
        k = len(self.starts)
        self.starts.append(self.fake.now)
        self.fake.now += self.work[k % len(self.work)]
        return make_observation(SPEC, k)

    def send_action(self, action: np.ndarray) -> None:
        self.sent.append(action)


@pytest.fixture
def controller(make_policy):
    return Controller(make_policy(SPEC))


def test_ticks_sit_on_the_grid(controller):
    fake = FakeTime()
    robot = TimedRobot(fake, [0.03])
    stats = run(controller, robot, rate_hz=10, max_steps=5, clock=fake.clock, sleep=fake.sleep)
    np.testing.assert_allclose(robot.starts, 100 + 0.1 * np.arange(5), atol=1e-9)
    assert (stats.steps, stats.overruns, stats.missed_ticks) == (5, 0, 0)
    assert stats.mean_step_time == pytest.approx(0.03)
    assert stats.max_step_time == pytest.approx(0.03)
    assert stats.duration == pytest.approx(0.43)  # no sleep after the last step
    assert len(robot.sent) == 5 and controller.step_count == 5
    assert "5 steps" in stats.summary()


def test_sleep_overshoot_does_not_accumulate(controller):
    fake = FakeTime(overshoot=0.004)
    robot = TimedRobot(fake, [0.02, 0.05, 0.01])
    run(controller, robot, rate_hz=10, max_steps=30, clock=fake.clock, sleep=fake.sleep)
    lateness = np.asarray(robot.starts) - (100 + 0.1 * np.arange(30))
    np.testing.assert_allclose(lateness[1:], 0.004, atol=1e-9)  # constant, not growing


def test_overrun_skips_to_the_next_tick(controller):
    fake = FakeTime()
    robot = TimedRobot(fake, [0.03, 0.25, 0.03, 0.03])
    stats = run(controller, robot, rate_hz=10, max_steps=4, clock=fake.clock, sleep=fake.sleep)
    # Step 1 ends at t0 + 0.35: ticks 2 and 3 are missed, step 2 starts on tick 4.
    np.testing.assert_allclose(robot.starts, [100.0, 100.1, 100.4, 100.5], atol=1e-9)
    assert (stats.overruns, stats.missed_ticks) == (1, 2)
    assert stats.max_step_time == pytest.approx(0.25)


def test_stop_and_default_rate(controller):
    fake = FakeTime()
    robot = TimedRobot(fake, [0.01])
    stats = run(controller, robot, stop=lambda: len(robot.sent) >= 3, clock=fake.clock,
                sleep=fake.sleep)
    assert stats.steps == 3
    np.testing.assert_allclose(robot.starts, [100.0, 100.1, 100.2], atol=1e-9)  # model's 10 Hz
    with pytest.raises(ValueError, match="rate_hz must be positive"):
        run(controller, robot, rate_hz=0)


def test_real_short_run(controller):
    class Robot:
        def __init__(self):
            self.sent = []

        def read_observation(self):
            return make_observation(SPEC, len(self.sent))

        def send_action(self, action):
            self.sent.append(action)

    robot = Robot()
    assert isinstance(robot, RobotInterface)
    start = time.monotonic()
    stats = run(controller, robot, rate_hz=100, max_steps=20)
    wall = time.monotonic() - start
    assert stats.steps == 20 and len(robot.sent) == 20
    assert 0.185 <= stats.duration <= wall < 0.8  # 19 periods of 10 ms, plus the last step
    assert stats.mean_step_time < 0.01


def test_robot_interface_protocol():
    class NoSend:
        def read_observation(self):
            return {}

    assert not isinstance(NoSend(), RobotInterface)
