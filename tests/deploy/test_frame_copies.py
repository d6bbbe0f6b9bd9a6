"""Camera frames are copied into the controller's own buffers: a robot driver that overwrites
its frame buffer after every step never changes a frame the controller already holds."""

from __future__ import annotations

import numpy as np
import pytest
from rfmp_deploy import Controller
from rfmp_deploy.observation import ObservationProcessor
from toy_policy import Recording, ToySpec, make_observation

SPEC = ToySpec(cameras={"front": (3, 12, 16), "wrist": (1, 8, 8)}, horizon=4, action_steps=2)


def _buffers(layout: str):
    """``(robot buffer, frame handed to the controller, camera)`` for one layout: each frame
    is a view of the buffer the robot keeps writing into."""
    if layout == "rgb":  # HWC, already at the training size
        buf = np.zeros((12, 16, 3), np.uint8)
        return buf, buf, "front"
    if layout == "rgb-resized":  # HWC, resized to the training size
        buf = np.zeros((24, 32, 3), np.uint8)
        return buf, buf, "front"
    if layout == "hwc-view-of-chw":  # a CHW driver buffer handed over as an HWC view
        buf = np.zeros((3, 12, 16), np.uint8)
        return buf, buf.transpose(1, 2, 0), "front"
    if layout == "gray":  # (H, W), already at size
        buf = np.zeros((8, 8), np.uint8)
        return buf, buf, "wrist"
    if layout == "gray-hw1":  # (H, W, 1), already at size
        buf = np.zeros((8, 8, 1), np.uint8)
        return buf, buf, "wrist"
    raise AssertionError(layout)


LAYOUTS = ["rgb", "rgb-resized", "hwc-view-of-chw", "gray", "gray-hw1"]


@pytest.mark.parametrize("layout", LAYOUTS)
def test_a_preprocessed_frame_does_not_follow_the_robot_buffer(make_policy, layout):
    process = ObservationProcessor(make_policy(SPEC).meta)
    buf, frame, camera = _buffers(layout)
    observation = make_observation(SPEC, 0, frame_size=(8, 8))
    buf[...] = 7
    observation[camera] = frame
    kept = process(observation).images[camera]
    assert (kept == 7).all()
    buf[...] = 200  # the driver writes the next frame into the same buffer
    assert (kept == 7).all(), "the controller's frame aliases the robot's buffer"


@pytest.mark.parametrize("layout", LAYOUTS)
def test_the_window_pairs_two_different_frames(make_policy, layout):
    recording = Recording(make_policy(SPEC))
    controller = Controller(recording, seed=0)
    buf, frame, camera = _buffers(layout)
    for k in range(3):  # plans at steps 0 and 2: the second window holds steps 1 and 2
        buf[...] = 10 * (k + 1)
        observation = make_observation(SPEC, k, frame_size=(8, 8))
        observation[camera] = frame
        controller.step(observation)
    _, images, _ = recording.calls[-1]
    window = images[camera][0]  # (T_o, C, H, W): previous, latest
    assert (window[0] == 20).all() and (window[1] == 30).all()
