"""T_o > 2: the controller keeps the last T_o observations and feeds ``[oldest, latest]``.

Every test plans at every step (T_a = 1), so the recorded policy calls show the window of each
step: with T_o = 4 the window at step ``k`` is ``[o_max(k-3, s0), o_k]``, where ``s0`` is the
first step since construction, `Controller.reset` or a ``resync``.
"""

from __future__ import annotations

import numpy as np
import pytest
from rfmp_deploy import Controller
from toy_policy import Recording, ToySpec, lowdim_vector, make_observation, project, reference

T_O = 4
SPEC = ToySpec(cameras={"front": (3, 12, 16)}, horizon=4, action_steps=1, obs_horizon=T_O)


@pytest.fixture
def recording(make_policy):
    return Recording(make_policy(SPEC))


def _assert_window(call, context: float, latest: float) -> None:
    """The call's window holds the observations made with ``k = context`` and ``k = latest``."""
    observation, images, _ = call
    expected = np.stack([lowdim_vector(SPEC, make_observation(SPEC, k))
                         for k in (context, latest)])[None].astype(np.float32)
    np.testing.assert_allclose(observation, expected, atol=1e-7)
    front = images["front"]  # (1, 2, C, H, W); make_observation's frames are constant 10 k
    assert front.shape == (1, 2, 3, 12, 16) and front.dtype == np.uint8
    assert (front[0, 0] == int(10 * context)).all() and (front[0, 1] == int(10 * latest)).all()


def test_the_metadata_sets_the_kept_observations(recording):
    controller = Controller(recording)
    assert controller.meta.obs_horizon == T_O
    assert controller.meta.lowdim_input.shape == (2, 7)  # the graph's window: 2 rows


def test_window_is_the_oldest_of_the_last_t_o_then_the_latest_step_by_step(recording):
    controller = Controller(recording, seed=0)
    actions = [controller.step(make_observation(SPEC, k)) for k in range(10)]
    assert len(recording.calls) == controller.plan_count == 10
    # Episode start: the first observation stands in for the T_o - 1 steps not seen yet.
    for k, call in enumerate(recording.calls):
        _assert_window(call, max(k - (T_O - 1), 0), k)
    # The actions are the policy's on exactly those inputs.
    for action, call in zip(actions, recording.calls, strict=True):
        np.testing.assert_allclose(action, project(SPEC, reference(SPEC, *call)[0, 0]), atol=1e-5)


def test_reset_starts_the_window_again_from_the_first_observation(recording):
    controller = Controller(recording, seed=0)
    for k in range(6):
        controller.step(make_observation(SPEC, k))
    controller.reset()
    for k in range(10, 16):
        controller.step(make_observation(SPEC, k))
    after = recording.calls[6:]
    for i, call in enumerate(after):  # nothing from before the reset
        _assert_window(call, 10 + max(i - (T_O - 1), 0), 10 + i)


def test_after_an_outage_the_window_refills_like_an_episode_start(recording):
    controller = Controller(recording, seed=0)
    for k in range(6):
        controller.step(make_observation(SPEC, k))
    for _ in range(3):  # rejected: the robot holds, no plan
        controller.step({})
    assert len(recording.calls) == 6
    for k in range(9, 16):
        controller.step(make_observation(SPEC, k))
    assert controller.event_counts["resync"] == 1
    (resync,) = [e for e in controller.events if e.kind == "resync"]
    assert resync.step == 9 and "outage of 4 steps" in resync.message
    # The first fresh observation repeated until T_o fresh ones are kept; never a frame from
    # before the outage (steps 0-5).
    for i, call in enumerate(recording.calls[6:]):
        _assert_window(call, 9 + max(i - (T_O - 1), 0), 9 + i)


def test_a_single_rejected_step_also_refills_the_window(recording):
    controller = Controller(recording, seed=0)
    for k in range(5):
        controller.step(make_observation(SPEC, k))
    controller.step({})
    controller.step(make_observation(SPEC, 6))
    controller.step(make_observation(SPEC, 7))
    _assert_window(recording.calls[-2], 6, 6)
    _assert_window(recording.calls[-1], 6, 7)


def test_kept_frames_do_not_follow_a_reused_driver_buffer(recording):
    """The context frame is T_o - 1 steps old: it must be the controller's own copy."""
    controller = Controller(recording, seed=0)
    for size in ((12, 16), (24, 32)):  # at the training size (no resize) and resized
        controller.reset()
        first = len(recording.calls)
        buf = np.zeros((*size, 3), np.uint8)
        for k in range(7):
            buf[...] = 10 * k  # the driver writes every frame into the same buffer
            controller.step(make_observation(SPEC, k) | {"front": buf})
        for k, call in enumerate(recording.calls[first:]):
            _assert_window(call, max(k - (T_O - 1), 0), k)


def test_asynchronous_requests_use_the_same_window(make_policy):
    recording = Recording(make_policy(SPEC))
    with Controller(recording, seed=0, asynchronous=True) as controller:
        for k in range(8):  # one request per step, each finished before the next step
            controller.step(make_observation(SPEC, k))
            assert controller.wait_inference(5.0)
    assert len(recording.calls) == 8
    for k, call in enumerate(recording.calls):
        _assert_window(call, max(k - (T_O - 1), 0), k)


@pytest.mark.parametrize("obs_horizon", [2, 3, 6])
def test_every_t_o_keeps_t_o_observations(make_policy, obs_horizon):
    spec = ToySpec(obs_keys=[("pos", 3)], horizon=2, action_steps=1, obs_horizon=obs_horizon)
    recording = Recording(make_policy(spec))
    controller = Controller(recording, seed=0)
    for k in range(10):
        controller.step(make_observation(spec, k))
    for k, (observation, _, _) in enumerate(recording.calls):
        context = max(k - (obs_horizon - 1), 0)
        np.testing.assert_allclose(observation[0, :, 0], [0.1 * context, 0.1 * k], atol=1e-6)
