"""`Controller` in synchronous mode: history window, action queue, noise, reset."""

from __future__ import annotations

import numpy as np
import pytest
from rfmp_deploy import Controller
from toy_policy import (
    Recording,
    ToySpec,
    lowdim_vector,
    make_observation,
    project,
    reference,
)

SPEC = ToySpec(cameras={"front": (3, 12, 16)}, horizon=4, action_steps=2)


@pytest.fixture
def recording(make_policy):
    return Recording(make_policy(SPEC))


def _window(*observations):
    return np.stack([lowdim_vector(SPEC, o) for o in observations])[None].astype(np.float32)


def test_executes_t_a_actions_of_each_chunk(recording):
    controller = Controller(recording, seed=0)
    observations = [make_observation(SPEC, k) for k in range(9)]
    actions = [controller.step(o) for o in observations]
    # T_p = 4, T_a = 2: a chunk at steps 0, 2, 4, 6, 8.
    assert len(recording.calls) == controller.plan_count == 5
    assert controller.step_count == 9
    for i, (obs, images, noise) in enumerate(recording.calls):
        s = 2 * i
        chunk = reference(SPEC, obs, images, noise)[0]  # (T_p, D)
        for j in range(2):
            if s + j < len(actions):
                np.testing.assert_allclose(actions[s + j], project(SPEC, chunk[j]), atol=1e-5)
    assert all(a.shape == (8,) and a.dtype == np.float32 for a in actions)


def test_window_is_context_then_latest(recording):
    controller = Controller(recording, seed=0)
    observations = [make_observation(SPEC, k) for k in range(5)]
    for o in observations:
        controller.step(o)
    windows = [c[0] for c in recording.calls]  # steps 0, 2, 4
    # First step after construction: the latest observation repeated.
    np.testing.assert_allclose(windows[0], _window(observations[0], observations[0]))
    np.testing.assert_allclose(windows[1], _window(observations[1], observations[2]))
    np.testing.assert_allclose(windows[2], _window(observations[3], observations[4]))
    # Camera frames (constant 10 k, resized from 48x64 to 12x16) follow the same window.
    front = recording.calls[1][1]["front"]
    assert front.shape == (1, 2, 3, 12, 16) and front.dtype == np.uint8
    np.testing.assert_array_equal(front[0, :, 0, 0, 0], [10, 20])
    first = recording.calls[0][1]["front"]
    np.testing.assert_array_equal(first[0, 0], first[0, 1])


def test_reset_clears_history_and_queue(recording):
    controller = Controller(recording, seed=0)
    for k in range(3):  # chunks at steps 0 and 2; one action left in the queue
        controller.step(make_observation(SPEC, k))
    assert controller.queue_size == 1 and len(recording.calls) == 2
    controller.reset()
    assert controller.queue_size == 0
    fresh = make_observation(SPEC, 7)
    controller.step(fresh)
    assert len(recording.calls) == 3  # re-planned at once
    np.testing.assert_allclose(recording.calls[-1][0], _window(fresh, fresh))
    # The last executed action is forgotten too: right after a reset the hold is safe_action.
    controller.reset()
    np.testing.assert_array_equal(controller.hold_action, controller.safe_action)


def test_action_steps_override(recording):
    controller = Controller(recording, action_steps=4)
    for k in range(8):
        controller.step(make_observation(SPEC, k))
    assert len(recording.calls) == 2
    with pytest.raises(ValueError, match="action_steps must be in"):
        Controller(recording, action_steps=5)


def test_noise_is_seeded_standard_normal(recording):
    controller = Controller(recording, seed=3)
    for k in range(4):
        controller.step(make_observation(SPEC, k))
    rng = np.random.default_rng(3)
    for call in recording.calls:
        np.testing.assert_array_equal(call[2], rng.standard_normal((1, 8), dtype=np.float32))
    # Same seed, same actions; another seed, other actions.
    a = [Controller(recording, seed=1).step(make_observation(SPEC)) for _ in range(2)]
    b = Controller(recording, seed=2).step(make_observation(SPEC))
    np.testing.assert_array_equal(a[0], a[1])
    assert not np.allclose(a[0], b)


def test_deterministic_feeds_zeros(recording, make_policy):
    actions = []
    for seed in (0, 1):
        controller = Controller(recording, seed=seed, deterministic=True)
        actions.append(controller.step(make_observation(SPEC)))
        np.testing.assert_array_equal(recording.calls[-1][2], np.zeros((1, 8), np.float32))
    np.testing.assert_array_equal(actions[0], actions[1])
    # A model whose metadata says noise.default = zeros is deterministic by default.
    zeros = Controller(make_policy(ToySpec(noise_default="zeros")))
    assert zeros.deterministic
    assert not Controller(recording).deterministic


def test_accepts_a_path(make_model):
    controller = Controller(make_model(SPEC))
    assert controller.meta.horizon == 4
    assert controller.step(make_observation(SPEC)).shape == (8,)


def test_frames_are_resized_with_inter_area(recording):
    import cv2

    rng = np.random.default_rng(0)
    frame = rng.integers(0, 256, (30, 50, 3), dtype=np.uint8)
    observation = make_observation(SPEC) | {"front": frame}
    Controller(recording).step(observation)
    expected = cv2.resize(frame, (16, 12), interpolation=cv2.INTER_AREA).transpose(2, 0, 1)
    np.testing.assert_array_equal(recording.calls[0][1]["front"][0, 1], expected)
    # Frames already at the model's size are passed through untouched.
    exact = rng.integers(0, 256, (12, 16, 3), dtype=np.uint8)
    Controller(recording).step(make_observation(SPEC) | {"front": exact})
    np.testing.assert_array_equal(recording.calls[-1][1]["front"][0, 1], exact.transpose(2, 0, 1))
