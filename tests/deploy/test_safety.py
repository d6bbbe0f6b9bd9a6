"""Safety: bad observations hold, actions are clipped and renormalised, errors become events."""

from __future__ import annotations

import logging
import re

import numpy as np
import pytest
from rfmp_deploy import Controller, Event
from toy_policy import R3_S3_R1, Recording, ToySpec, make_observation

SPEC = ToySpec(cameras={"front": (3, 12, 16)}, horizon=4, action_steps=2)
SAFE = np.float32([0, 0, 0, 0, 0, 0, 1, 0])  # midpoint of [-1, 1]; identity quaternion


def _bad(edit):
    def make():
        observation = make_observation(SPEC, 1.0)
        edit(observation)
        return observation
    return make


BAD_OBSERVATIONS = {
    "nan": (_bad(lambda o: o.update(pos=np.array([0.1, np.nan, 0.2]))), "'pos': non-finite"),
    "inf": (_bad(lambda o: o.update(quat=np.array([0, 0, np.inf, 1.0]))), "'quat': non-finite"),
    "float32 overflow": (_bad(lambda o: o.update(pos=np.array([1e39, 0, 0]))), "beyond float32"),
    "wrong shape": (_bad(lambda o: o.update(pos=np.zeros(4))), r"expected shape \(3,\)"),
    "wrong rank": (_bad(lambda o: o.update(pos=np.zeros((1, 3)))), r"got \(1, 3\)"),
    "string dtype": (_bad(lambda o: o.update(pos=np.array(["a", "b", "c"]))), "real numbers"),
    "complex dtype": (_bad(lambda o: o.update(pos=np.zeros(3, complex))), "complex128"),
    "bool dtype": (_bad(lambda o: o.update(pos=np.ones(3, bool))), "dtype bool"),
    "object": (_bad(lambda o: o.update(pos=[object(), 1, 2])), "real numbers"),
    "missing key": (_bad(lambda o: o.pop("quat")), "missing key 'quat'"),
    "missing camera": (_bad(lambda o: o.pop("front")), "missing camera 'front'"),
    "camera channels": (_bad(lambda o: o.update(front=np.zeros((48, 64, 4), np.uint8))),
                        r"expected an \(H, W, 3\) frame, got shape \(48, 64, 4\)"),
    "camera gray": (_bad(lambda o: o.update(front=np.zeros((48, 64), np.uint8))),
                    r"got shape \(48, 64\)"),
    "camera dtype": (_bad(lambda o: o.update(front=np.zeros((48, 64, 3), np.float32))),
                     "expected dtype uint8, got float32"),
    "camera list": (_bad(lambda o: o.update(front=[[0, 0, 0]])), "expected a uint8 numpy array"),
    "camera empty": (_bad(lambda o: o.update(front=np.zeros((0, 64, 3), np.uint8))),
                     r"got shape \(0, 64, 3\)"),
    "not a dict": (lambda: [1, 2, 3], "observation must be a dict"),
}


@pytest.fixture
def recording(make_policy):
    return Recording(make_policy(SPEC))


@pytest.mark.parametrize("case", sorted(BAD_OBSERVATIONS))
def test_bad_observation_holds_with_an_event(recording, caplog, case):
    make, message = BAD_OBSERVATIONS[case]
    controller = Controller(recording, clock=lambda: 42.0)
    with caplog.at_level(logging.WARNING, logger="rfmp_deploy"):
        first = controller.step(make())  # nothing executed yet: the safe action
    np.testing.assert_array_equal(first, SAFE)
    assert len(controller.events) == 1
    event = controller.events[0]
    assert isinstance(event, Event) and event.kind == "rejected" and event.step == 0
    assert event.time == 42.0
    assert re.search(message, event.message)
    assert "rejected" in caplog.text
    assert recording.calls == []  # never reached the model

    executed = controller.step(make_observation(SPEC, 0.0))
    held = controller.step(make())  # after an executed action: hold it
    np.testing.assert_array_equal(held, executed)
    assert controller.event_counts["rejected"] == 2


def test_all_problems_are_listed_at_once(recording):
    controller = Controller(recording)
    controller.step({"pos": np.array([np.nan, 0, 0])})
    message = controller.events[-1].message
    assert "'pos': non-finite" in message and "missing key 'quat'" in message
    assert "missing camera 'front'" in message


def test_rejection_drops_the_plan(recording):
    controller = Controller(recording)
    controller.step(make_observation(SPEC, 0))
    assert controller.queue_size == 1
    controller.step({})
    assert controller.queue_size == 0
    controller.step(make_observation(SPEC, 1))  # the next good observation re-plans
    assert len(recording.calls) == 2
    # ... from a window refilled with fresh observations: the frame before the outage is not
    # the previous step's, so it is not paired with the new one as if consecutive
    np.testing.assert_allclose(recording.calls[1][0][0, :, 0], [0.1, 0.1], atol=1e-7)
    assert controller.event_counts["resync"] == 1


def test_extra_keys_and_types_that_are_fine(recording):
    observation = make_observation(SPEC) | {"joint_torques": np.zeros(7)}
    observation["pos"] = [0, 1, 2]  # python ints
    observation["quat"] = observation["quat"].astype(np.float16)
    Controller(recording).step(observation)
    np.testing.assert_array_equal(recording.calls[0][0][0, 1, :3], [0, 1, 2])


def test_scalar_for_a_one_dim_field(make_policy):
    spec = ToySpec(obs_keys=[("gripper", 1)])
    controller = Controller(Recording(make_policy(spec)))
    controller.step({"gripper": 0.04})
    controller.step({"gripper": np.array([0.05])})
    assert controller.event_counts["rejected"] == 0


def test_clamped_and_renormalised(make_policy):
    # Bias pushes x far above its limit; the quaternion comes out with norm ~5.
    bias = np.array([3.0, 0, 0, 0, 0, 0, 5.0, 0])
    spec = ToySpec(bias=bias, horizon=4, action_steps=2)
    controller = Controller(make_policy(spec), deterministic=True)
    actions = np.stack([controller.step(make_observation(spec, 0.1 * k)) for k in range(4)])
    assert np.all(actions[:, 0] == 1.0)  # clipped to action_high
    assert np.all(actions[:, :3] <= 1) and np.all(actions[:, :3] >= -1)
    np.testing.assert_allclose(np.linalg.norm(actions[:, 3:7], axis=1), 1.0, rtol=1e-6)
    clamped = [e for e in controller.events if e.kind == "clamped"]
    assert len(clamped) == 4
    assert "clipped coordinate(s) 0 to [-1, 1]" in clamped[0].message
    assert "renormalised S3 at 3:7" in clamped[0].message


def test_no_clamped_event_for_valid_actions(make_policy):
    spec = ToySpec(manifold={"type": "euclidean", "dim": 8}, weight=np.zeros((22, 8)),
                   bias=np.full(8, 0.5), offsets=np.zeros((4, 8)))
    controller = Controller(make_policy(spec))
    np.testing.assert_array_equal(controller.step(make_observation(spec)), np.full(8, 0.5))
    assert controller.events == []


class Broken:
    def __init__(self, policy, mode):
        self.policy, self.meta, self.mode = policy, policy.meta, mode

    def __call__(self, *inputs):
        if self.mode == "raise":
            raise RuntimeError("CUDA fell off the bus")
        chunk = self.policy(*inputs)
        if self.mode == "nan":
            chunk[:, :, 1] = np.nan
        else:  # zero quaternion
            chunk[:, :, 3:7] = 0.0
        return chunk


@pytest.mark.parametrize(
    ("mode", "kind", "message"),
    [("raise", "inference_error", "CUDA fell off the bus"),
     ("nan", "invalid_action", r"non-finite coordinate\(s\) \[1\]"),
     ("zero", "invalid_action", "no direction to renormalise")],
)
def test_unusable_policy_output_holds(make_policy, mode, kind, message):
    controller = Controller(Broken(make_policy(SPEC), mode))
    action = controller.step(make_observation(SPEC))
    np.testing.assert_array_equal(action, SAFE)
    assert controller.events[-1].kind == kind
    assert re.search(message, controller.events[-1].message)
    assert controller.queue_size == 0  # the next step re-plans


def test_safe_action(make_policy):
    unbounded = ToySpec(low=[None] * 8, high=[None] * 8)
    with pytest.raises(ValueError, match="pass Controller\\(..., safe_action=...\\)"):
        Controller(make_policy(unbounded))
    home = np.array([0.3, 0.0, 0.2, 0, 0, 0, 1.0, 0.0])
    controller = Controller(make_policy(unbounded), safe_action=home)
    np.testing.assert_allclose(controller.step({}), home)
    # the robot holds the safe action as given: a quaternion off S^3 is refused, not fixed
    with pytest.raises(ValueError, match="safe_action is off the manifold: its S3 component"):
        Controller(make_policy(unbounded), safe_action=home * [1, 1, 1, 1, 1, 1, 2, 1])
    with pytest.raises(ValueError, match="outside the action limits"):
        Controller(make_policy(SPEC), safe_action=np.full(8, 2.0))
    with pytest.raises(ValueError, match=r"shape \(3,\)"):
        Controller(make_policy(SPEC), safe_action=np.zeros(3))


def test_overrun_in_synchronous_mode(make_policy):
    now = [0.0]

    class Slow:
        def __init__(self, policy):
            self.policy, self.meta = policy, policy.meta

        def __call__(self, *inputs):
            now[0] += 0.25  # 250 ms of fake time, period 100 ms
            return self.policy(*inputs)

    controller = Controller(Slow(make_policy(SPEC)), clock=lambda: now[0])
    controller.step(make_observation(SPEC))
    assert controller.last_inference_time == pytest.approx(0.25)
    overruns = [e for e in controller.events if e.kind == "overrun"]
    assert len(overruns) == 1 and overruns[0].time == pytest.approx(0.25)
    assert "250.0 ms, longer than the control period 100.0 ms" in overruns[0].message
    controller.step(make_observation(SPEC))  # served from the queue: no inference, no overrun
    assert controller.event_counts["overrun"] == 1
    fast = Controller(make_policy(SPEC), control_rate_hz=1e-3)  # a 1000 s period never overruns
    fast.step(make_observation(SPEC))
    assert fast.event_counts["overrun"] == 0 and len(fast.inference_times) == 1


def test_event_list_is_bounded(recording):
    controller = Controller(recording, max_events=5)
    for _ in range(12):
        controller.step({})
    assert len(controller.events) == 5 and controller.event_counts["rejected"] == 12
    assert [e.step for e in controller.events] == [7, 8, 9, 10, 11]


def test_action_space_spec_is_the_models(make_policy):
    controller = Controller(make_policy(SPEC))
    assert controller.space.spec == R3_S3_R1


def test_unexpected_preprocessing_failure_is_a_rejection(recording):
    controller = Controller(recording)

    def broken(observation):
        raise RuntimeError("driver returned garbage")

    controller.processor = broken
    np.testing.assert_array_equal(controller.step(make_observation(SPEC)), SAFE)
    event = controller.events[-1]
    assert event.kind == "rejected" and "RuntimeError('driver returned garbage')" in event.message


def test_after_an_outage_the_window_is_refilled_and_a_resync_reported(recording):
    controller = Controller(recording)
    for k in range(3):
        controller.step(make_observation(SPEC, k))
    for _ in range(50):  # a 50-step outage: every observation rejected, the robot holds
        controller.step({})
    controller.step(make_observation(SPEC, 9))
    (resync,) = [e for e in controller.events if e.kind == "resync"]
    assert "outage of 51 steps" in resync.message and resync.step == 53
    np.testing.assert_allclose(recording.calls[-1][0][0, :, 0], [0.9, 0.9], atol=1e-6)
    controller.step(make_observation(SPEC, 10))  # consecutive again: no further resync
    assert controller.event_counts["resync"] == 1


def test_async_underrun_after_an_outage_names_its_cause(make_policy):
    controller = Controller(Recording(make_policy(SPEC)), asynchronous=True)
    controller.step(make_observation(SPEC, 0))
    controller.wait_inference(5.0)
    controller.step(make_observation(SPEC, 1))
    controller.step({})
    controller.step(make_observation(SPEC, 3))
    underruns = [e.message for e in controller.events if e.kind == "underrun"]
    assert "the plan was dropped: resynchronising after a 2-step outage" in underruns[-1]
    assert "slower than the queue drains" not in underruns[-1]
    controller.close()
