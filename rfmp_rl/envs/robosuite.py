"""robosuite manipulation (Lift, PickPlaceCan, NutAssemblySquare, ToolHang, TwoArmTransport, and
the mug tasks PickPlaceMug and MugFlip of `rfmp_rl.envs.robosuite_mug`) as a batched TorchRL env.

`RobosuiteEnv` holds ``N`` robosuite environments (a Panda arm driven by the ``OSC_POSE``
controller at 20 Hz, robomimic's setting; two opposed Pandas for TwoArmTransport) and steps them
in a loop as one batch ``[N]``; instance ``i`` is reset with seed ``seeds[i]`` (the same seed
gives the same initial scene).

Observations (robomimic's low-dim keys, each its own entry and concatenated in this order into
``observation``; ``low_dim_keys=ROBOSUITE_PROPRIO_KEYS`` leaves ``object`` out of it, robomimic's
image setting):

- ``robot0_eef_pos (N, 3)``: the gripper site position (world frame, m);
- ``robot0_eef_quat (N, 4)``: the hand orientation, a unit quaternion ``xyzw`` (robosuite's
  ``robot0_eef_quat``: the ``robot0_right_hand`` body, as in the robomimic data sets);
- ``robot0_gripper_qpos (N, 2)``: the finger joint positions;
- ``object (N, D_obj)``: the task's object state (`ROBOSUITE_OBJECT_DIMS`), in the order of
  robosuite 1.5's ``object-state``: Lift ``cube_pos (3), cube_quat (4), gripper_to_cube_pos (3)``
  (``cube_pos - eef_pos``); PickPlaceCan / NutAssemblySquare ``obj_to_eef_pos (3),
  obj_to_eef_quat (4), obj_pos (3), obj_quat (4)`` (the object pose in the end-effector frame,
  then in the world frame); PickPlaceMug / MugFlip the same 14 for the mug, then
  ``plate_pos (3)``. It is computed from the simulator at every step, so it is never
  stale (robosuite's own ``object-state`` reports zeros for the relative part right after a
  reset and relative values one step old while the object moves). ToolHang (44) and
  TwoArmTransport (41) use robosuite's ``object-state`` layout as is (ToolHang: base, frame and
  tool, each pose in the end-effector frame then in the world frame, then
  ``frame_is_assembled``, ``tool_on_frame``; TwoArmTransport: payload, trash and lid-handle
  poses, target and trash bin positions, the two success flags, then gripper-to-object vectors),
  its sensors evaluated afresh at every step.

TwoArmTransport has two arms: ``robot1_eef_pos``, ``robot1_eef_quat``, ``robot1_gripper_qpos``
follow robot 0's keys, before ``object`` (robomimic's order; `task_low_dim_keys`).

Quaternion signs: the entries above keep the signs robosuite and MuJoCo give (the hand's body
quaternion is continuous along a trajectory; ``obj_to_eef_quat`` comes from robosuite's
``mat2quat``, which puts ``w >= 0`` and so jumps whenever the relative rotation crosses a
half-turn, as it does for an upright object under a downward hand). `make_robosuite_env`
with ``obs_quaternions`` (`robosuite_obs_quaternions`) makes them canonical in ``observation``,
as the recipe's training data holds them (`rfmp_rl.data.quaternions.canonical_quaternion_signs`).

Cameras (optional): ``agentview_image`` and ``robot0_eye_in_hand_image`` ``(N, 3, H, W) uint8``
(84 x 84 by default), flipped upright as robomimic stores them; TwoArmTransport's are
``shouldercamera0``, ``shouldercamera1``, ``robot0_eye_in_hand``, ``robot1_eye_in_hand``
(`task_cameras`).

Action spaces:

- ``"delta"`` (7-D, robomimic's): OSC_POSE deltas in ``[-1, 1]``: position (3) scaled by
  0.05 m, axis-angle rotation (3) scaled by 0.5 rad (both in the robot base frame), gripper (1,
  ``-1`` open, ``+1`` close).
- ``"abs_pose"`` (8-D, R^3 x S^3 x R^1): the absolute end-effector pose, position (3, world
  frame, the frame of ``robot0_eef_pos``), unit quaternion ``xyzw`` (4, world frame, the frame of
  ``robot0_eef_quat``; it is normalised, ``q`` and ``-q`` are the same command), gripper (1). The
  controller runs with ``input_type="absolute"``, ``input_ref_frame="world"``, which expects the
  grip-site orientation as an axis-angle vector: the env converts (`pose_action_to_osc`).

With two arms (TwoArmTransport) the action is robot 0's followed by robot 1's (14-D delta,
16-D abs_pose; `action_dim`), each in its own robot's base frame for ``"delta"``.

Protocol: at most `ROBOSUITE_MAX_STEPS` steps (Lift 300, Can and Square 500, ToolHang and
TwoArmTransport 700, PickPlaceMug 300, MugFlip 400; ``truncated``),
``success`` is robosuite's ``_check_success()`` and ends the episode (``terminated``); the
reward is the sparse ``float(success)``.

robosuite and MuJoCo are needed (``pip install rfmp_rl[sim]``); they are imported on first use.
Without a display, set ``MUJOCO_GL=egl`` for cameras (done automatically when ``DISPLAY`` is
unset).
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator, Sequence
from typing import Any

import numpy as np
import torch
from tensordict import TensorDict
from torchrl.data import Bounded, Categorical, Composite, Unbounded
from torchrl.envs import TransformedEnv

from rfmp_rl import keys
from rfmp_rl.envs.batch import SimulatorBatchEnv
from rfmp_rl.envs.transforms import QuaternionSigns, observation_windows

__all__ = [
    "RobosuiteEnv",
    "make_robosuite_env",
    "make_robosuite_sim",
    "osc_pose_controller_config",
    "pose_action_to_osc",
    "object_state",
    "object_body_id",
    "ROBOSUITE_TASKS",
    "ROBOSUITE_MUG_TASKS",
    "ROBOSUITE_MAX_STEPS",
    "ROBOSUITE_OBJECT_DIMS",
    "ROBOSUITE_ACTION_DIMS",
    "ROBOSUITE_CAMERAS",
    "ROBOSUITE_LOW_DIM_KEYS",
    "ROBOSUITE_PROPRIO_KEYS",
    "ROBOSUITE_TASK_CAMERAS",
    "TWO_ARM_TASKS",
    "low_dim_key_dims",
    "robosuite_obs_quaternions",
    "task_low_dim_keys",
    "task_proprio_keys",
    "task_cameras",
    "num_arms",
    "action_dim",
    "ROBOSUITE_CONTROL_FREQ",
    "OSC_POS_SCALE",
    "OSC_ROT_SCALE",
]

#: The simulated stand-ins for the paper's real-robot tasks (`rfmp_rl.envs.robosuite_mug`).
ROBOSUITE_MUG_TASKS = ("PickPlaceMug", "MugFlip")
ROBOSUITE_TASKS = ("Lift", "PickPlaceCan", "NutAssemblySquare", "ToolHang", "TwoArmTransport",
                   *ROBOSUITE_MUG_TASKS)
ROBOSUITE_MAX_STEPS = {"Lift": 300, "PickPlaceCan": 500, "NutAssemblySquare": 500,
                       "ToolHang": 700, "TwoArmTransport": 700, "PickPlaceMug": 300,
                       "MugFlip": 400}
ROBOSUITE_OBJECT_DIMS = {"Lift": 10, "PickPlaceCan": 14, "NutAssemblySquare": 14,
                         "ToolHang": 44, "TwoArmTransport": 41, "PickPlaceMug": 17,
                         "MugFlip": 17}
#: Action size per arm (`action_dim` gives a task's whole action).
ROBOSUITE_ACTION_DIMS = {"delta": 7, "abs_pose": 8}
ROBOSUITE_CAMERAS = ("agentview", "robot0_eye_in_hand")
#: Tasks whose cameras are not `ROBOSUITE_CAMERAS` (robomimic's image setting of each).
ROBOSUITE_TASK_CAMERAS = {
    "TwoArmTransport": ("shouldercamera0", "shouldercamera1", "robot0_eye_in_hand",
                        "robot1_eye_in_hand"),
}
#: Tasks with two Pandas (``robots=["Panda", "Panda"]``, robosuite's opposed configuration).
TWO_ARM_TASKS = ("TwoArmTransport",)
ROBOSUITE_LOW_DIM_KEYS = ("robot0_eef_pos", "robot0_eef_quat", "robot0_gripper_qpos", "object")
#: robomimic's image observations keep only these low-dim keys (no object state).
ROBOSUITE_PROPRIO_KEYS = ROBOSUITE_LOW_DIM_KEYS[:3]
ROBOSUITE_CONTROL_FREQ = 20
_PROPRIO_DIMS = {"eef_pos": 3, "eef_quat": 4, "gripper_qpos": 2}


def num_arms(task: str) -> int:
    """Number of Panda arms of ``task`` (2 for TwoArmTransport, else 1)."""
    return 2 if task in TWO_ARM_TASKS else 1


def task_proprio_keys(task: str) -> tuple[str, ...]:
    """The proprioceptive low-dim keys of ``task``: eef position, quaternion and gripper of each
    arm (`ROBOSUITE_PROPRIO_KEYS` for one arm).

    Example:
        >>> task_proprio_keys("TwoArmTransport")[3:]
        ('robot1_eef_pos', 'robot1_eef_quat', 'robot1_gripper_qpos')
    """
    return tuple(f"robot{r}_{k}" for r in range(num_arms(task)) for k in _PROPRIO_DIMS)


def task_low_dim_keys(task: str) -> tuple[str, ...]:
    """robomimic's low-dim keys of ``task``: `task_proprio_keys` then ``object``
    (`ROBOSUITE_LOW_DIM_KEYS` for one arm)."""
    return (*task_proprio_keys(task), "object")


def task_cameras(task: str) -> tuple[str, ...]:
    """The cameras of ``task`` (`ROBOSUITE_TASK_CAMERAS`, else `ROBOSUITE_CAMERAS`)."""
    return ROBOSUITE_TASK_CAMERAS.get(task, ROBOSUITE_CAMERAS)


def action_dim(task: str, action_space: str) -> int:
    """Size of ``task``'s action: `ROBOSUITE_ACTION_DIMS` per arm times `num_arms`.

    Example:
        >>> action_dim("TwoArmTransport", "delta")
        14
    """
    return ROBOSUITE_ACTION_DIMS[action_space] * num_arms(task)


def low_dim_key_dims(task: str) -> dict[str, int]:
    """Size of each low-dim observation key of ``task``, in `task_low_dim_keys` order."""
    dims = {k: _PROPRIO_DIMS[k.split("_", 1)[1]] for k in task_proprio_keys(task)}
    dims["object"] = ROBOSUITE_OBJECT_DIMS[task]
    return dims


#: References of the observed quaternions (xyzw; `robosuite_obs_quaternions`): the Panda's hand
#: points down at reset, a half-turn about world x, and so does an upright object seen from it;
#: objects in the world frame start upright (a turn about z from the identity).
_HALF_TURN_X = (1.0, 0.0, 0.0, 0.0)
_IDENTITY = (0.0, 0.0, 0.0, 1.0)
_OBJECT_QUATERNIONS = {  # offset in the object state -> reference
    "Lift": {3: _IDENTITY},  # cube_quat
    "PickPlaceCan": {3: _HALF_TURN_X, 10: _IDENTITY},  # obj_to_eef_quat, obj_quat
    "NutAssemblySquare": {3: _HALF_TURN_X, 10: _IDENTITY},
    "PickPlaceMug": {3: _HALF_TURN_X, 10: _IDENTITY},  # then the plate position
    "MugFlip": {3: _HALF_TURN_X, 10: _IDENTITY},
}


def robosuite_obs_quaternions(
    task: str, low_dim_keys: Sequence[str] | None = None
) -> list[dict[str, list]]:
    """The quaternions of ``observation`` (the ``low_dim_keys`` concatenated) and the reference
    whose hemisphere each stream starts in (`rfmp_rl.data.quaternions.ObservedQuaternion`):
    each arm's ``robot<k>_eef_quat`` (reference: the hand pointing down, ``x = 1``; robosuite's
    hand starts within a few degrees of it, so the first frame is far from the boundary, where
    ``w >= 0`` would be on it) and the object state's quaternions (``low_dim_keys``: default
    `task_low_dim_keys`). ToolHang's and TwoArmTransport's object states keep robosuite's signs:
    their layouts hold several relative quaternions not yet mapped here.

    Example:
        >>> [q["columns"] for q in robosuite_obs_quaternions("PickPlaceCan")]
        [[3, 7], [12, 16], [19, 23]]
        >>> robosuite_obs_quaternions("Lift", ROBOSUITE_PROPRIO_KEYS)
        [{'columns': [3, 7], 'reference': [1.0, 0.0, 0.0, 0.0]}]
    """
    if task not in ROBOSUITE_TASKS:
        raise ValueError(f"robosuite task must be one of {ROBOSUITE_TASKS}, got {task!r}")
    dims, out, start = low_dim_key_dims(task), [], 0
    for key in task_low_dim_keys(task) if low_dim_keys is None else low_dim_keys:
        if key.endswith("_eef_quat"):
            out.append({"columns": [start, start + 4], "reference": list(_HALF_TURN_X)})
        elif key == "object":
            for offset, ref in _OBJECT_QUATERNIONS.get(task, {}).items():
                out.append({"columns": [start + offset, start + offset + 4],
                            "reference": list(ref)})
        start += dims[key]
    return out


#: OSC_POSE delta output limits per unit action: metres and radians.
OSC_POS_SCALE = 0.05
OSC_ROT_SCALE = 0.5
# Bounds advertised by the abs_pose action spec (world frame, m); commands are not clipped.
_POS_LOW = (-1.0, -1.0, 0.5)
_POS_HIGH = (1.0, 1.0, 1.5)


def _check(task: str, action_space: str) -> None:
    if task not in ROBOSUITE_TASKS:
        raise ValueError(f"robosuite task must be one of {ROBOSUITE_TASKS}, got {task!r}")
    _check_action_space(action_space)


def _check_action_space(action_space: str) -> None:
    if action_space not in ROBOSUITE_ACTION_DIMS:
        raise ValueError(
            f"robosuite action_space must be 'delta' or 'abs_pose', got {action_space!r}"
        )


def _robosuite() -> Any:
    if "MUJOCO_GL" not in os.environ and not os.environ.get("DISPLAY"):
        os.environ["MUJOCO_GL"] = "egl"  # headless offscreen rendering
    try:
        import robosuite
    except ImportError as exc:  # pragma: no cover - robosuite ships with rfmp_rl[sim]
        raise ImportError(
            "robosuite envs need robosuite: pip install 'rfmp_rl[sim]' (robosuite==1.5.1)"
        ) from exc
    return robosuite


@contextlib.contextmanager
def _global_numpy_seed(seed: int) -> Iterator[None]:
    """Seed NumPy's global RNG (robosuite samples scenes from it), restore it on exit."""
    if not 0 <= int(seed) < 2**32:
        raise ValueError(f"robosuite seeds must be in [0, 2**32), got {seed}")
    state = np.random.get_state()  # noqa: NPY002 - robosuite draws from the global RNG
    np.random.seed(int(seed))  # noqa: NPY002
    try:
        yield
    finally:
        np.random.set_state(state)  # noqa: NPY002


def osc_pose_controller_config(action_space: str = "delta") -> dict[str, Any]:
    """robosuite 1.5 composite controller config: ``BASIC`` with one OSC_POSE arm (``right``)
    (two-arm tasks give it to both Pandas).

    ``"delta"`` keeps robosuite's defaults (robomimic's): ``input_type="delta"``,
    ``input_ref_frame="base"``, inputs in ``[-1, 1]`` scaled to 0.05 m / 0.5 rad, kp 150,
    critically damped. ``"abs_pose"`` sets ``input_type="absolute"`` and
    ``input_ref_frame="world"``: the arm action is then the grip-site goal, position (3) and
    axis-angle rotation (3), in the world frame (neither clipped nor scaled).

    Example::

        cfg = osc_pose_controller_config("abs_pose")
        cfg["body_parts"]["right"]["input_type"]  # 'absolute'
    """
    _check_action_space(action_space)
    suite = _robosuite()
    cfg = suite.load_composite_controller_config(controller="BASIC")
    arm = dict(cfg["body_parts"]["right"])
    if action_space == "abs_pose":
        arm.update(input_type="absolute", input_ref_frame="world")
    cfg["body_parts"] = {"right": arm}  # a Panda has no left arm, torso, head, base or legs
    return cfg


def make_robosuite_sim(
    task: str,
    action_space: str = "delta",
    *,
    cameras: Sequence[str] = (),
    image_size: int = 84,
    hard_reset: bool = False,
    model_seed: int = 0,
) -> Any:
    """One robosuite env (Panda, OSC_POSE, 20 Hz; two opposed Pandas for `TWO_ARM_TASKS`) as
    `RobosuiteEnv` uses it.

    The global NumPy RNG is seeded with ``model_seed`` while the model is built (Lift draws its
    cube size from it) and restored afterwards, so every instance holds the same model.
    ``ignore_done=True``: the step limit is `RobosuiteEnv`'s.

    Example::

        sim = make_robosuite_sim("Lift", "delta")
        sim.reset()["robot0_eef_pos"].shape  # (3,)
    """
    _check(task, action_space)
    suite = _robosuite()
    cameras = list(cameras)
    for cam in cameras:
        if cam not in task_cameras(task):
            raise ValueError(f"robosuite {task} camera must be one of {task_cameras(task)}, "
                             f"got {cam!r}")
    if task in ROBOSUITE_MUG_TASKS:
        import rfmp_rl.envs.robosuite_mug  # noqa: F401 - registers the mug tasks with robosuite
    with _global_numpy_seed(model_seed):
        return suite.make(
            task,
            robots="Panda" if num_arms(task) == 1 else ["Panda"] * num_arms(task),
            controller_configs=osc_pose_controller_config(action_space),
            has_renderer=False,
            has_offscreen_renderer=bool(cameras),
            use_camera_obs=bool(cameras),
            camera_names=cameras or task_cameras(task)[0],
            camera_heights=int(image_size),
            camera_widths=int(image_size),
            control_freq=ROBOSUITE_CONTROL_FREQ,
            reward_shaping=False,
            ignore_done=True,
            hard_reset=hard_reset,
        )


def pose_action_to_osc(action: np.ndarray, hand_to_site: np.ndarray) -> np.ndarray:
    """8-D ``abs_pose`` action -> the 7-D absolute OSC_POSE command robosuite expects.

    Args:
        action: ``(8,)`` position (3), hand quaternion ``xyzw`` (4, any norm > 0), gripper (1).
        hand_to_site: ``(3, 3)`` the grip site's orientation in the hand frame
            (``R_hand^T R_site``; a constant of the robot, a 90 degree turn about z for the Panda).

    Returns:
        ``(7,)`` position (3), grip-site axis-angle rotation (3), gripper (1).

    Example:
        >>> a = np.array([0.1, 0.0, 1.0, 1.0, 0.0, 0.0, 0.0, -1.0])  # hand turned pi about x
        >>> np.round(pose_action_to_osc(a, np.eye(3)), 4).tolist()
        [0.1, 0.0, 1.0, 3.1416, 0.0, 0.0, -1.0]
    """
    from scipy.spatial.transform import Rotation

    action = np.asarray(action, dtype=np.float64)
    quat = action[3:7]
    norm = float(np.linalg.norm(quat))
    if not np.isfinite(norm) or norm < 1e-8:
        raise ValueError(f"abs_pose action has no valid quaternion: {quat.tolist()}")
    site = Rotation.from_quat(quat / norm).as_matrix() @ hand_to_site
    rotvec = Rotation.from_matrix(site).as_rotvec()
    return np.concatenate([action[:3], rotvec, action[7:8]])


def object_body_id(sim_env: Any, task: str) -> int:
    """MuJoCo body id of the task's object (the cube, the can, the square nut, the tool of
    ToolHang, the payload of TwoArmTransport, the mug).

    Example::

        sim = make_robosuite_sim("Lift")
        sim.sim.data.body_xpos[object_body_id(sim, "Lift")]  # the cube position
    """
    if task == "Lift":
        obj = sim_env.cube
    elif task == "PickPlaceCan":
        obj = sim_env.objects[sim_env.object_id]
    elif task == "ToolHang":
        obj = sim_env.tool
    elif task == "TwoArmTransport":
        obj = sim_env.transport.payload
    elif task in ROBOSUITE_MUG_TASKS:
        obj = sim_env.mug
    else:
        obj = sim_env.nuts[sim_env.nut_id]
    return sim_env.sim.model.body_name2id(obj.root_body)


def object_state(sim_env: Any, task: str) -> np.ndarray:
    """The ``object`` observation of a robosuite env, computed from its current sim state.

    Layout as robosuite 1.5's ``object-state`` (see the module docstring), float64.

    Example::

        sim = make_robosuite_sim("PickPlaceCan")
        sim.reset()
        object_state(sim, "PickPlaceCan").shape  # (14,)
    """
    if task in ("ToolHang", "TwoArmTransport"):
        return _fresh_object_state(sim_env)
    data = sim_env.sim.data
    body = object_body_id(sim_env, task)
    pos = np.array(data.body_xpos[body], dtype=np.float64)
    quat = np.array(data.body_xquat[body], dtype=np.float64)[[1, 2, 3, 0]]  # wxyz -> xyzw
    robot = sim_env.robots[0]
    eef_pos = np.array(data.site_xpos[robot.eef_site_id["right"]], dtype=np.float64)
    if task == "Lift":
        return np.concatenate([pos, quat, pos - eef_pos])
    hand = np.array(data.get_body_xmat(robot.robot_model.eef_name["right"]), dtype=np.float64)
    rel_pos = hand.T @ (pos - eef_pos)
    from robosuite.utils.transform_utils import mat2quat, quat2mat

    rel_quat = mat2quat(hand.T @ quat2mat(quat))  # xyzw, robosuite's sign convention
    if task in ROBOSUITE_MUG_TASKS:  # the plate moves between episodes: the policy must see it
        plate = np.array(data.body_xpos[sim_env.plate_body_id], dtype=np.float64)
        return np.concatenate([rel_pos, rel_quat, pos, quat, plate])
    return np.concatenate([rel_pos, rel_quat, pos, quat])


def _fresh_object_state(sim_env: Any) -> np.ndarray:
    """robosuite's ``object-state`` recomputed from the current sim state.

    robosuite evaluates relative sensors before the absolute ones they read in the same step
    (so they lag one step, and are zero right after a reset); two passes over the sensors with
    a fresh cache give every entry at the current state. Camera sensors (modality ``image``)
    are left out: no object entry reads them, and each would render its camera again.
    """
    observables = [o for o in sim_env._observables.values()
                   if o.is_enabled() and o.modality != "image"]
    cache: dict[str, Any] = {}
    for _ in range(2):
        for obs in observables:
            cache[obs.name] = np.array(obs._sensor(cache))
    parts = [np.asarray(cache[o.name], dtype=np.float64).reshape(-1)
             for o in observables if o.is_active() and o.modality == "object"]
    return np.concatenate(parts)


class RobosuiteEnv(SimulatorBatchEnv):
    """A batch of robosuite manipulation envs (Panda, OSC_POSE, 20 Hz) as one TorchRL env.

    Args:
        task: one of `ROBOSUITE_TASKS`.
        batch_size: ``[N]``, the number of robosuite envs.
        action_space: ``"delta"`` (7-D per arm) or ``"abs_pose"`` (8-D per arm); see the module
            docstring.
        cameras: camera names among `task_cameras` of the task, or ``True`` for all of them;
            each adds an ``<name>_image (N, 3, H, W) uint8`` entry.
        image_size: camera height and width.
        low_dim_keys: the low-dim keys concatenated into ``observation``, in this order (default
            all of the task's, `task_low_dim_keys`; `task_proprio_keys` for robomimic's image
            setting, which leaves the object state out). Every key keeps its own entry either
            way. Default ``None``: all.
        max_steps: episode limit (default `ROBOSUITE_MAX_STEPS` of the task).
        seeds: ``N`` reset seeds (default ``100000 + i``, disjoint from the demo seeds of
            `generate_demos` of recipes/robosuite/experts.py); a ``seed`` entry ``(N,)`` in the
            reset TensorDict overrides them. Resets seed NumPy's global RNG (robosuite's object
            placement and arm initialisation noise draw from it) and restore it afterwards.
        hard_reset: rebuild the MuJoCo model at every reset (robosuite's default; slower). With
            ``False`` the model is built once (Lift's cube size then stays fixed).
        device: where the TensorDicts live.

    Output keys: ``observation``, the task's low-dim keys, camera images, ``success``,
    ``step_count``, ``reward``, ``done``/``terminated``/``truncated``. A finished instance is
    frozen: later actions are ignored, it keeps reporting its last observation and ``done``
    (with reward 0), so ``rollout(..., break_when_any_done=False, break_when_all_done=True)``
    runs the whole batch. A ``_reset`` mask resets only the instances it selects.

    The robosuite envs are ``env.sims``; ``env.hand_to_site`` is the constant rotation between
    the hand frame of ``robot0_eef_quat`` and the grip site the controller tracks.

    Example::

        env = RobosuiteEnv("Lift", [2], action_space="abs_pose", seeds=[0, 1])
        td = env.reset()
        td["observation"].shape  # torch.Size([2, 19])
        out = env.rollout(3, break_when_any_done=False)
    """

    def __init__(
        self,
        task: str,
        batch_size: Sequence[int] | torch.Size,
        action_space: str = "delta",
        *,
        cameras: Sequence[str] | bool = (),
        image_size: int = 84,
        low_dim_keys: Sequence[str] | None = None,
        max_steps: int | None = None,
        seeds: Sequence[int] | None = None,
        hard_reset: bool = False,
        device: str | torch.device = "cpu",
    ) -> None:
        _check(task, action_space)
        batch_size = torch.Size(batch_size)
        if len(batch_size) != 1:
            raise ValueError(f"RobosuiteEnv: batch_size must be [N], got {list(batch_size)}")
        super().__init__(batch_size=batch_size, device=device)
        if cameras is True:
            cameras = task_cameras(task)
        elif cameras is False:
            cameras = ()
        self.task, self.action_space_name = task, action_space
        self.cameras = tuple(cameras)
        self.all_low_dim_keys = task_low_dim_keys(task)
        if low_dim_keys is None:
            low_dim_keys = self.all_low_dim_keys
        unknown = [k for k in low_dim_keys if k not in self.all_low_dim_keys]
        if unknown or not low_dim_keys:
            raise ValueError(f"RobosuiteEnv: low_dim_keys must be a non-empty subset of "
                             f"{self.all_low_dim_keys} ({task}), got {list(low_dim_keys)}")
        self.low_dim_keys = tuple(low_dim_keys)
        self.image_size = int(image_size)
        self.max_steps = int(ROBOSUITE_MAX_STEPS[task] if max_steps is None else max_steps)
        n = batch_size[0]
        self.seeds = list(range(100000, 100000 + n)) if seeds is None else [int(s) for s in seeds]
        if len(self.seeds) != n:
            raise ValueError(f"RobosuiteEnv: {len(self.seeds)} seeds for a batch of {n}")
        self.sims = [
            make_robosuite_sim(task, action_space, cameras=self.cameras,
                               image_size=self.image_size, hard_reset=hard_reset)
            for _ in range(n)
        ]
        robot = self.sims[0].robots[0]
        data = self.sims[0].sim.data
        hand = np.array(data.get_body_xmat(robot.robot_model.eef_name["right"]))
        site = np.array(data.site_xmat[robot.eef_site_id["right"]]).reshape(3, 3)
        self.hand_to_site = np.round(hand.T @ site, 6)  # rigid: the gripper is welded to the hand
        self._last: list[dict[str, np.ndarray]] = [{} for _ in range(n)]
        self._count = np.zeros(n, dtype=np.int64)
        self._success = np.zeros(n, dtype=bool)
        self._reward = np.zeros(n)
        self._truncated = np.zeros(n, dtype=bool)
        self._make_specs()

    @property
    def obs_dim(self) -> int:
        """Size of ``observation``: the sizes of ``low_dim_keys`` (all of them: 3 + 4 + 2 per arm
        + the object state)."""
        return sum(low_dim_key_dims(self.task)[k] for k in self.low_dim_keys)

    # ----- specs -------------------------------------------------------------------------------
    def _make_specs(self) -> None:
        batch, dev = self.batch_size, self.device
        f32 = {"dtype": torch.float32, "device": dev}
        dims = low_dim_key_dims(self.task)
        spec = {keys.OBSERVATION: Unbounded((*batch, self.obs_dim), **f32)}
        spec.update({k: Unbounded((*batch, d), **f32) for k, d in dims.items()})
        for cam in self.cameras:
            spec[f"{cam}_image"] = Bounded(
                0, 255, (*batch, 3, self.image_size, self.image_size), dtype=torch.uint8,
                device=dev,
            )
        spec["success"] = Categorical(2, (*batch, 1), dtype=torch.bool, device=dev)
        spec["step_count"] = Unbounded((*batch, 1), dtype=torch.int64, device=dev)
        self.observation_spec = Composite(spec, shape=batch, device=dev)
        self.state_spec = Composite(
            seed=Unbounded((*batch,), dtype=torch.int64, device=dev), shape=batch, device=dev
        )
        arms, dim = num_arms(self.task), action_dim(self.task, self.action_space_name)
        if self.action_space_name == "delta":
            self.action_spec = Bounded(-1.0, 1.0, (*batch, dim), **f32)
        else:
            low = torch.tensor([*_POS_LOW, -1.0, -1.0, -1.0, -1.0, -1.0] * arms)
            high = torch.tensor([*_POS_HIGH, 1.0, 1.0, 1.0, 1.0, 1.0] * arms)
            self.action_spec = Bounded(low.expand(*batch, dim), high.expand(*batch, dim), **f32)
        self.reward_spec = Unbounded((*batch, 1), **f32)
        self.full_done_spec = Composite(
            {
                name: Categorical(2, (*batch, 1), dtype=torch.bool, device=dev)
                for name in ("done", "terminated", "truncated")
            },
            shape=batch,
            device=dev,
        )

    # ----- observation assembly ---------------------------------------------------------------
    def _observe(self, i: int, sim_obs: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        out = {k: np.asarray(sim_obs[k], dtype=np.float64) for k in task_proprio_keys(self.task)}
        out["object"] = object_state(self.sims[i], self.task)
        out[keys.OBSERVATION] = np.concatenate([out[k] for k in self.low_dim_keys])
        for cam in self.cameras:
            image = np.asarray(sim_obs[f"{cam}_image"])[::-1]  # OpenGL rows are bottom-up
            out[f"{cam}_image"] = np.ascontiguousarray(image.transpose(2, 0, 1))
        return out

    def _pack(self) -> TensorDict:
        dev = self.device
        f32 = {"dtype": torch.float32, "device": dev}
        data: dict[str, torch.Tensor] = {}
        for key in (keys.OBSERVATION, *self.all_low_dim_keys):
            data[key] = torch.as_tensor(np.stack([o[key] for o in self._last]), **f32)
        for cam in self.cameras:
            key = f"{cam}_image"
            data[key] = torch.as_tensor(np.stack([o[key] for o in self._last]), device=dev)
        data.update(self._done_entries(self._success))
        return TensorDict(data, batch_size=self.batch_size, device=dev)

    def _osc_action(self, action: np.ndarray) -> np.ndarray:
        if self.action_space_name == "delta":
            return action
        return np.concatenate([pose_action_to_osc(a, self.hand_to_site)
                               for a in np.split(action, num_arms(self.task))])

    # ----- dynamics (`SimulatorBatchEnv`) -------------------------------------------------------
    def _done(self, i: int) -> bool:
        return bool(self._success[i])

    def _reset_instance(self, i: int) -> None:
        with _global_numpy_seed(self.seeds[i]):
            sim_obs = self.sims[i].reset()
        self._success[i] = False
        self._last[i] = self._observe(i, sim_obs)

    def _step_instance(self, i: int, action: np.ndarray) -> None:
        sim = self.sims[i]
        sim_obs, _, _, _ = sim.step(self._osc_action(action))
        self._success[i] = bool(sim._check_success())
        self._reward[i] = float(self._success[i])
        self._last[i] = self._observe(i, sim_obs)


def make_robosuite_env(
    task: str,
    batch_size: Sequence[int] | torch.Size,
    *,
    obs_horizon: int = 2,
    obs_quaternions: Sequence[dict] | None = None,
    **env_kwargs,
) -> TransformedEnv:
    """`RobosuiteEnv` with the observation windows an RFMP policy reads.

    ``obs_quaternions`` (``ModelConfig.obs_quaternions``, e.g. `robosuite_obs_quaternions`):
    `QuaternionSigns` makes those columns of ``observation`` canonical first, frame by frame
    (None: the raw signs, what models trained before the rule read).

    ``obs_window (N, 2, D)`` = ``[o^{s-T_o}, o^{s-1}]``, the oldest and the latest of the last
    ``obs_horizon`` (T_o) observations (after a reset the first is repeated); each camera adds
    ``<name>_image_window (N, 2, 3, H, W)`` the same way; with T_o > 2 ``obs_gap (N,)`` = T_o
    (`rfmp_rl.envs.observation_windows`). ``InitTracker`` writes ``is_init`` for
    ``MultiStepActorWrapper``.

    Example::

        env = make_robosuite_env("NutAssemblySquare", [2], cameras=True)
        td = env.reset()
        td["obs_window"].shape  # torch.Size([2, 2, 23])
        td["agentview_image_window"].shape  # torch.Size([2, 2, 3, 84, 84])
    """
    env = RobosuiteEnv(task, batch_size, **env_kwargs)
    cameras = {f"{cam}_image": f"{cam}_image_window" for cam in env.cameras}
    windows = observation_windows(obs_horizon, {keys.OBSERVATION: keys.OBS_WINDOW}, cameras)
    if obs_quaternions:
        windows.insert(0, QuaternionSigns(obs_quaternions))
    return TransformedEnv(env, windows)
