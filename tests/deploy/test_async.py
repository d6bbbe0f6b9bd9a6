"""`Controller(asynchronous=True)`: step never waits for inference; late chunks skip stale
actions; an empty queue holds with an ``underrun`` event."""

from __future__ import annotations

import time

import numpy as np
import pytest
from rfmp_deploy import Controller, run
from toy_policy import Gated, ToySpec, lowdim_vector, make_observation, project, reference

SPEC = ToySpec(horizon=8, action_steps=4)  # request a new chunk when <= 4 actions are left
SAFE = np.float32([0, 0, 0, 0, 0, 0, 1, 0])
FAST = 0.1  # seconds: a step that "never blocks" is far below this (the gated model blocks 10 s)


def _chunk(call):
    return reference(SPEC, *call)[0]  # (T_p, D)


def _timed_step(controller, observation):
    start = time.perf_counter()
    action = controller.step(observation)
    return action, time.perf_counter() - start


@pytest.fixture
def gated(make_policy):
    policy = Gated(make_policy(SPEC))
    yield policy
    policy.gate.set()  # never leave the worker blocked


def test_step_never_blocks_on_a_slow_model(gated):
    with Controller(gated, asynchronous=True) as controller:
        action, elapsed = _timed_step(controller, make_observation(SPEC, 0))
        assert elapsed < FAST
        np.testing.assert_array_equal(action, SAFE)
        assert gated.started.wait(5)  # the worker is now stuck inside inference
        for k in (1, 2):
            action, elapsed = _timed_step(controller, make_observation(SPEC, k))
            assert elapsed < FAST
            np.testing.assert_array_equal(action, SAFE)
        kinds = [e.kind for e in controller.events if e.kind != "clamped"]
        assert kinds == ["underrun"] * 3
        assert "no chunk yet" in controller.events[0].message
        gated.gate.set()
        assert controller.wait_inference(5)
        # Requested at step 0, collected at step 3: actions 0-2 are stale, c[3] is due now.
        action, _ = _timed_step(controller, make_observation(SPEC, 3))
        np.testing.assert_allclose(action, project(SPEC, _chunk(gated.calls[0])[3]), atol=1e-5)
        assert controller.plan_count == 1


def test_steady_state_replans_every_t_a_steps(gated):
    gated.gate.set()
    observations = [make_observation(SPEC, k) for k in range(10)]
    with Controller(gated, asynchronous=True) as controller:
        actions = []
        for o in observations:
            actions.append(controller.step(o))
            assert controller.wait_inference(5)  # a model faster than the control period
    assert controller.event_counts["underrun"] == 1  # only the very first step
    # Requests at steps 0, 3, 6, 9 (queue down to T_p - T_a = 4); each chunk arrives one step
    # after its request, so steps s+1..s+3 execute c[1..3].
    assert len(gated.calls) == 4
    window = np.stack([lowdim_vector(SPEC, observations[k]) for k in (2, 3)])
    np.testing.assert_allclose(gated.calls[1][0][0], window)
    for i, call in enumerate(gated.calls[:3]):
        chunk = _chunk(call)
        for j in (1, 2, 3):
            np.testing.assert_allclose(actions[3 * i + j], project(SPEC, chunk[j]), atol=1e-5)


def test_underrun_holds_the_last_action(gated):
    with Controller(gated, asynchronous=True) as controller:
        controller.step(make_observation(SPEC, 0))
        gated.gate.set()
        assert controller.wait_inference(5)
        gated.gate.clear()  # the next inference will take "forever"
        actions = []
        for k in range(1, 8):  # c0[1..7]; the request made at step 3 never returns
            action, elapsed = _timed_step(controller, make_observation(SPEC, k))
            assert elapsed < FAST
            actions.append(action)
        assert controller.queue_size == 0
        held, elapsed = _timed_step(controller, make_observation(SPEC, 8))
        assert elapsed < FAST
        np.testing.assert_array_equal(held, actions[-1])
        last = controller.events[-1]
        assert last.kind == "underrun" and last.step == 8
        assert "inference is slower than the queue drains" in last.message
        gated.gate.set()
        assert controller.wait_inference(5)
        # Requested at step 3, collected at step 9: c1[6] is due.
        action = controller.step(make_observation(SPEC, 9))
        np.testing.assert_allclose(action, project(SPEC, _chunk(gated.calls[1])[6]), atol=1e-5)


def test_reset_discards_the_chunk_in_flight(gated):
    with Controller(gated, asynchronous=True) as controller:
        controller.step(make_observation(SPEC, 0))
        assert gated.started.wait(5)
        controller.reset()
        gated.gate.set()
        fresh = make_observation(SPEC, 5)
        controller.step(fresh)  # the old chunk is ignored; a new one is requested
        assert controller.wait_inference(5)
        assert controller.step(fresh) is not None
        assert controller.plan_count == 1
        np.testing.assert_allclose(gated.calls[-1][0][0],
                                   np.stack([lowdim_vector(SPEC, fresh)] * 2), atol=1e-7)


def test_background_errors_become_events(make_policy):
    class Failing:
        def __init__(self, policy):
            self.meta = policy.meta

        def __call__(self, *inputs):
            raise RuntimeError("session lost")

    with Controller(Failing(make_policy(SPEC)), asynchronous=True) as controller:
        controller.step(make_observation(SPEC))
        assert controller.wait_inference(5)
        action = controller.step(make_observation(SPEC))
    np.testing.assert_array_equal(action, SAFE)
    kinds = [e.kind for e in controller.events]
    assert kinds == ["underrun", "inference_error", "underrun"]
    assert "session lost" in controller.events[1].message


def test_close_stops_the_worker(gated):
    gated.gate.set()
    controller = Controller(gated, asynchronous=True)
    controller.step(make_observation(SPEC))
    thread = controller._worker._thread
    assert thread.is_alive() and thread.daemon
    controller.close()
    thread.join(5)
    assert not thread.is_alive()
    assert Controller(gated)._worker is None  # synchronous controllers start no thread


def test_real_time_loop_with_a_sleeping_model(make_policy):
    """A model 3x slower than the period: the loop keeps its rate and the robot holds."""

    class Sleepy:
        def __init__(self, policy):
            self.policy, self.meta = policy, policy.meta

        def __call__(self, *inputs):
            time.sleep(0.06)
            return self.policy(*inputs)

    class Robot:
        def __init__(self):
            self.sent = []

        def read_observation(self):
            return make_observation(SPEC, len(self.sent))

        def send_action(self, action):
            self.sent.append(action)

    robot = Robot()
    with Controller(Sleepy(make_policy(SPEC)), asynchronous=True) as controller:
        stats = run(controller, robot, rate_hz=50, max_steps=25)
    assert stats.steps == 25 and len(robot.sent) == 25
    assert stats.max_step_time < 0.045  # never waited for the 60 ms inference
    assert controller.event_counts["underrun"] >= 3  # the first 60 ms at least
    assert controller.plan_count >= 2
