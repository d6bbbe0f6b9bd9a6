"""The fixed-rate control loop and the interface a robot implements to be driven by it."""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

import numpy as np

from rfmp_deploy.controller import Controller

logger = logging.getLogger("rfmp_deploy")

__all__ = ["RobotInterface", "RunStats", "SendActionError", "run"]


@runtime_checkable
class RobotInterface(Protocol):
    """What the control loop needs from a robot. Implement these two methods for your arm.

    ``read_observation`` returns the latest readings, without waiting for new ones longer than
    necessary: a dict with one entry per low-dimensional field in the model's
    ``observation_keys`` (``(dim,)`` numbers in the units and frames used in training) and one
    entry per camera name (``H x W x 3`` uint8 RGB, any size: the controller resizes). Print
    ``python -m rfmp_deploy --model policy.onnx --check`` for the list. If a sensor is
    unavailable, leave its key out (or pass NaN) rather than raising: the controller then holds
    and records a ``rejected`` event, and the loop keeps its rate. Exceptions from
    ``read_observation`` propagate and end the loop.

    ``send_action`` receives one ``(D,)`` float32 action in the layout of the model's
    ``action_manifold`` (e.g. position xyz, quaternion xyzw, gripper) and must return quickly
    (queue it to the driver; do not wait for the motion to finish). It is already clipped to
    the training limits; apply your robot's own limits too (workspace, velocity, force). If it
    raises, `run` counts and logs the failure and goes on (the robot holds its last command);
    ``max_send_errors`` failures in a row stop the loop with `SendActionError`.

    Example:
        >>> class MyArm:
        ...     def read_observation(self) -> dict:
        ...         return {"eef_pos": np.zeros(3), "eef_quat": np.array([0, 0, 0, 1.0]),
        ...                 "gripper": np.zeros(1), "wrist": np.zeros((480, 640, 3), np.uint8)}
        ...     def send_action(self, action: np.ndarray) -> None:
        ...         pass  # e.g. publish a pose target
        >>> isinstance(MyArm(), RobotInterface)
        True
    """

    def read_observation(self) -> dict[str, Any]: ...

    def send_action(self, action: np.ndarray) -> None: ...


@dataclass
class RunStats:
    """What `run` measured.

    Attributes:
        steps: control steps completed.
        overruns: steps whose work (read, step, send) took longer than the period.
        missed_ticks: control ticks skipped because a step ended after the next tick: an
            overrun, or a step that started late because the process woke late from its sleep
            (the loop does not burst to catch up; it waits for the next tick on the original
            grid).
        mean_step_time: mean seconds spent in read + step + send.
        max_step_time: the longest such time.
        duration: seconds from the first tick to the end.

    Example:
        >>> print(RunStats(steps=100, overruns=1, missed_ticks=2, mean_step_time=0.0021,
        ...                max_step_time=0.25, duration=10.1).summary())
        100 steps in 10.10 s; step time mean 2.10 ms, max 250.00 ms;
        1 overrun(s), 2 missed tick(s)
    """

    steps: int = 0
    overruns: int = 0
    missed_ticks: int = 0
    mean_step_time: float = 0.0
    max_step_time: float = 0.0
    duration: float = 0.0
    send_errors: int = 0
    last_send_error: str | None = None

    def summary(self) -> str:
        text = (f"{self.steps} steps in {self.duration:.2f} s; step time mean "
                f"{self.mean_step_time * 1e3:.2f} ms, max {self.max_step_time * 1e3:.2f} ms; "
                f"{self.overruns} overrun(s), {self.missed_ticks} missed tick(s)")
        if self.send_errors:
            text += f"; {self.send_errors} failed send_action call(s): {self.last_send_error}"
        return text


class SendActionError(RuntimeError):
    """``send_action`` failed ``max_send_errors`` times in a row: the loop stopped."""


def run(
    controller: Controller,
    robot: RobotInterface,
    rate_hz: float | None = None,
    max_steps: int | None = None,
    stop: Callable[[], bool] = lambda: False,
    clock: Callable[[], float] = time.monotonic,
    sleep: Callable[[float], None] = time.sleep,
    max_send_errors: int = 5,
) -> RunStats:
    """Drive ``robot`` with ``controller`` at a fixed rate until ``stop()`` or ``max_steps``.

    Each tick: ``robot.read_observation()``, ``controller.step(...)``,
    ``robot.send_action(...)``, then sleep until the next tick. Ticks sit on a fixed grid
    ``t_0 + k / rate_hz`` of the monotonic clock, so sleeping imprecision never accumulates
    into drift. A tick whose work overruns the period is counted; the loop then starts the next
    step at the next grid tick instead of bursting to catch up.

    Args:
        controller: the controller (call ``controller.reset()`` first for a new episode).
        robot: anything with ``read_observation`` and ``send_action`` (`RobotInterface`).
        rate_hz: control rate; ``None`` uses the model's ``control_rate_hz``.
        max_steps: stop after this many steps (``None``: no limit).
        stop: checked before every step; return ``True`` to end the loop (e.g. an e-stop flag
            or ``lambda: robot.done``).
        clock: monotonic clock in seconds.
        sleep: sleeps for the given seconds.
        max_send_errors: an exception from ``robot.send_action`` is counted and logged and the
            loop goes on (the robot keeps its last command: it holds); this many failures in a
            row stop the loop with `SendActionError`.

    Returns:
        the loop's `RunStats`.

    Raises:
        SendActionError: ``send_action`` failed ``max_send_errors`` times in a row.
    """
    if rate_hz is None:  # the model's rate; a FaultController (no model) carries its own
        meta = getattr(controller, "meta", None)
        rate_hz = meta.control_rate_hz if meta is not None else controller.control_rate_hz
    rate = float(rate_hz)
    if not rate > 0:
        raise ValueError(f"rate_hz must be positive, got {rate_hz}")
    if hasattr(controller, "set_control_rate"):  # its events speak of this loop's period
        controller.set_control_rate(rate)
    period = 1.0 / rate
    stats = RunStats()
    total = 0.0
    failures = 0  # send_action failures in a row
    start = clock()
    tick = 0  # index of the grid tick the current step starts on
    while (max_steps is None or stats.steps < max_steps) and not stop():
        begin = clock()
        action = controller.step(robot.read_observation())
        try:
            robot.send_action(action)
            failures = 0
        except Exception as e:  # the driver's problem: hold (send nothing new), then stop
            failures += 1
            stats.send_errors += 1
            stats.last_send_error = repr(e)
            logger.warning("step %d: send_action failed (%d in a row): %r", stats.steps,
                           failures, e)
            if failures >= max_send_errors:
                stats.duration = clock() - start
                raise SendActionError(f"send_action failed {failures} times in a row, stopping "
                                      f"the loop: {e!r}") from e
        end = clock()
        work = end - begin
        stats.steps += 1
        total += work
        stats.max_step_time = max(stats.max_step_time, work)
        if work > period:
            stats.overruns += 1
        # Next tick on the grid strictly after `end` (ticks already passed are skipped).
        following = max(tick + 1, math.floor((end - start) / period) + 1)
        stats.missed_ticks += following - tick - 1
        tick = following
        if max_steps is not None and stats.steps >= max_steps:
            break
        delay = start + tick * period - clock()
        if delay > 0:
            sleep(delay)
    stats.duration = clock() - start
    stats.mean_step_time = total / stats.steps if stats.steps else 0.0
    return stats
