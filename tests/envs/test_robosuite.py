"""RobosuiteEnv and its scripted experts: specs, seeding, abs_pose control, cameras, demos."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import pytest
import torch
from tensordict import TensorDict

pytest.importorskip("robosuite")

from torchrl.envs.utils import check_env_specs  # noqa: E402

from rfmp_rl.envs.robosuite import (  # noqa: E402
    ROBOSUITE_MAX_STEPS,
    ROBOSUITE_OBJECT_DIMS,
    ROBOSUITE_PROPRIO_KEYS,
    RobosuiteEnv,
    make_robosuite_env,
)

EXPERTS = Path(__file__).resolve().parents[2] / "recipes" / "robosuite" / "experts.py"
_spec = importlib.util.spec_from_file_location("robosuite_experts", EXPERTS)
experts = importlib.util.module_from_spec(_spec)
sys.modules[_spec.name] = experts  # the recipe's scripted experts (recipes/ is not a package)
_spec.loader.exec_module(experts)
ExpertPolicy, generate_demos = experts.ExpertPolicy, experts.generate_demos

TASKS = ["Lift", "PickPlaceCan", "NutAssemblySquare"]
SPACES = ["delta", "abs_pose"]
SEEDS = {"Lift": 3, "PickPlaceCan": 4, "NutAssemblySquare": 5}


@pytest.fixture(scope="module")
def envs():
    """One batch-1 env per (task, action space), built once for the module."""
    cache: dict[tuple[str, str], RobosuiteEnv] = {}

    def get(task: str, space: str) -> RobosuiteEnv:
        if (task, space) not in cache:
            cache[task, space] = RobosuiteEnv(task, [1], space)
        return cache[task, space]

    yield get
    for env in cache.values():
        env.close()


def reset(env: RobosuiteEnv, seed: int) -> TensorDict:
    return env.reset(TensorDict({"seed": torch.tensor([seed])}, [1]))


def test_bad_arguments():
    with pytest.raises(ValueError, match="task"):
        RobosuiteEnv("Stack", [1])
    with pytest.raises(ValueError, match="action_space"):
        RobosuiteEnv("Lift", [1], "joint_velocity")
    with pytest.raises(ValueError, match="batch_size"):
        RobosuiteEnv("Lift", [2, 2])
    with pytest.raises(ValueError, match="low_dim_keys"):
        RobosuiteEnv("Lift", [1], low_dim_keys=("robot0_eef_pos", "cube_pos"))


@pytest.mark.slow
def test_proprio_observation_leaves_the_object_out():
    env = RobosuiteEnv("PickPlaceCan", [1], low_dim_keys=ROBOSUITE_PROPRIO_KEYS)
    try:
        check_env_specs(env)
        td = reset(env, 7)
        assert env.obs_dim == 9 and td["observation"].shape == (1, 9)
        expected = torch.cat([td[k] for k in ROBOSUITE_PROPRIO_KEYS], -1)
        assert torch.equal(td["observation"], expected)
        assert td["object"].shape == (1, ROBOSUITE_OBJECT_DIMS["PickPlaceCan"])  # still its own key
    finally:
        env.close()


@pytest.mark.slow
@pytest.mark.parametrize("space", SPACES)
@pytest.mark.parametrize("task", TASKS)
def test_specs_and_shapes(envs, task, space):
    env = envs(task, space)
    check_env_specs(env)
    obj = ROBOSUITE_OBJECT_DIMS[task]
    td = reset(env, 0)
    shapes = {k: tuple(td[k].shape) for k in
              ("robot0_eef_pos", "robot0_eef_quat", "robot0_gripper_qpos", "object", "observation")}
    assert shapes == {"robot0_eef_pos": (1, 3), "robot0_eef_quat": (1, 4),
                      "robot0_gripper_qpos": (1, 2), "object": (1, obj),
                      "observation": (1, 9 + obj)}
    parts = [td[k] for k in ("robot0_eef_pos", "robot0_eef_quat", "robot0_gripper_qpos", "object")]
    torch.testing.assert_close(td["observation"], torch.cat(parts, -1))
    torch.testing.assert_close(td["robot0_eef_quat"].norm(dim=-1), torch.ones(1))
    assert env.action_spec.shape == (1, 7 if space == "delta" else 8)
    assert env.max_steps == ROBOSUITE_MAX_STEPS[task]
    assert not td["done"].any() and td["step_count"].item() == 0


@pytest.mark.slow
@pytest.mark.parametrize("task", TASKS)
def test_same_seed_same_scene(envs, task):
    env = envs(task, "delta")
    first = reset(env, 11)["object"]
    td = reset(env, 12)
    for _ in range(5):  # some history in between must not matter
        td = env.step(td.set("action", torch.ones(1, 7)))["next"]
    again = reset(env, 11)["object"]
    other = reset(env, 12)["object"]
    torch.testing.assert_close(first, again, rtol=0, atol=0)
    assert not torch.allclose(first, other)


@pytest.mark.slow
@pytest.mark.parametrize("task", TASKS)
def test_abs_pose_holds_the_current_pose(envs, task):
    env = envs(task, "abs_pose")
    td = reset(env, 0)
    pos, quat = td["robot0_eef_pos"].clone(), td["robot0_eef_quat"].clone()
    hold = torch.cat([pos, quat, -torch.ones(1, 1)], -1)
    for _ in range(20):
        td = env.step(td.set("action", hold))["next"]
    assert (td["robot0_eef_pos"] - pos).norm() < 0.01
    assert (td["robot0_eef_quat"] * quat).sum().abs() > 0.999
    if task == "Lift":  # and a small offset is reached
        target = pos + torch.tensor([0.04, -0.03, 0.05])
        move = torch.cat([target, -quat, -torch.ones(1, 1)], -1)  # -q: the same rotation
        for _ in range(30):
            td = env.step(td.set("action", move))["next"]
        assert (td["robot0_eef_pos"] - target).norm() < 0.01


@pytest.mark.slow
@pytest.mark.parametrize("space", SPACES)
@pytest.mark.parametrize("task", TASKS)
def test_expert_succeeds(envs, task, space):
    env = envs(task, space)
    env.seeds = [SEEDS[task]]
    out = env.rollout(env.max_steps, ExpertPolicy(env), break_when_any_done=True)
    assert out["next", "success"][0, -1].item()
    assert out["next", "terminated"][0, -1].item() and not out["next", "truncated"].any()
    assert out["next", "reward"][0, -1].item() == 1.0


@pytest.mark.slow
def test_batched_rollout_freezes_finished_instances():
    env = make_robosuite_env("Lift", [2], action_space="abs_pose", seeds=[0, 1])
    out = env.rollout(ROBOSUITE_MAX_STEPS["Lift"], ExpertPolicy(env), break_when_any_done=False,
                      break_when_all_done=True)
    env.close()
    assert out["next", "success"][:, -1, 0].all()
    assert out["obs_window"].shape[-2:] == (2, 19)
    steps = out["next", "step_count"][:, :, 0]
    first = int(steps[:, -1].argmin())  # the instance that finished first stopped counting
    assert steps[first, -1] < out.shape[1] and (steps[first, -1] == steps[first, -2])


@pytest.mark.slow
def test_cameras():
    env = make_robosuite_env("Lift", [1], cameras=True, seeds=[0])
    td = env.reset()
    for cam in ("agentview", "robot0_eye_in_hand"):
        image = td[f"{cam}_image"]
        assert image.shape == (1, 3, 84, 84) and image.dtype == torch.uint8
        assert image.float().std() > 1.0  # a rendered scene, not a blank frame
        assert td[f"{cam}_image_window"].shape == (1, 2, 3, 84, 84)
    td = env.step(td.set("action", torch.zeros(1, 7)))["next"]
    assert td["agentview_image_window"].shape == (1, 2, 3, 84, 84)
    # Upright: the table (bottom rows) is nearer than the sky/wall (top rows) in agentview;
    # compare with the raw OpenGL frame, which is bottom-up.
    raw = env.base_env.sims[0]._get_observations(force_update=True)["agentview_image"]
    flipped = torch.as_tensor(raw[::-1].copy()).permute(2, 0, 1)
    assert torch.equal(flipped, td["agentview_image"][0])
    env.close()


@pytest.mark.slow
def test_generate_demos(tmp_path):
    from rfmp_rl.data.robomimic import read_robomimic

    path = tmp_path / "lift.hdf5"
    info = generate_demos("Lift", 2, "abs_pose", images=True, path=str(path), verbose=False)
    assert info["successes"] == 2 and info["attempts"] >= 2
    assert info["success_rate"] == 2 / info["attempts"]
    episodes, manifest = read_robomimic(path, with_next_obs=True)
    assert manifest.rate_hz == 20.0 and len(episodes) == 2
    env_args = manifest.extra["env_args"]
    assert env_args["env_name"] == "Lift" and env_args["action_space"] == "abs_pose"
    assert env_args["expert"]["seeds"] == info["seeds"]
    ep = episodes[0]
    steps = ep.batch_size[0]
    assert ep["action"].shape == (steps, 8) and ep["done"][-1].item()
    assert ep["obs", "object"].shape == (steps, 10)
    assert ep["obs", "agentview_image"].shape == (steps, 84, 84, 3)
    assert ep["obs", "robot0_eye_in_hand_image"].dtype == torch.uint8
    eef = ep["obs", "robot0_eef_pos"]
    torch.testing.assert_close(ep["next_obs", "robot0_eef_pos"][:-1], eef[1:])


def test_the_experts_run_as_a_script_from_the_repository_root():
    import subprocess

    root = EXPERTS.parents[2]
    result = subprocess.run([sys.executable, "recipes/robosuite/experts.py", "--help"], cwd=root,
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    assert "--task" in result.stdout and "--evaluate N" in result.stdout
