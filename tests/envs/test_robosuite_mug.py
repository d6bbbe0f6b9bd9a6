"""The mug tasks (PickPlaceMug, MugFlip): registration, placements, success check, object state,
cameras, and one successful episode of each scripted expert."""

from __future__ import annotations

import importlib.util
import math
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from tensordict import TensorDict

pytest.importorskip("robosuite")

from rfmp_rl.envs.robosuite import (  # noqa: E402
    ROBOSUITE_MUG_TASKS,
    ROBOSUITE_OBJECT_DIMS,
    RobosuiteEnv,
)

RECIPE = Path(__file__).resolve().parents[2] / "recipes" / "robosuite"
_spec = importlib.util.spec_from_file_location("robosuite_experts", RECIPE / "experts.py")
experts = importlib.util.module_from_spec(_spec)
sys.modules[_spec.name] = experts  # the recipe's scripted experts (recipes/ is not a package)
_spec.loader.exec_module(experts)

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def envs():
    """One batch-1 abs_pose env per mug task, built once for the module."""
    cache = {task: RobosuiteEnv(task, [1], "abs_pose") for task in ROBOSUITE_MUG_TASKS}
    yield cache
    for env in cache.values():
        env.close()


def reset(env: RobosuiteEnv, seed: int) -> TensorDict:
    return env.reset(TensorDict({"seed": torch.tensor([seed])}, [1]))


def _scene(env: RobosuiteEnv) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    sim = env.sims[0]
    data = sim.sim.data
    return (np.array(data.body_xpos[sim.mug_body_id]), sim.mug_axis(),
            np.array(data.body_xpos[sim.plate_body_id]))


@pytest.mark.parametrize("task", ROBOSUITE_MUG_TASKS)
def test_placements_are_random_seeded_and_as_documented(envs, task):
    env = envs[task]
    from rfmp_rl.envs import robosuite_mug

    cls = getattr(robosuite_mug, task)
    scenes = []
    for seed in (0, 1, 2, 0):
        td = reset(env, seed)
        mug, axis, plate = _scene(env)
        scenes.append(mug)
        assert td["object"].shape == (1, ROBOSUITE_OBJECT_DIMS[task]) == (1, 17)
        # object: mug in the hand frame (7), mug pose (7), then the plate position (3)
        f32 = {"dtype": torch.float32}
        torch.testing.assert_close(td["object"][0, 7:10], torch.as_tensor(mug, **f32))
        torch.testing.assert_close(td["object"][0, 14:], torch.as_tensor(plate, **f32))
        assert not td["success"].any()
        assert cls.mug_x_range[0] - 1e-6 <= mug[0] <= cls.mug_x_range[1] + 1e-6
        assert cls.mug_y_range[0] - 1e-6 <= mug[1] <= cls.mug_y_range[1] + 1e-6
        assert cls.plate_y_range[0] - 1e-6 <= plate[1] <= cls.plate_y_range[1] + 1e-6
        if task == "MugFlip":  # on its side, the opening within the documented yaw range
            assert abs(axis[2]) < 1e-2
            yaw = math.atan2(axis[1], axis[0])
            assert cls.mug_yaw_range[0] - 1e-2 <= yaw <= cls.mug_yaw_range[1] + 1e-2
        else:
            assert axis[2] > 0.999
    assert not np.allclose(scenes[0], scenes[1])  # different seeds, different scenes
    np.testing.assert_allclose(scenes[0], scenes[3])  # the same seed, the same scene
    # the mug rests where it was put (the lying mug does not roll): 10 steps holding the pose
    td = reset(env, 1)
    before = _scene(env)[0]
    hold = torch.cat([td["robot0_eef_pos"], td["robot0_eef_quat"], -torch.ones(1, 1)], -1)
    for _ in range(10):
        td = env.step(td.set("action", hold))["next"]
    np.testing.assert_allclose(_scene(env)[0], before, atol=2e-3)


def _put_mug(env: RobosuiteEnv, offset_xy, upright: bool, lift: float = 0.0) -> bool:
    """Place the mug relative to the plate and return the env's success check."""
    from robosuite.utils.transform_utils import axisangle2quat, convert_quat

    from rfmp_rl.envs.robosuite_mug import MUG_HALF_HEIGHT, MUG_RADIUS, PLATE_HALF_HEIGHT

    sim = env.sims[0]
    plate = np.array(sim.sim.data.body_xpos[sim.plate_body_id])
    top = plate[2] + PLATE_HALF_HEIGHT
    if upright:
        pos = [plate[0] + offset_xy[0], plate[1] + offset_xy[1], top + MUG_HALF_HEIGHT + lift]
        quat = [1.0, 0.0, 0.0, 0.0]
    else:
        pos = [plate[0] + offset_xy[0], plate[1] + offset_xy[1], top + MUG_RADIUS + lift]
        quat = convert_quat(axisangle2quat(np.array([0.0, math.pi / 2, 0.0])), to="wxyz")
    sim.sim.data.set_joint_qpos(sim.mug.joints[0], np.concatenate([pos, quat]))
    sim.sim.forward()
    return bool(sim._check_success())


def test_success_is_upright_on_the_plate(envs):
    env = envs["PickPlaceMug"]
    reset(env, 3)
    assert _put_mug(env, (0.0, 0.0), upright=True)
    assert _put_mug(env, (0.03, -0.02), upright=True)  # off centre, still on the plate
    assert not _put_mug(env, (0.0, 0.0), upright=False)  # on its side
    assert not _put_mug(env, (0.0, 0.12), upright=True)  # beside the plate
    assert not _put_mug(env, (0.0, 0.0), upright=True, lift=0.05)  # above it


@pytest.mark.parametrize("task", ROBOSUITE_MUG_TASKS)
def test_expert_succeeds(envs, task):
    env = envs[task]
    env.seeds = [7]
    out = env.rollout(env.max_steps, experts.ExpertPolicy(env), break_when_any_done=True)
    assert out["next", "success"][0, -1].item()
    assert out["next", "terminated"][0, -1].item() and not out["next", "truncated"].any()
    q = out["action"][0, :, 3:7]
    torch.testing.assert_close(q.norm(dim=-1), torch.ones(q.shape[0]), atol=1e-5, rtol=0)
    mug, axis, plate = _scene(env)
    assert axis[2] > 0.96 and np.linalg.norm(mug[:2] - plate[:2]) < 0.055
    if task == "MugFlip":  # the hand turned by 90 degrees or more on the way
        hand = out["robot0_eef_quat"][0].double()
        turn = 2 * torch.acos((hand[0] @ hand.T).abs().clamp(max=1.0)).max()
        assert float(turn) > 1.4, float(turn)


def test_cameras_render_the_scene():
    env = RobosuiteEnv("MugFlip", [1], cameras=True, image_size=64, seeds=[0])
    td = env.reset()
    for cam in ("agentview", "robot0_eye_in_hand"):
        image = td[f"{cam}_image"]
        assert image.shape == (1, 3, 64, 64) and image.dtype == torch.uint8
        assert image.float().std() > 1.0
    env.close()


def test_mug_expert_rejects_other_tasks():
    sys.path.insert(0, str(RECIPE))
    try:
        from experts_mug import MugExpert
    finally:
        sys.path.remove(str(RECIPE))
    with pytest.raises(ValueError, match="MugExpert: task"):
        MugExpert("Lift", "abs_pose")
    assert type(experts.make_expert("MugFlip", "abs_pose")).__name__ == "MugExpert"
