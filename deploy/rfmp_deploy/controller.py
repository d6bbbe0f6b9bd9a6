"""The receding-horizon controller: observation history, action queue, safety, timing.

Timing picture (T_p = 16 predicted, T_a = 8 executed per chunk; ``c_k[j]`` is action ``j`` of
chunk ``k``; each column is one ``step`` call, one control period)::

    synchronous (default): inference inside step, every T_a steps
      step     0      1     ...  7      8      9     ...  15     16
      infer    c_0                      c_1                      c_2
      action   c_0[0] c_0[1] ... c_0[7] c_1[0] c_1[1] ... c_1[7] c_2[0]

    asynchronous: step never waits; a background thread plans while the queue drains
      step     0      1      ...  7      8      9      ...
      request  r_0                r_1 (queue at T_p - T_a = 8)
      action   hold   c_0[1] ... c_0[7] c_0[8] c_1[2] ...   (c_1 arrived 2 steps after r_1,
                                                             so its first 2 actions are stale)

Observation window (T_o = ``obs_horizon`` from the metadata; ``o_k`` is the observation given
to step ``k``; the graph takes ``[context, latest]`` and, for T_o > 2, holds the gap T_o)::

    T_o = 4     step 0      step 1      step 2      step 3      step 4      step 5
    kept        o_0         o_0 o_1     o_0 .. o_2  o_0 .. o_3  o_1 .. o_4  o_2 .. o_5
    window      [o_0, o_0]  [o_0, o_1]  [o_0, o_2]  [o_0, o_3]  [o_1, o_4]  [o_2, o_5]

The context is the oldest of the last T_o observations; until T_o have been seen since `reset`
(or since a ``resync``) the first one stands in for the missing ones, as training pads at an
episode's start. T_o = 2 gives ``[previous, latest]``.

A chunk requested at step ``s`` is planned from the observation of step ``s``, so its action
``j`` belongs to step ``s + j``; when it arrives ``k`` steps late the controller starts at
``c[k]``. The queue runs dry (an ``underrun``: the robot holds) only when inference takes longer
than ``T_p - T_a`` control periods (or on the first step after `Controller.reset`).
"""

from __future__ import annotations

import logging
import os
import queue
import threading
import time
from collections import Counter, deque
from collections.abc import Callable, Mapping
from concurrent.futures import Future, wait
from typing import Any

import numpy as np

from rfmp_deploy.observation import Frame, ObservationError, ObservationProcessor, stack_window
from rfmp_deploy.policy import Policy
from rfmp_deploy.safety import Event, guard_action, resolve_safe_action

__all__ = ["Controller", "FaultController", "open_controller"]

logger = logging.getLogger("rfmp_deploy")


class _InferenceThread:
    """One daemon thread running policy calls in order; results come back as futures."""

    def __init__(self, policy: Callable[..., np.ndarray], clock: Callable[[], float]) -> None:
        self._policy = policy
        self._clock = clock
        self._jobs: queue.SimpleQueue = queue.SimpleQueue()
        self._thread = threading.Thread(target=self._run, name="rfmp-inference", daemon=True)
        self._thread.start()

    def submit(self, *args: Any) -> Future:
        future: Future = Future()
        self._jobs.put((future, args))
        return future

    def _run(self) -> None:
        while True:
            job = self._jobs.get()
            if job is None:
                return
            future, args = job
            if not future.set_running_or_notify_cancel():
                continue  # cancelled while queued
            start = self._clock()
            try:
                chunk = self._policy(*args)
            except BaseException as e:  # handed to the control thread, never lost
                future.set_exception(e)
            else:
                future.set_result((chunk, self._clock() - start))

    def close(self) -> None:
        self._jobs.put(None)


class Controller:
    """Turns a stream of robot observations into a stream of safe actions, one per step.

    Each `step` takes the robot's latest observation dict (low-dim fields from the model's
    ``observation_keys``, camera name -> ``H x W x 3`` uint8 RGB frame of any size) and returns
    one ``(D,)`` float32 action to send. Internally it keeps the last T_o (``obs_horizon``)
    observations, vectors and camera frames copied into its own buffers, and feeds the policy
    the window ``[o^c, o^{s-1}]``: the oldest kept observation (the context) and the latest;
    right after construction, `reset` or a ``resync`` the first observation stands in for the
    ones not seen yet. It predicts chunks of ``T_p`` actions and executes ``T_a`` of each (see
    the module's pictures).

    Safety: `step` never raises on bad input. An observation with a missing key or camera, the
    wrong shape or dtype, or NaN/inf is rejected — the controller records a ``"rejected"``
    `Event`, drops its queued plan and returns the hold action; the next good observation
    re-plans. The hold action is the last action executed since `reset`, or ``safe_action``
    before that. Every executed action has its Euclidean coordinates clipped to
    ``[action_low, action_high]`` and its sphere components (quaternions) renormalised
    (``"clamped"`` event when that changed anything). Events are appended to ``events`` and
    logged on the ``rfmp_deploy`` logger.

    Args:
        policy: a `Policy`, a path to a ``.onnx`` file, or any object with a ``meta``
            (`PolicyMeta`) and Policy's ``__call__``.
        seed: seed of the numpy ``Generator`` that draws the prior noise.
        deterministic: ``True`` feeds zeros as noise (the policy's deterministic mode),
            ``False`` draws N(0, I); ``None`` follows the metadata's ``noise.default``
            (``standard_normal`` for rfmp_rl exports).
        safe_action: ``(D,)`` action to hold before anything was executed. Default: from the
            metadata — the midpoint of ``[action_low, action_high]`` for Euclidean coordinates
            and ``(0, ..., 0, 1)`` for each sphere (the identity quaternion in xyzw order).
            Required when the limits are unbounded. Check that it is safe for your robot: the
            midpoint of the demonstrated workspace is not a resting pose.
        clock: monotonic clock in seconds (event times, inference timing).
        asynchronous: run inference in a background thread so `step` never waits for it.
        action_steps: T_a override (default: the metadata's ``action_steps``).
        control_rate_hz: rate override for the overrun check (default: the metadata's).
        max_events: keep at most this many events (oldest dropped first).

    Attributes:
        events: recorded `Event` s, oldest first.
        event_counts: kind -> number of events since construction (never trimmed).
        inference_times: recent inference durations in seconds.
        step_count: number of `step` calls since construction.
        plan_count: number of chunks put into the action queue since construction.

    Example:
        >>> controller = Controller("policy.onnx", seed=0)
        >>> observation = {"eef_pos": np.array([0.1, 0.0, 0.3]),
        ...                "eef_quat": np.array([0.0, 0.0, 0.0, 1.0]), "gripper": np.array([0.04]),
        ...                "wrist": np.zeros((480, 640, 3), np.uint8)}
        >>> actions = [controller.step(observation) for _ in range(10)]
        >>> actions[0].shape, controller.plan_count    # T_a = 8: planned at steps 0 and 8
        ((8,), 2)
        >>> bad = dict(observation, eef_pos=np.array([np.nan, 0.0, 0.3]))
        >>> held = controller.step(bad)              # no exception: hold the last action
        >>> bool(np.array_equal(held, actions[-1])), controller.events[-1].kind
        (True, 'rejected')
    """

    def __init__(
        self,
        policy: Policy | str | os.PathLike[str],
        seed: int | None = 0,
        deterministic: bool | None = None,
        safe_action: np.ndarray | None = None,
        clock: Callable[[], float] = time.monotonic,
        asynchronous: bool = False,
        action_steps: int | None = None,
        control_rate_hz: float | None = None,
        max_events: int = 10_000,
    ) -> None:
        if isinstance(policy, str | os.PathLike):
            policy = Policy(policy)
        self.policy = policy
        self.meta = meta = policy.meta
        self.space = meta.action_space
        self.processor = ObservationProcessor(meta)
        self.safe_action = resolve_safe_action(self.space, safe_action)
        self.action_steps = int(action_steps or meta.action_steps)
        if not 1 <= self.action_steps <= meta.horizon:
            raise ValueError(f"action_steps must be in [1, T_p={meta.horizon}], "
                             f"got {self.action_steps}")
        self.period = 1.0 / float(control_rate_hz or meta.control_rate_hz)
        self.deterministic = (
            meta.noise_default == "zeros" if deterministic is None else bool(deterministic)
        )
        self.asynchronous = bool(asynchronous)
        self.clock = clock
        self.max_events = int(max_events)
        self.events: list[Event] = []
        self.event_counts: Counter[str] = Counter()
        self.inference_times: deque[float] = deque(maxlen=1000)
        self.step_count = 0
        self.plan_count = 0
        self._rng = np.random.default_rng(seed)
        # the last T_o frames, oldest first: the window is [oldest, latest]
        self._history: deque[Frame] = deque(maxlen=meta.obs_horizon)
        self._queue: deque[np.ndarray] = deque()
        self._executed = 0  # actions executed from the current chunk (synchronous mode)
        self._last_action: np.ndarray | None = None
        self._worker: _InferenceThread | None = None
        self._pending: tuple[Future, int] | None = None  # (future, step index of the request)
        self._current = -1
        self._last_frame: tuple[int, float] | None = None  # (step, time) of the last frame kept
        self._dropped: str | None = None  # why the queue was last emptied (underrun messages)

    # ----- public API ----------------------------------------------------------------------
    def set_control_rate(self, rate_hz: float) -> None:
        """The rate the loop runs at (`run` sets it from its ``rate_hz``): the period that
        overrun and underrun events and their messages refer to."""
        if not float(rate_hz) > 0:
            raise ValueError(f"rate_hz must be positive, got {rate_hz}")
        self.period = 1.0 / float(rate_hz)

    def reset(self, seed: int | None = None) -> None:
        """Start a new episode: forget the history, the queued actions and the last action.

        Args:
            seed: reseed the noise generator (``None`` continues its stream).
        """
        self._drop_plan()
        self._history.clear()
        self.processor.reset()  # observed quaternions: new streams
        self._last_action = None
        self._last_frame, self._dropped = None, None
        if seed is not None:
            self._rng = np.random.default_rng(seed)

    def step(self, observation: Mapping[str, Any]) -> np.ndarray:
        """One control step: take the latest observation, return the action to send now.

        Args:
            observation: low-dim key -> ``(dim,)`` numbers and camera name -> ``(H, W, 3)``
                uint8 RGB frame.

        Returns:
            ``(D,)`` float32 action in raw units, inside the limits and on the manifold.
        """
        self._current = self.step_count
        self.step_count += 1
        try:
            frame = self.processor(observation)
        except Exception as e:  # ObservationError, or anything else preprocessing ran into
            reason = str(e) if isinstance(e, ObservationError) else f"preprocessing failed: {e!r}"
            self._drop_plan()
            self._dropped = f"an observation was rejected at step {self._current}"
            self._record("rejected", f"observation rejected, holding: {reason}")
            return self.hold_action
        self._resync()
        self._history.append(frame)
        self._last_frame = (self._current, self.clock())
        if self.asynchronous:
            return self._step_async()
        return self._step_sync()

    @property
    def hold_action(self) -> np.ndarray:
        """What the controller sends when it cannot act: the last executed action, else
        ``safe_action``."""
        action = self._last_action if self._last_action is not None else self.safe_action
        return action.copy()

    @property
    def queue_size(self) -> int:
        """Actions waiting in the queue."""
        return len(self._queue)

    @property
    def last_inference_time(self) -> float | None:
        return self.inference_times[-1] if self.inference_times else None

    def wait_inference(self, timeout: float | None = None) -> bool:
        """Block until the background inference in flight (if any) has finished.

        For start-up (step once, wait, then start the loop, so the robot does not hold while the
        first chunk is computed) and tests; never call it inside the control loop.

        Returns:
            ``True`` when no inference is in flight any more, ``False`` on timeout.
        """
        if self._pending is None:
            return True
        done, _ = wait([self._pending[0]], timeout=timeout)
        return bool(done)

    def close(self) -> None:
        """Stop the background inference thread (asynchronous mode)."""
        self._drop_plan()
        if self._worker is not None:
            self._worker.close()
            self._worker = None

    def __enter__(self) -> Controller:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ----- internals ---------------------------------------------------------------------------
    def _record(self, kind: str, message: str) -> None:
        event = Event(self.clock(), self._current, kind, message)
        self.events.append(event)
        if len(self.events) > self.max_events:
            del self.events[: len(self.events) - self.max_events]
        self.event_counts[kind] += 1
        level = logging.INFO if kind == "clamped" else logging.WARNING
        logger.log(level, "step %d: %s: %s", event.step, kind, message)

    def _resync(self) -> None:
        """After an outage (steps whose observations were rejected, so the robot held), the kept
        frames are no longer the last T_o steps': refill them from fresh observations and drop
        the plan. As after `reset`, the first fresh frame stands in for the steps not seen yet
        (the next plan pairs it with itself; for T_o > 2 it stays the context until T_o fresh
        frames were kept). (A late step after an overrun is still the next step: no resync.)"""
        if self._last_frame is None:
            return
        step, when = self._last_frame
        steps, seconds = self._current - step, self.clock() - when
        if steps <= 1:
            return
        self._history.clear()
        self._drop_plan()
        self._dropped = f"resynchronising after a {steps}-step outage"
        self._record("resync", f"observation window refilled after an outage of {steps} steps "
                               f"({seconds * 1e3:.1f} ms, control period "
                               f"{self.period * 1e3:.1f} ms)")

    def _drop_plan(self) -> None:
        self._queue.clear()
        self._executed = 0
        if self._pending is not None:
            self._pending[0].cancel()  # no-op when already running; its result is ignored
            self._pending = None

    def _inputs(self) -> tuple[np.ndarray | None, dict[str, np.ndarray], np.ndarray]:
        # [o^(s-T_o), o^(s-1)]; with fewer than T_o frames kept the first one is the context
        frames = [self._history[0], self._history[-1]]
        observation, images = stack_window(frames, self.meta)
        if self.deterministic:
            noise = np.zeros((1, self.meta.noise_dim), dtype=np.float32)
        else:
            noise = self._rng.standard_normal((1, self.meta.noise_dim), dtype=np.float32)
        return observation, images, noise

    def _execute(self, action: np.ndarray) -> np.ndarray:
        safe, message = guard_action(self.space, action)
        if safe is None:
            self._drop_plan()
            self._record("invalid_action", f"policy action unusable, holding: {message}")
            return self.hold_action
        if message:
            self._record("clamped", message)
        self._last_action = safe
        return safe.copy()

    def _step_sync(self) -> np.ndarray:
        if not self._queue or self._executed >= self.action_steps:
            self._queue.clear()
            inputs = self._inputs()
            start = self.clock()
            try:
                chunk = self.policy(*inputs)[0]  # (T_p, D)
            except Exception as e:
                self._record("inference_error", f"inference failed, holding: {e!r}")
                return self.hold_action
            elapsed = self.clock() - start
            self.inference_times.append(elapsed)
            if elapsed > self.period:
                self._record("overrun", f"inference took {elapsed * 1e3:.1f} ms, longer than the "
                                        f"control period {self.period * 1e3:.1f} ms")
            self._queue.extend(chunk[: self.action_steps])
            self._executed = 0
            self.plan_count += 1
        self._executed += 1
        return self._execute(self._queue.popleft())

    def _collect(self) -> str | None:
        """Take a finished chunk from the background thread; returns a note for underruns."""
        if self._pending is None or not self._pending[0].done():
            return None
        future, requested = self._pending
        self._pending = None
        error = future.exception()
        if error is not None:
            self._record("inference_error", f"background inference failed: {error!r}")
            return "the last inference failed"
        chunk, elapsed = future.result()
        chunk = chunk[0]  # (T_p, D)
        self.inference_times.append(elapsed)
        self._dropped = None
        late = self._current - requested
        self._queue = deque(chunk[late:])
        self.plan_count += 1
        if late >= len(chunk):
            return f"the chunk arrived {late} steps after its request, all {len(chunk)} stale"
        return None

    def _step_async(self) -> np.ndarray:
        note = self._collect()
        if self._queue:
            action = self._execute(self._queue.popleft())
        else:
            if note is None and self._dropped is not None:
                note = f"the plan was dropped: {self._dropped}"
            elif note is None:
                note = ("no chunk yet since reset" if self._last_action is None
                        else "inference is slower than the queue drains")
            self._record("underrun", f"action queue empty, holding ({note})")
            action = self.hold_action
        if self._pending is None and len(self._queue) <= self.meta.horizon - self.action_steps:
            if self._worker is None:
                self._worker = _InferenceThread(self.policy, self.clock)
            self._pending = (self._worker.submit(*self._inputs()), self._current)
        return action


#: The rate at which a `FaultController` holds its safe action under `run` without a rate.
FAULT_RATE_HZ = 10.0


class FaultController:
    """Stands in for a `Controller` whose model could not be loaded: it holds the safe action.

    A robot loop must not crash because ``policy.onnx`` is missing, truncated or inconsistent
    with its metadata: `open_controller` returns this instead, so the loop keeps running, every
    step returns ``safe_action`` and records a ``model_error`` event naming the file and the
    problem (also logged).

    Example:
        >>> fault = FaultController(ValueError("policy.onnx: bad"), safe_action=np.zeros(2))
        >>> fault.step({}), fault.events[0].kind
        (array([0., 0.], dtype=float32), 'model_error')
    """

    meta = None

    def __init__(
        self,
        error: Exception,
        safe_action: np.ndarray,
        clock: Callable[[], float] = time.monotonic,
        max_events: int = 10_000,
        control_rate_hz: float | None = None,
    ) -> None:
        self.error = error
        self.safe_action = np.asarray(safe_action, dtype=np.float32).reshape(-1).copy()
        if self.safe_action.size == 0 or not np.isfinite(self.safe_action).all():
            raise ValueError(f"safe_action must be a non-empty finite (D,) action, got "
                             f"{self.safe_action}")
        # the rate run() holds the safe action at when none is given (no model to read it from)
        self.control_rate_hz = float(control_rate_hz or FAULT_RATE_HZ)
        self.clock, self.max_events = clock, int(max_events)
        self.events: list[Event] = []
        self.event_counts: Counter[str] = Counter()
        self.step_count = 0
        self.plan_count = 0
        logger.error("no policy, holding the safe action: %s", error)

    def reset(self, seed: int | None = None) -> None:
        """Nothing to forget: the controller only ever holds."""

    def step(self, observation: Mapping[str, Any]) -> np.ndarray:
        event = Event(self.clock(), self.step_count, "model_error", f"no policy: {self.error}")
        if len(self.events) < self.max_events:
            self.events.append(event)
        self.event_counts["model_error"] += 1
        self.step_count += 1
        return self.safe_action.copy()

    def close(self) -> None:
        """Nothing to release."""

    def __enter__(self) -> FaultController:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def open_controller(
    model: str | os.PathLike[str], safe_action: np.ndarray | None = None, **kwargs: Any
) -> Controller | FaultController:
    """`Controller` for ``model``, or a `FaultController` holding ``safe_action`` if it cannot load.

    Args:
        model: path of the exported ``.onnx`` file.
        safe_action: the action to hold; required for the fallback (without it a model that
            cannot be loaded raises, since no safe action can be read from its metadata). With a
            model that loads it is checked against the model (length, finite, on the manifold,
            inside the limits).
        **kwargs: forwarded to `Controller`; ``control_rate_hz`` also sets the rate at which
            `run` holds the fallback's safe action when no rate is given (default 10 Hz).

    Raises:
        FileNotFoundError, ValueError: the model cannot be loaded and no ``safe_action`` was
            given.
        ValueError: the model loads but ``safe_action`` does not fit it (the message names
            ``safe_action``): the caller's error, never a reason to run without the policy.

    Example:
        >>> ctl = open_controller("missing.onnx", safe_action=np.zeros(3))
        >>> type(ctl).__name__, ctl.step({})
        ('FaultController', array([0., 0., 0.], dtype=float32))
    """
    try:
        policy = Policy(model)
    except (FileNotFoundError, ValueError) as err:
        if safe_action is None:
            raise
        clock = kwargs.get("clock", time.monotonic)
        return FaultController(err, safe_action, clock=clock,
                               max_events=kwargs.get("max_events", 10_000),
                               control_rate_hz=kwargs.get("control_rate_hz"))
    # the model loaded: a bad safe action (or setting) is the caller's error, raised as such,
    # never a reason to run without the policy
    return Controller(policy, safe_action=safe_action, **kwargs)
