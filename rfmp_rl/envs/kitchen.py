"""Franka Kitchen (gymnasium-robotics ``FrankaKitchen-v1``) as a batched TorchRL env with an
end-effector pose action on R^3 x S^3 x R^2.

`FrankaKitchenEnv` holds ``N`` kitchen envs (gymnasium-robotics 1.4.2's ``KitchenEnv``, the
tasks microwave, kettle, light switch and slide cabinet, 12.5 Hz) and steps them as one batch
``[N]``; instance ``i`` is reset with seed ``seeds[i]``.

Actions:

- ``"ee_pose"`` (9-D, R^3 x S^3 x R^2, the paper's Franka Kitchen action): the target pose of
  the ``end_effector`` site (between the fingertips), position (3, world frame, m), unit
  quaternion ``xyzw`` (4, world frame; normalised by the env, ``q`` and ``-q`` are the same
  command), and the two finger joint positions (2, m, in ``[0, 0.04]``). A damped-least-squares
  controller (`DLSController`) turns it into the kitchen env's native joint-velocity action at
  every step.
- ``"joint_velocity"`` (9-D, the native action of ``FrankaKitchen-v1`` and of Minari's
  ``D4RL/kitchen`` data sets): joint velocities in ``[-1, 1]`` (scaled by 2 rad/s, m/s).

Controller (`DLSController`): the kitchen env turns a velocity ``v`` into the position target
``q_obs + v dt`` of MuJoCo position servos (``dt = 0.08`` s, ``kp`` 870 / 120, joint damping 100 /
10, no gravity compensation). One DLS step ``dq = J^T (J J^T + lambda^2 I)^{-1} e`` on the
site Jacobian of the true state (``e``: the position error and the rotation vector of
``R_target R^T``, capped at 6 cm and 0.35 rad per step; joints that would cross a limit are
held at it and the rest re-solved), a null-space pull towards the reset posture, the step
scaled to at most 0.1 rad per joint, and feed-forward terms for gravity (``qfrc_bias / kp``)
and joint damping (``damping * dq / (dt kp)``) give the servo target.

Tracking error (`measure_tracking_error`: the achieved site pose one step after each command,
against that command; seeds 0-9, no contact), in `TRACKING_ERROR`:

============================================  ==========  =========  ===========  ==========
`tracking_test_trajectory`                    pos mean    pos max    rot mean     rot max
============================================  ==========  =========  ===========  ==========
10 s figure-eight (10 x 6 cm, +-30 deg yaw)   1.1 mm      4.4 mm     0.22 deg     0.51 deg
5 s figure-eight (twice as fast)              1.6 mm      5.5 mm     0.45 deg     1.0 deg
============================================  ==========  =========  ===========  ==========

(means over the seeds of each run's mean and maximum; the worst single step over all runs:
11 mm / 12.7 mm, 0.52 / 1.2 deg). The fingers track to within 2 mm (4 mm at double speed). At
the scripted expert's speeds (up to 3.5 cm per step) the site trails its command: one step
after a command the gap is 3 cm median, 21 cm at the 90th percentile (the large
reorientations between subtasks, where the 0.1 rad joint step cap binds;
recipes/kitchen/README.md).

Observations (each its own entry, concatenated in this order into ``observation``, 66-D):

- ``robot_qpos (N, 9)``, ``robot_qvel (N, 9)``: the arm and finger joints as the kitchen env
  reports them (with its observation noise, ``robot_noise_ratio=0.01``);
- ``ee_pos (N, 3)``, ``ee_quat (N, 4)``: the ``end_effector`` site pose by forward kinematics of
  ``robot_qpos`` (`KitchenKinematics`), the quaternion ``xyzw`` with the sign rule of
  `rfmp_rl.data.quaternions` (``w >= 0`` at reset, then continuous along the episode);
- ``object (N, 41)``: the kitchen's object joint positions (21) and velocities (20), as the
  kitchen env reports them.

The first 9 + 9 and the last 41 values are the kitchen env's 59-D ``observation`` (the
``observation/observation`` entry of Minari's ``D4RL/kitchen`` data sets), so data sets
recorded from the native env map onto this layout (`kitchen_episodes`).

Protocol: at most `KITCHEN_MAX_STEPS` steps (280, the env's default; ``truncated``). A subtask
is complete once its joints come within 0.3 of the goal (the kitchen env's rule) and stays
complete; ``("subtasks", <name>)`` (`KITCHEN_SUBTASK_KEYS`) holds the flags, ``success`` is all
four and ends the episode (``terminated``); ``reward`` is the kitchen env's: the number of
subtasks completed at that step.

Initial states: the kitchen env always resets to the same configuration; with
``init_noise > 0`` the seven arm joints are offset by ``U(-init_noise, init_noise)`` rad
(default 0.1) and the kettle by ``U(-kettle_noise, kettle_noise)`` m in x and y (default 0.02),
drawn from the seed.

gymnasium-robotics and MuJoCo are needed (``pip install rfmp_rl[sim]``), and Minari for the
recipe's dataset writer; they are imported on first use.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.data import Bounded, Categorical, Composite, Unbounded
from torchrl.envs import TransformedEnv

from rfmp_rl import keys
from rfmp_rl.envs.batch import SimulatorBatchEnv
from rfmp_rl.envs.transforms import observation_windows

__all__ = [
    "FrankaKitchenEnv",
    "KitchenInstance",
    "KitchenKinematics",
    "DLSController",
    "make_kitchen_env",
    "make_kitchen_sim",
    "kitchen_episodes",
    "measure_tracking_error",
    "tracking_test_trajectory",
    "quat_xyzw_from_mat",
    "KITCHEN_TASKS",
    "KITCHEN_SUBTASK_KEYS",
    "KITCHEN_MAX_STEPS",
    "KITCHEN_ACTION_DIMS",
    "KITCHEN_OBS_KEYS",
    "KITCHEN_OBS_DIMS",
    "KITCHEN_CONTROL_FREQ",
    "KITCHEN_EE_SITE",
    "TRACKING_ERROR",
]

#: The four subtasks, in the order the paper (and D4RL's ``kitchen-complete``) performs them.
KITCHEN_TASKS = ("microwave", "kettle", "light switch", "slide cabinet")
#: TensorDict names of the subtask flags (``("subtasks", name)``), in `KITCHEN_TASKS` order.
KITCHEN_SUBTASK_KEYS = ("microwave", "kettle", "light_switch", "slide_cabinet")
KITCHEN_MAX_STEPS = 280
KITCHEN_ACTION_DIMS = {"ee_pose": 9, "joint_velocity": 9}
KITCHEN_OBS_KEYS = ("robot_qpos", "robot_qvel", "ee_pos", "ee_quat", "object")
KITCHEN_OBS_DIMS = {"robot_qpos": 9, "robot_qvel": 9, "ee_pos": 3, "ee_quat": 4, "object": 41}
KITCHEN_CONTROL_FREQ = 12.5
KITCHEN_EE_SITE = "end_effector"
#: Tracking error of `DLSController` on the 10 s `tracking_test_trajectory`
#: (`measure_tracking_error(seed, steps=125)`, seeds 0-9, means of the per-run mean and maximum
#: over steps 10-124): position in mm, orientation in degrees (module docstring).
TRACKING_ERROR = {"pos_mm_mean": 1.1, "pos_mm_max": 4.4, "rot_deg_mean": 0.22,
                  "rot_deg_max": 0.51}

_FINGER_MAX = 0.04
# Bounds advertised by the ee_pose action spec (world frame, m); commands are not clipped.
_POS_LOW = (-1.5, -0.5, 1.0)
_POS_HIGH = (1.0, 1.5, 3.0)


def _check_action_space(action_space: str) -> None:
    if action_space not in KITCHEN_ACTION_DIMS:
        raise ValueError(f"kitchen action_space must be one of {tuple(KITCHEN_ACTION_DIMS)}, "
                         f"got {action_space!r}")


def quat_xyzw_from_mat(mat: np.ndarray) -> np.ndarray:
    """Unit quaternion ``xyzw`` of a rotation matrix (``(3, 3)`` or MuJoCo's flat ``(9,)``).

    Example:
        >>> quat_xyzw_from_mat(np.eye(3)).tolist()
        [0.0, 0.0, 0.0, 1.0]
    """
    import mujoco

    wxyz = np.zeros(4)
    mujoco.mju_mat2Quat(wxyz, np.asarray(mat, dtype=np.float64).reshape(9))
    return wxyz[[1, 2, 3, 0]]


def _mat_from_xyzw(quat: np.ndarray) -> np.ndarray:
    import mujoco

    q = np.asarray(quat, dtype=np.float64)
    norm = float(np.linalg.norm(q))
    if not np.isfinite(norm) or norm < 1e-8:
        raise ValueError(f"ee_pose action has no valid quaternion: {q.tolist()}")
    mat = np.zeros(9)
    mujoco.mju_quat2Mat(mat, (q / norm)[[3, 0, 1, 2]])
    return mat.reshape(3, 3)


def _rotvec(mat: np.ndarray) -> np.ndarray:
    """Rotation vector (axis * angle) of a rotation matrix."""
    import mujoco

    wxyz = np.zeros(4)
    mujoco.mju_mat2Quat(wxyz, np.ascontiguousarray(mat).reshape(9))
    vec = np.zeros(3)
    mujoco.mju_quat2Vel(vec, wxyz, 1.0)
    return vec


def make_kitchen_sim(**kwargs: Any) -> Any:
    """One gymnasium-robotics ``KitchenEnv`` with the four tasks (`KITCHEN_TASKS`).

    The env is built directly (not through ``gym.make``): the step limit is
    `FrankaKitchenEnv`'s. ``kwargs`` go to ``KitchenEnv`` (e.g. ``robot_noise_ratio``).

    Example::

        sim = make_kitchen_sim()
        obs, info = sim.reset(seed=0)
        obs["observation"].shape  # (59,)
    """
    try:
        from gymnasium_robotics.envs.franka_kitchen.kitchen_env import KitchenEnv
    except ImportError as exc:  # pragma: no cover - ships with rfmp_rl[sim]
        raise ImportError("Franka Kitchen needs gymnasium-robotics: pip install "
                          "'rfmp_rl[sim]' (gymnasium-robotics==1.4.2)") from exc
    kwargs.setdefault("tasks_to_complete", list(KITCHEN_TASKS))
    return KitchenEnv(**kwargs)


class KitchenKinematics:
    """Forward kinematics of the kitchen's Franka on a private ``MjData`` (the sim is untouched).

    Args:
        model: the kitchen's ``mujoco.MjModel``.

    Example::

        fk = KitchenKinematics(make_kitchen_sim().model)
        pos, quat = fk.ee_pose(np.zeros(7))  # site position (3,), quaternion xyzw (4,)
    """

    def __init__(self, model: Any) -> None:
        import mujoco

        self.model = model
        self.data = mujoco.MjData(model)
        self.site = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, KITCHEN_EE_SITE)

    def ee_pose(self, arm_qpos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Site position and quaternion ``xyzw`` (raw sign) for the seven arm joint angles."""
        import mujoco

        self.data.qpos[:7] = np.asarray(arm_qpos, dtype=np.float64)[:7]
        mujoco.mj_kinematics(self.model, self.data)
        return (self.data.site_xpos[self.site].copy(),
                quat_xyzw_from_mat(self.data.site_xmat[self.site]))

    def ee_poses(self, arm_qpos: np.ndarray) -> np.ndarray:
        """``(T, 7)`` site positions and quaternions ``xyzw`` (raw signs) for ``(T, >=7)``."""
        arm_qpos = np.asarray(arm_qpos, dtype=np.float64)
        return np.stack([np.concatenate(self.ee_pose(q)) for q in arm_qpos]) \
            if len(arm_qpos) else np.zeros((0, 7))


class DLSController:
    """End-effector pose target -> the kitchen env's joint-velocity action (module docstring).

    Args:
        sim: a ``KitchenEnv`` (`make_kitchen_sim`); the controller reads its true MuJoCo state.
        damping: ``lambda`` of the damped least squares (m).
        max_step_pos: cap on the position error used per step (m).
        max_step_rot: cap on the rotation error used per step (rad).
        nullspace_gain: pull of the joints towards ``rest_qpos`` in the Jacobian's null space.
        max_joint_step: cap on the largest joint change per step (rad; the step is scaled down
            as a whole, keeping its direction).
        rest_qpos: the posture the null space pulls to (default: the kitchen's reset posture).

    Example::

        sim = make_kitchen_sim(); sim.reset(seed=0)
        ctrl = DLSController(sim)
        action = ctrl(np.array([-0.4, 0.2, 2.0, 0.5, 0.5, 0.5, -0.5, 0.04, 0.04]))  # (9,)
        sim.step(action)
    """

    def __init__(
        self,
        sim: Any,
        *,
        damping: float = 0.05,
        max_step_pos: float = 0.06,
        max_step_rot: float = 0.35,
        nullspace_gain: float = 0.1,
        max_joint_step: float = 0.1,
        rest_qpos: np.ndarray | None = None,
    ) -> None:
        import mujoco

        self.sim = sim
        self.model, self.data = sim.model, sim.data
        self.site = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_SITE, KITCHEN_EE_SITE)
        self.damping = float(damping)
        self.max_step_pos = float(max_step_pos)
        self.max_step_rot = float(max_step_rot)
        self.nullspace_gain = float(nullspace_gain)
        self.max_joint_step = float(max_joint_step)
        robot = sim.robot_env
        self.rest_qpos = np.array(robot.init_qpos[:7] if rest_qpos is None else rest_qpos,
                                  dtype=np.float64)
        self.dt = float(robot.dt)
        self.kp = np.array(self.model.actuator_gainprm[:9, 0], dtype=np.float64)
        self.joint_damping = np.array(self.model.dof_damping[:9], dtype=np.float64)
        self.vel_scale = np.array(robot.act_rng, dtype=np.float64)  # action 1 -> 2 rad/s
        margin = 0.05  # rad kept from each arm joint limit
        self.limits = np.stack([
            np.maximum(self.model.jnt_range[:7, 0], robot.robot_pos_bound[:7, 0]) + margin,
            np.minimum(self.model.jnt_range[:7, 1], robot.robot_pos_bound[:7, 1]) - margin,
        ], axis=1)
        self._jacp = np.zeros((3, self.model.nv))
        self._jacr = np.zeros((3, self.model.nv))

    def ee_pose(self) -> tuple[np.ndarray, np.ndarray]:
        """The true site position (3,) and rotation matrix (3, 3)."""
        return (self.data.site_xpos[self.site].copy(),
                self.data.site_xmat[self.site].reshape(3, 3).copy())

    def __call__(self, pose: np.ndarray) -> np.ndarray:
        """The ``(9,)`` joint-velocity action in ``[-1, 1]`` that tracks ``pose`` (9-D)."""
        import mujoco

        pose = np.asarray(pose, dtype=np.float64)
        if pose.shape != (9,) or not np.all(np.isfinite(pose)):
            raise ValueError(f"ee_pose action must be 9 finite values, got {pose.tolist()}")
        target_rot = _mat_from_xyzw(pose[3:7])
        pos, rot = self.ee_pose()
        e_pos = pose[:3] - pos
        e_rot = _rotvec(target_rot @ rot.T)
        if (n := np.linalg.norm(e_pos)) > self.max_step_pos:
            e_pos *= self.max_step_pos / n
        if (n := np.linalg.norm(e_rot)) > self.max_step_rot:
            e_rot *= self.max_step_rot / n
        mujoco.mj_jacSite(self.model, self.data, self._jacp, self._jacr, self.site)
        jac = np.vstack([self._jacp[:, :7], self._jacr[:, :7]])  # (6, 7)
        err = np.concatenate([e_pos, e_rot])
        q = self.data.qpos[:7]
        low, high = self.limits[:, 0], self.limits[:, 1]
        free = np.ones(7, dtype=bool)
        held_dq = np.zeros(7)
        for _ in range(7):  # joints that would cross their limit are held there (active set)
            jf = jac * free
            jjt = jf @ jf.T + self.damping**2 * np.eye(6)
            dq = jf.T @ np.linalg.solve(jjt, err)
            pinv = jf.T @ np.linalg.solve(jjt, jf)
            dq += (np.eye(7) - pinv) @ (self.nullspace_gain * (self.rest_qpos - q) * free)
            fix = free & (((q + dq) < low) | ((q + dq) > high))
            if not fix.any():
                break
            held_dq[fix] = np.clip(q + dq, low, high)[fix] - q[fix]
            err = err - jac[:, fix] @ held_dq[fix]
            free &= ~fix
        dq = np.where(free, dq, held_dq)
        if (peak := np.abs(dq).max()) > self.max_joint_step:  # keep the direction, bound the step
            dq *= self.max_joint_step / peak
        fingers = np.clip(pose[7:9], 0.0, _FINGER_MAX)
        dq_all = np.concatenate([dq, fingers - self.data.qpos[7:9]])
        # servo target: q + dq, plus what gravity and joint damping will take off it
        target = self.data.qpos[:9] + dq_all
        target += self.data.qfrc_bias[:9] / self.kp
        target[:7] += self.joint_damping[:7] * dq / (self.dt * self.kp[:7])
        velocity = (target - self.sim.robot_env._last_robot_qpos) / self.dt
        return np.clip(velocity / self.vel_scale, -1.0, 1.0)


class KitchenInstance:
    """One kitchen env with the pose controller, the randomised reset and the subtask flags.

    `FrankaKitchenEnv` steps ``N`` of these; the scripted expert and the data set writer of
    recipes/kitchen use one directly.

    Args:
        init_noise: half-width of the uniform offset of the seven arm joints at reset (rad).
        kettle_noise: half-width of the uniform offset of the kettle in x and y at reset (m).
        sim_kwargs: passed to `make_kitchen_sim`.

    Example::

        inst = KitchenInstance()
        obs = inst.reset(seed=3)          # the 66-D observation entries (numpy)
        obs = inst.step_pose(inst.ee_target_now())
        inst.completed                    # {'microwave': False, ...}
    """

    def __init__(self, *, init_noise: float = 0.1, kettle_noise: float = 0.02,
                 **sim_kwargs: Any) -> None:
        self.sim = make_kitchen_sim(**sim_kwargs)
        self.model, self.data = self.sim.model, self.sim.data
        self.kinematics = KitchenKinematics(self.model)
        self.controller = DLSController(self.sim)
        self.init_noise, self.kettle_noise = float(init_noise), float(kettle_noise)
        self._kettle_qpos = int(self.model.jnt_qposadr[self.model.joint("kettle").id])
        self.completed = dict.fromkeys(KITCHEN_TASKS, False)
        self.raw_obs: dict[str, Any] = {}
        self.last_joint_action = np.zeros(9)
        self.last_reward = 0.0
        self._prev_quat: np.ndarray | None = None

    def reset(self, seed: int) -> dict[str, np.ndarray]:
        """Reset with ``seed`` (the same seed gives the same initial state and noise)."""
        import mujoco

        if not 0 <= int(seed) < 2**32:
            raise ValueError(f"kitchen seeds must be in [0, 2**32), got {seed}")
        self.sim.reset(seed=int(seed))
        rng = np.random.default_rng(int(seed))
        qpos = self.data.qpos.copy()
        qpos[:7] += rng.uniform(-self.init_noise, self.init_noise, 7)
        qpos[self._kettle_qpos:self._kettle_qpos + 2] += rng.uniform(
            -self.kettle_noise, self.kettle_noise, 2)
        self.sim.robot_env.set_state(qpos, np.zeros_like(self.data.qvel))
        mujoco.mj_forward(self.model, self.data)
        robot_obs = self.sim.robot_env._get_obs()  # refreshes the servo reference
        self.raw_obs = self.sim._get_obs(robot_obs)
        self.completed = dict.fromkeys(KITCHEN_TASKS, False)
        self.last_joint_action = np.zeros(9)
        self.last_reward = 0.0
        self._prev_quat = None
        return self.observe()

    def observe(self) -> dict[str, np.ndarray]:
        """The observation entries of `KITCHEN_OBS_KEYS` and ``observation`` (float64)."""
        native = np.asarray(self.raw_obs["observation"], dtype=np.float64)
        pos, quat = self.kinematics.ee_pose(native[:7])
        if self._prev_quat is None:
            quat = quat if quat[3] >= 0 else -quat
        elif float(quat @ self._prev_quat) < 0:
            quat = -quat
        self._prev_quat = quat
        out = {"robot_qpos": native[:9], "robot_qvel": native[9:18], "ee_pos": pos,
               "ee_quat": quat, "object": native[18:]}
        out[keys.OBSERVATION] = np.concatenate([out[k] for k in KITCHEN_OBS_KEYS])
        return out

    def ee_target_now(self) -> np.ndarray:
        """The current true site pose and finger positions as a 9-D ``ee_pose`` action."""
        pos, rot = self.controller.ee_pose()
        return np.concatenate([pos, quat_xyzw_from_mat(rot), self.data.qpos[7:9]])

    def step_joint_velocity(self, action: np.ndarray) -> dict[str, np.ndarray]:
        """Step with the native joint-velocity action (9-D, in ``[-1, 1]``)."""
        action = np.clip(np.asarray(action, dtype=np.float64), -1.0, 1.0)
        self.raw_obs, reward, _, _, info = self.sim.step(action)
        self.last_joint_action = action
        self.last_reward = float(reward)
        for task in info["episode_task_completions"]:
            self.completed[task] = True
        return self.observe()

    def step_pose(self, pose: np.ndarray) -> dict[str, np.ndarray]:
        """Step with a 9-D ``ee_pose`` action through `DLSController`."""
        return self.step_joint_velocity(self.controller(pose))

    @property
    def success(self) -> bool:
        """All four subtasks complete."""
        return all(self.completed.values())

    def site_pos(self, name: str) -> np.ndarray:
        """World position of a MuJoCo site of the kitchen (e.g. ``"microhandle_site"``)."""
        return self.data.site(name).xpos.copy()

    def close(self) -> None:
        self.sim.close()


def tracking_test_trajectory(start: np.ndarray, steps: int = 125) -> np.ndarray:
    """``(steps, 9)`` ee_pose targets: a figure-eight of 10 cm x 6 cm (x, z) around ``start``
    (a 9-D pose) over ``steps`` steps, the orientation swept +-30 degrees about the world z
    axis and back, the fingers opening and closing.

    Example::

        traj = tracking_test_trajectory(KitchenInstance().reset(0) and inst.ee_target_now())
    """
    from scipy.spatial.transform import Rotation

    start = np.asarray(start, dtype=np.float64)
    s = np.linspace(0.0, 1.0, steps)
    phase = 2 * np.pi * s
    ramp = np.minimum(1.0, s * 8)  # ease in over the first eighth
    out = np.repeat(start[None], steps, axis=0)
    out[:, 0] += ramp * 0.05 * np.sin(phase)
    out[:, 2] += ramp * 0.03 * np.sin(2 * phase)
    yaw = ramp * np.deg2rad(30.0) * np.sin(phase)
    base = Rotation.from_quat(start[3:7])
    out[:, 3:7] = (Rotation.from_euler("z", yaw[:, None]) * base).as_quat()
    out[:, 7:9] = 0.02 + 0.02 * np.cos(phase)[:, None]
    return out


def measure_tracking_error(seed: int = 0, steps: int = 125, warmup: int = 10,
                           instance: KitchenInstance | None = None) -> dict[str, float]:
    """Track `tracking_test_trajectory` from a reset and return the error of the achieved
    site pose against the pose commanded at the same step (after ``warmup`` steps):
    ``pos_mm_mean``, ``pos_mm_max``, ``rot_deg_mean``, ``rot_deg_max``, ``finger_mm_max``.

    Example::

        measure_tracking_error(seed=0)["pos_mm_mean"]
    """
    inst = KitchenInstance() if instance is None else instance
    inst.reset(seed)
    traj = tracking_test_trajectory(inst.ee_target_now(), steps)
    pos_err, rot_err, finger_err = [], [], []
    for target in traj:
        inst.step_pose(target)
        pos, rot = inst.controller.ee_pose()
        pos_err.append(np.linalg.norm(pos - target[:3]))
        rot_err.append(np.linalg.norm(_rotvec(_mat_from_xyzw(target[3:7]) @ rot.T)))
        finger_err.append(np.abs(inst.data.qpos[7:9] - target[7:9]).max())
    pos_err, rot_err = np.array(pos_err[warmup:]), np.array(rot_err[warmup:])
    return {"pos_mm_mean": float(pos_err.mean() * 1e3), "pos_mm_max": float(pos_err.max() * 1e3),
            "rot_deg_mean": float(np.rad2deg(rot_err.mean())),
            "rot_deg_max": float(np.rad2deg(rot_err.max())),
            "finger_mm_max": float(np.max(finger_err[warmup:]) * 1e3)}


class FrankaKitchenEnv(SimulatorBatchEnv):
    """A batch of Franka Kitchen envs (four subtasks, 12.5 Hz) as one TorchRL env.

    Args:
        batch_size: ``[N]``, the number of kitchen envs.
        action_space: ``"ee_pose"`` (9-D, R^3 x S^3 x R^2) or ``"joint_velocity"`` (9-D, the
            native action); see the module docstring.
        max_steps: episode limit (default `KITCHEN_MAX_STEPS`).
        seeds: ``N`` reset seeds (default ``100000 + i``, disjoint from the demonstration seeds
            of recipes/kitchen/experts.py); a ``seed`` entry ``(N,)`` in the reset TensorDict
            overrides them.
        init_noise: arm joint offset at reset, rad (`KitchenInstance`).
        kettle_noise: kettle x/y offset at reset, m (`KitchenInstance`).
        device: where the TensorDicts live.

    Output keys: ``observation`` (66-D) and its five parts (`KITCHEN_OBS_KEYS`),
    ``("subtasks", name)`` for the names of `KITCHEN_SUBTASK_KEYS` (``(N, 1)`` bool, complete so
    far), ``success``, ``step_count``, ``joint_velocity`` (the native action executed at the
    step, ``(N, 9)``; zeros at reset), ``reward``, ``done``/``terminated``/``truncated``. A
    finished instance is frozen (later actions are ignored, reward 0), so
    ``rollout(..., break_when_any_done=False, break_when_all_done=True)`` runs the whole batch.
    A ``_reset`` mask resets only the instances it selects. The kitchen envs are
    ``env.instances`` (`KitchenInstance`).

    Example::

        env = FrankaKitchenEnv([2], seeds=[0, 1])
        td = env.reset()
        td["observation"].shape  # torch.Size([2, 66])
        out = env.rollout(3, break_when_any_done=False)
        out["next", "subtasks", "kettle"].shape  # torch.Size([2, 3, 1])
    """

    simulators_attr = "instances"

    def __init__(
        self,
        batch_size: Sequence[int] | torch.Size,
        action_space: str = "ee_pose",
        *,
        max_steps: int | None = None,
        seeds: Sequence[int] | None = None,
        init_noise: float = 0.1,
        kettle_noise: float = 0.02,
        device: str | torch.device = "cpu",
    ) -> None:
        _check_action_space(action_space)
        batch_size = torch.Size(batch_size)
        if len(batch_size) != 1:
            raise ValueError(f"FrankaKitchenEnv: batch_size must be [N], got {list(batch_size)}")
        super().__init__(batch_size=batch_size, device=device)
        self.action_space_name = action_space
        self.max_steps = int(KITCHEN_MAX_STEPS if max_steps is None else max_steps)
        n = batch_size[0]
        self.seeds = list(range(100000, 100000 + n)) if seeds is None else [int(s) for s in seeds]
        if len(self.seeds) != n:
            raise ValueError(f"FrankaKitchenEnv: {len(self.seeds)} seeds for a batch of {n}")
        self.instances = [KitchenInstance(init_noise=init_noise, kettle_noise=kettle_noise)
                          for _ in range(n)]
        self._last: list[dict[str, np.ndarray]] = [{} for _ in range(n)]
        self._count = np.zeros(n, dtype=np.int64)
        self._reward = np.zeros(n)
        self._truncated = np.zeros(n, dtype=bool)
        self._joint = np.zeros((n, 9))
        self._make_specs()

    @property
    def obs_dim(self) -> int:
        """Size of ``observation`` (66)."""
        return sum(KITCHEN_OBS_DIMS.values())

    def _make_specs(self) -> None:
        batch, dev = self.batch_size, self.device
        f32 = {"dtype": torch.float32, "device": dev}
        flag = {"dtype": torch.bool, "device": dev}
        spec = {keys.OBSERVATION: Unbounded((*batch, self.obs_dim), **f32)}
        spec.update({k: Unbounded((*batch, d), **f32) for k, d in KITCHEN_OBS_DIMS.items()})
        spec["subtasks"] = Composite(
            {name: Categorical(2, (*batch, 1), **flag) for name in KITCHEN_SUBTASK_KEYS},
            shape=batch, device=dev)
        spec["success"] = Categorical(2, (*batch, 1), **flag)
        spec["step_count"] = Unbounded((*batch, 1), dtype=torch.int64, device=dev)
        spec["joint_velocity"] = Bounded(-1.0, 1.0, (*batch, 9), **f32)
        self.observation_spec = Composite(spec, shape=batch, device=dev)
        self.state_spec = Composite(
            seed=Unbounded((*batch,), dtype=torch.int64, device=dev), shape=batch, device=dev)
        if self.action_space_name == "joint_velocity":
            self.action_spec = Bounded(-1.0, 1.0, (*batch, 9), **f32)
        else:
            low = torch.tensor([*_POS_LOW, -1.0, -1.0, -1.0, -1.0, 0.0, 0.0])
            high = torch.tensor([*_POS_HIGH, 1.0, 1.0, 1.0, 1.0, _FINGER_MAX, _FINGER_MAX])
            self.action_spec = Bounded(low.expand(*batch, 9), high.expand(*batch, 9), **f32)
        self.reward_spec = Unbounded((*batch, 1), **f32)
        self.full_done_spec = Composite(
            {name: Categorical(2, (*batch, 1), **flag)
             for name in ("done", "terminated", "truncated")},
            shape=batch, device=dev)

    def _pack(self) -> TensorDict:
        n, dev = self.batch_size[0], self.device
        f32 = {"dtype": torch.float32, "device": dev}
        data: dict[str, Any] = {
            key: torch.as_tensor(np.stack([o[key] for o in self._last]), **f32)
            for key in (keys.OBSERVATION, *KITCHEN_OBS_KEYS)
        }
        flags = np.array([[inst.completed[t] for t in KITCHEN_TASKS] for inst in self.instances])
        data["subtasks"] = {
            name: torch.as_tensor(flags[:, j], device=dev).reshape(n, 1)
            for j, name in enumerate(KITCHEN_SUBTASK_KEYS)
        }
        data.update(self._done_entries(flags.all(1),
                                       joint_velocity=torch.as_tensor(self._joint, **f32)))
        return TensorDict(data, batch_size=self.batch_size, device=dev)

    # ----- dynamics (`SimulatorBatchEnv`) -------------------------------------------------------
    def _done(self, i: int) -> bool:
        return self.instances[i].success

    def _reset_instance(self, i: int) -> None:
        self._last[i] = self.instances[i].reset(self.seeds[i])
        self._joint[i] = 0.0

    def _step_instance(self, i: int, action: np.ndarray) -> None:
        inst = self.instances[i]
        if self.action_space_name == "ee_pose":
            self._last[i] = inst.step_pose(action)
        else:
            self._last[i] = inst.step_joint_velocity(action)
        self._joint[i] = inst.last_joint_action
        self._reward[i] = inst.last_reward


def make_kitchen_env(
    batch_size: Sequence[int] | torch.Size,
    *,
    obs_horizon: int = 2,
    **env_kwargs,
) -> TransformedEnv:
    """`FrankaKitchenEnv` with the observation window an RFMP policy reads.

    ``obs_window (N, 2, 66)`` = ``[o^{s-T_o}, o^{s-1}]`` (after a reset the first is repeated);
    with T_o > 2 ``obs_gap (N,)`` = T_o (`rfmp_rl.envs.observation_windows`); ``InitTracker``
    writes ``is_init`` for ``MultiStepActorWrapper``.

    Example::

        env = make_kitchen_env([2])
        env.reset()["obs_window"].shape  # torch.Size([2, 2, 66])
    """
    env = FrankaKitchenEnv(batch_size, **env_kwargs)
    windows = observation_windows(obs_horizon, {keys.OBSERVATION: keys.OBS_WINDOW}, {})
    return TransformedEnv(env, windows)


def kitchen_episodes(
    source: Any,
    *,
    episodes: Sequence[int] | None = None,
    model: Any = None,
) -> tuple[list[TensorDict], Any]:
    """Episodes of a Minari kitchen dataset in `FrankaKitchenEnv`'s layout, for training.

    Reads ``source`` with `rfmp_rl.data.read_minari` (a dataset id under
    ``$MINARI_DATASETS_PATH`` such as ``D4RL/kitchen/complete-v2``, or a local folder) and
    returns, per episode of ``T`` steps:

    - ``observation (T, 66)``: the 59-D kitchen observation split and completed as the env does
      (``robot_qpos``, ``robot_qvel``, ``ee_pos`` and ``ee_quat`` by forward kinematics of the
      observed joint positions, ``object``);
    - ``action (T, 9)``: the ee_pose action. A dataset written by recipes/kitchen/experts.py
      stores it (``actions/ee_pose``); for ``D4RL/kitchen`` (joint-velocity actions in
      ``[-1, 1]``) it is the pose the action led to, as the paper builds it: the forward
      kinematics of the next observed joint positions ``q_{t+1}`` (site pose, finger
      positions); the last step, whose next observation is not kept, uses the joint position
      its action commands, ``q_t + 2 a_t dt``;
    - ``reward``, ``terminated``, ``truncated`` as read, and ``timestamp`` (12.5 Hz).

    Quaternion signs (``observation[21:25]``, ``action[3:7]``) follow
    `rfmp_rl.data.quaternions`: ``w >= 0`` at an episode's first step, then continuous.

    Args:
        source: a Minari dataset id or folder (`rfmp_rl.data.read_minari`).
        episodes: episode ids to read (default all).
        model: the kitchen's ``mujoco.MjModel`` for the forward kinematics (default: a
            `make_kitchen_sim` model; its 0.08 s step and 2 rad/s action scale are the env's).

    Returns:
        ``(episodes, manifest)``; ``manifest.extra["kitchen_action_source"]`` says which path
        was taken (``"ee_pose"`` or ``"joint_velocity_fk"``).

    Raises:
        DataError: the dataset has no ``observation/observation`` of 59 values per step, or
            no 9-D ``action`` / ``action/ee_pose``.

    Example::

        eps, manifest = kitchen_episodes("data/kitchen/kitchen-expert-v0")
        eps[0]["observation"].shape  # torch.Size([T, 66])
    """
    from rfmp_rl.data.episodes import DataError
    from rfmp_rl.data.minari import read_minari
    from rfmp_rl.data.quaternions import (
        canonicalize_episode_quaternions,
        parse_quaternion_fields,
    )

    raw, manifest = read_minari(source, episodes=episodes, rate_hz=KITCHEN_CONTROL_FREQ)
    if model is None:
        sim = make_kitchen_sim()
        model, dt = sim.model, float(sim.robot_env.dt)
        vel_scale = np.array(sim.robot_env.act_rng, dtype=np.float64)
        sim.close()
    else:
        dt, vel_scale = 0.08, np.full(9, 2.0)
    fk = KitchenKinematics(model)
    out, source_kind = [], None
    for name, ep in zip(manifest.episode_names, raw, strict=True):
        obs_group = ep.get(keys.OBSERVATION, None)
        native = obs_group.get(keys.OBSERVATION, None) \
            if isinstance(obs_group, TensorDictBase) else None
        if native is None or native.shape[-1] != 59:
            raise DataError("expected a 59-D kitchen observation (observation/observation)",
                            file=manifest.source, key="observations/observation", episode=name)
        native = native.to(torch.float64).numpy()
        joint = ep.get(keys.ACTION, None)
        action = joint.get("ee_pose", None) if isinstance(joint, TensorDictBase) else None
        if action is not None:
            kind = "ee_pose"
            action = action.to(torch.float64).numpy()
        else:
            if not isinstance(joint, torch.Tensor) or joint.shape[-1] != 9:
                raise DataError("expected a 9-D action (D4RL/kitchen joint velocities) or "
                                "actions/ee_pose", file=manifest.source, key="actions",
                                episode=name)
            kind = "joint_velocity_fk"
            # the joint position reached after each action: the next observation's; for the
            # last step (its next observation is not kept) the position the action commands
            target = native[:, :9] + joint.to(torch.float64).numpy() * vel_scale * dt
            reached = np.concatenate([native[1:, :9], target[-1:]], axis=0)
            action = np.concatenate([fk.ee_poses(reached[:, :7]),
                                     np.clip(reached[:, 7:9], 0.0, _FINGER_MAX)], axis=1)
        if source_kind not in (None, kind):
            raise DataError("episodes mix ee_pose and joint-velocity actions",
                            file=manifest.source, episode=name)
        source_kind = kind
        ee = fk.ee_poses(native[:, :7])
        obs = np.concatenate([native[:, :18], ee, native[:, 18:]], axis=1)
        td = TensorDict({
            keys.OBSERVATION: torch.as_tensor(obs, dtype=torch.float32),
            keys.ACTION: torch.as_tensor(action, dtype=torch.float32),
            **{k: ep[k] for k in ("reward", "terminated", "truncated", keys.TIMESTAMP)
               if k in ep},
        }, batch_size=[len(obs)])
        out.append(td)
    manifest.extra["kitchen_action_source"] = source_kind
    fields = parse_quaternion_fields("observation[21:25],action[3:7]")
    canonicalize_episode_quaternions(out, manifest, fields)
    return out, manifest
