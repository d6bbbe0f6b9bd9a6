"""The fixed-rate control loop and the interface a robot implements to be driven by it."""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

import numpy as np

from rfmp_deploy.controller import Controller

__all__ = ["RobotInterface", "RunStats", "run"]


@runtime_checkable
class RobotInterface(Protocol):
    """What the control loop needs from a robot. Implement these two methods for your arm.

    ``read_observation`` returns the latest readings, without waiting for new ones longer than
    necessary: a dict with one entry per low-dimensional field in the model's
    ``observation_keys`` (``(dim,)`` numbers in the units and frames used in training) and one
    entry per camera name (``H x W x 3`` uint8 RGB, any size: the controller resizes). Print
    ``python -m rfmp_deploy.run --model policy.onnx --check`` for the list. If a sensor is
    unavailable, leave its key out (or pass NaN) rather than raising: the controller then holds
    and records a ``rejected`` event, and the loop keeps its rate. Exceptions propagate and end
    the loop.

    ``send_action`` receives one ``(D,)`` float32 action in the layout of the model's
    ``action_manifold`` (e.g. position xyz, quaternion xyzw, gripper) and must return quickly
    (queue it to the driver; do not wait for the motion to finish). It is already clipped to
    the training limits; apply your robot's own limits too (workspace, velocity, force).

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
        missed_ticks: control ticks skipped because of overruns (the loop does not burst to
            catch up; it waits for the next tick on the original grid).
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

    def summary(self) -> str:
        return (f"{self.steps} steps in {self.duration:.2f} s; step time mean "
                f"{self.mean_step_time * 1e3:.2f} ms, max {self.max_step_time * 1e3:.2f} ms; "
                f"{self.overruns} overrun(s), {self.missed_ticks} missed tick(s)")


def run(
    controller: Controller,
    robot: RobotInterface,
    rate_hz: float | None = None,
    max_steps: int | None = None,
    stop: Callable[[], bool] = lambda: False,
    clock: Callable[[], float] = time.monotonic,
    sleep: Callable[[float], None] = time.sleep,
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

    Returns:
        the loop's `RunStats`.
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
    start = clock()
    tick = 0  # index of the grid tick the current step starts on
    while (max_steps is None or stats.steps < max_steps) and not stop():
        begin = clock()
        robot.send_action(controller.step(robot.read_observation()))
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
