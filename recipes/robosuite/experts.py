"""Scripted experts for the robosuite tasks of `rfmp_rl.envs.robosuite`, and demo generation.

Part of the robosuite recipe (not of the library): `utils.py` beside it calls `generate_demos`
when a demonstration file is missing.

`RobosuiteExpert` is a waypoint planner that reads the TRUE object pose from the simulator
(``sim.data.body_xpos`` of the object's root body, and the nut's handle site): it picks a goal
end-effector pose (grip-site position and a downward orientation with a yaw) and a gripper
command per phase, and moves a setpoint toward the goal at a bounded speed (so the commanded
trajectory is smooth). The action is

- ``"delta"``: the setpoint minus the current grip-site pose, in the robot base frame, divided
  by the OSC_POSE output limits (0.05 m, 0.5 rad per unit) and clipped to ``[-1, 1]``;
- ``"abs_pose"``: the setpoint itself: position, hand quaternion ``xyzw`` (the frame of
  ``robot0_eef_quat``, in the hemisphere of the current one) and the gripper command.

Phases:

- Lift: above the cube (yaw aligned with a cube face), descend, close, lift.
- PickPlaceCan: above the can, descend, close, lift over the bin walls, carry the can (closed
  loop on its position) above the target of the Can bin, lower, open, retreat.
- NutAssemblySquare: above the handle (fingers across it), descend, close, lift above the peg,
  carry and turn the nut (closed loop on its pose) until its centre is over the square peg and
  its sides are aligned with the peg's, lower, open, retreat.

A grasp that closes on nothing, or an object that does not rise with the gripper, sends the
expert back to the approach (at most ``max_regrasps`` times).

TwoArmTransport's two-arm expert is `experts_hard.TransportExpert` and ToolHang's
`experts_toolhang.ToolHangExpert` (`make_expert` picks the expert of a task).

`generate_demos` runs the expert from consecutive seeds, keeps the successful episodes and
writes them as a robomimic HDF5 file. Command line::

    python recipes/robosuite/experts.py --task Lift --n 200 --action-space delta [--images]
    python recipes/robosuite/experts.py --task Lift --action-space abs_pose --evaluate 100
    python recipes/robosuite/experts.py --task TwoArmTransport --evaluate 100

The first writes the file that ``train.py task=Lift action_space=delta [obs=image]`` reads
(`default_demo_path`; ``--out`` for another); an existing file is kept unless ``--overwrite``.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import math
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tensordict import TensorDict, TensorDictBase

from recipes.common import ROOT
from recipes.expert_demos import (
    act_batched,
    attempts_limit,
    collect_successes,
    print_summary,
    success_summary,
)
from rfmp_rl import keys
from rfmp_rl.envs.robosuite import (
    OSC_POS_SCALE,
    OSC_ROT_SCALE,
    ROBOSUITE_CONTROL_FREQ,
    ROBOSUITE_MAX_STEPS,
    ROBOSUITE_MUG_TASKS,
    RobosuiteEnv,
    _check,
    num_arms,
    object_body_id,
    osc_pose_controller_config,
    task_cameras,
)

__all__ = [
    "RobosuiteExpert",
    "make_expert",
    "ExpertPolicy",
    "make_expert",
    "generate_demos",
    "evaluate_expert",
    "down_rotation",
    "yaw_of",
    "wrap_angle",
    "default_demo_path",
    "main",
]

#: Where the recipe's demonstration files live (`default_demo_path`).
DATA_DIR = ROOT / "data" / "robosuite"

# Grip-site orientation pointing down with the fingers closing along world y (yaw 0): columns are
# the site's x (closing axis), y and z (approach) axes in the world frame.
_DOWN = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
_GRIP_OPEN, _GRIP_CLOSE = -1.0, 1.0


def wrap_angle(angle: float, period: float = 2 * math.pi) -> float:
    """``angle`` wrapped into ``[-period / 2, period / 2)``.

    Example:
        >>> round(wrap_angle(3 * math.pi / 4, math.pi / 2), 4)
        -0.7854
    """
    return (angle + period / 2) % period - period / 2


def down_rotation(yaw: float) -> np.ndarray:
    """``(3, 3)`` grip-site orientation pointing down, fingers closing along ``(-sin, cos, 0)``.

    Example:
        >>> np.round(down_rotation(math.pi / 2)[:, 0], 6).tolist()  # the closing axis
        [-1.0, 0.0, 0.0]
    """
    c, s = math.cos(yaw), math.sin(yaw)
    rz = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return rz @ _DOWN


def yaw_of(rotation: np.ndarray) -> float:
    """Yaw of a grip-site orientation (the inverse of `down_rotation` for downward poses).

    Example:
        >>> round(yaw_of(down_rotation(0.3)), 6)
        0.3
    """
    closing = rotation[:, 0]
    return math.atan2(-closing[0], closing[1])


def _object_yaw(rotation: np.ndarray) -> float:
    """Yaw of an object frame's x axis."""
    return math.atan2(rotation[1, 0], rotation[0, 0])


def _closest_yaw(yaw: float, reference: float, period: float) -> float:
    """The angle ``yaw + k * period`` closest to ``reference``."""
    return reference + wrap_angle(yaw - reference, period)


def _rot():
    from scipy.spatial.transform import Rotation

    return Rotation


# Task geometry (m, rad). The grip site sits at the finger pads' centre; the fingertips reach
# about 1 cm below it. Square: the peg's top is at z = 0.95, the nut is 2 cm thick.
_PARAMS: dict[str, dict[str, Any]] = {
    "Lift": {"hover": 0.08, "grasp_dz": -0.003, "lift_z": 0.16, "min_gap": 0.01},
    "PickPlaceCan": {"hover": 0.10, "grasp_dz": 0.01, "carry_z": 1.06, "place_dz": 0.025,
                     "min_gap": 0.02, "place_offset": (-0.04, -0.06)},
    "NutAssemblySquare": {"hover": 0.08, "grasp_dz": 0.006, "carry_z": 1.02, "place_z": 0.88,
                          "min_gap": 0.008, "wrist_range": (-1.4, 2.4),
                          "peg_top": 0.975},
}


class RobosuiteExpert:
    """Waypoint planner on the true object pose for one robosuite env (see the module docstring).

    Args:
        task: ``"Lift"``, ``"PickPlaceCan"`` or ``"NutAssemblySquare"``.
        action_space: ``"delta"`` (7-D) or ``"abs_pose"`` (8-D), as `RobosuiteEnv`'s.
        noise_std: std of Gaussian noise (m) added to the commanded position every step.
        rot_noise_std: std of Gaussian noise (rad) added to the commanded rotation every step.
        seed: seed of the noise generator.
        speed: setpoint speed in free space (m per step); descents and placing go slower.
        turn_speed: setpoint turning speed (rad per step).
        max_regrasps: how often a failed grasp is retried.

    Call `reset` after every env reset, then `act` once per step with the robosuite env.

    Example::

        env = RobosuiteEnv("Lift", [1], seeds=[0])
        td = env.reset()
        expert = RobosuiteExpert("Lift", "delta")
        expert.reset(env.sims[0])
        while not td["done"].any():
            action = torch.as_tensor(expert.act(env.sims[0]), dtype=torch.float32)[None]
            td = env.step(td.set(keys.ACTION, action))["next"]
        td["success"].item()  # True
    """

    #: the geometry of each task the class plans for (``params`` is a copy of the task's entry)
    _TASK_PARAMS: dict[str, dict[str, Any]] = _PARAMS

    def __init__(
        self,
        task: str,
        action_space: str = "delta",
        *,
        noise_std: float = 0.0,
        rot_noise_std: float = 0.0,
        seed: int | None = None,
        speed: float = 0.015,
        turn_speed: float = 0.06,
        max_regrasps: int = 3,
    ) -> None:
        _check(task, action_space)
        self.task, self.action_space = task, action_space
        self.noise_std, self.rot_noise_std = float(noise_std), float(rot_noise_std)
        self.speed, self.turn_speed = float(speed), float(turn_speed)
        self.max_regrasps = int(max_regrasps)
        self.params = dict(self._TASK_PARAMS[task])
        self.rng = np.random.default_rng(seed)
        self.phase = "approach"
        self._sp_pos: np.ndarray | None = None

    def info(self) -> dict[str, Any]:
        """The expert's settings, JSON-serialisable (stored with generated demos).

        Example:
            >>> RobosuiteExpert("Lift").info()["name"]
            'RobosuiteExpert'
        """
        return {
            "name": type(self).__name__,
            "task": self.task,
            "action_space": self.action_space,
            "noise_std": self.noise_std,
            "rot_noise_std": self.rot_noise_std,
            "speed": self.speed,
            "turn_speed": self.turn_speed,
            "max_regrasps": self.max_regrasps,
            "params": dict(self.params),
        }

    # ----- simulator reads --------------------------------------------------------------------
    def reset(self, sim_env: Any) -> None:
        """Start a new episode on ``sim_env`` (a robosuite env, just reset)."""
        self.phase = "approach"
        self.phase_steps = 0
        self.regrasps = 0
        self._sp_pos = None
        self._sp_rot = None
        self._sp_yaw = 0.0
        self._grasp_yaw = 0.0
        self._nut_offset = 0.0
        self._nut_yaw = 0.0
        self._lift_ref = 0.0
        self._read_arm(sim_env, 0)
        data = sim_env.sim.data
        self._body = object_body_id(sim_env, self.task)
        if self.task == "NutAssemblySquare":
            nut = sim_env.nuts[sim_env.nut_id]
            self._handle = sim_env.sim.model.site_name2id(nut.important_sites["handle"])
            self._target = np.array(data.body_xpos[sim_env.peg1_body_id])[:2]
        elif self.task == "PickPlaceCan":
            # The centre of the Can bin is at the edge of the Panda's reach: aim nearer the robot,
            # still well inside the bin's success region.
            target = np.array(sim_env.target_bin_placements[sim_env.object_id])[:2]
            self._target = target + np.array(self.params["place_offset"])
            self._rest_z = float(data.body_xpos[self._body][2])  # the can stands on a bin floor

    def _read_arm(self, sim_env: Any, robot_index: int) -> None:
        """Read the frames of robot ``robot_index``'s arm: its grip site, its hand body, the
        hand-to-site rotation and the orientation of its controller's base frame."""
        robot = sim_env.robots[robot_index]
        data = sim_env.sim.data
        self._site_id = robot.eef_site_id["right"]
        self._hand_name = robot.robot_model.eef_name["right"]
        hand = np.array(data.get_body_xmat(self._hand_name))
        site = np.array(data.site_xmat[self._site_id]).reshape(3, 3)
        self._hand_to_site = hand.T @ site
        self._base_rot = np.array(robot.part_controllers["right"].origin_ori)

    def _eef(self, sim_env: Any) -> tuple[np.ndarray, np.ndarray]:
        data = sim_env.sim.data
        pos = np.array(data.site_xpos[self._site_id], dtype=np.float64)
        rot = np.array(data.site_xmat[self._site_id], dtype=np.float64).reshape(3, 3)
        return pos, rot

    def _object(self, sim_env: Any) -> tuple[np.ndarray, np.ndarray]:
        data = sim_env.sim.data
        pos = np.array(data.body_xpos[self._body], dtype=np.float64)
        rot = np.array(data.body_xmat[self._body], dtype=np.float64).reshape(3, 3)
        return pos, rot

    @staticmethod
    def _gap(sim_env: Any) -> float:
        """Finger opening (m): the two finger joints move in opposite directions."""
        robot = sim_env.robots[0]
        q = sim_env.sim.data.qpos[robot._ref_gripper_joint_pos_indexes["right"]]
        return float(abs(q[0] - q[-1]))

    # ----- planning ---------------------------------------------------------------------------
    def _goal(self, sim_env: Any) -> tuple[np.ndarray, float, float, float]:
        """(goal position, goal yaw, gripper, speed) of the current phase; advances phases."""
        for _ in range(4):  # a phase may end at once: plan the next one in the same step
            goal = getattr(self, f"_plan_{self.task}")(sim_env)
            if goal is not None:
                return goal
        raise RuntimeError("expert phases did not settle")  # pragma: no cover

    def _next(self, phase: str) -> None:
        self.phase, self.phase_steps = phase, 0

    def _reached(self, sim_env: Any, pos: np.ndarray, yaw: float | None, tol: float,
                 rot_tol: float = 0.08) -> bool:
        eef, rot = self._eef(sim_env)
        if np.linalg.norm(self._sp_pos - pos) > 1e-3 or np.linalg.norm(eef - pos) > tol:
            return False
        return yaw is None or abs(wrap_angle(yaw_of(rot) - yaw)) < rot_tol

    def _grasp_failed(self, sim_env: Any) -> bool:
        return self._gap(sim_env) < self.params["min_gap"]

    def _regrasp(self) -> None:
        self.regrasps += 1
        self._next("approach" if self.regrasps <= self.max_regrasps else "give_up")

    def _common(self, sim_env: Any, target: np.ndarray, yaw: float, period: float):
        """Approach / descend / close phases shared by the tasks (``None`` when past them)."""
        p, eef = self.params, self._eef(sim_env)[0]
        if self.phase == "approach":
            self._grasp_yaw = _closest_yaw(yaw, self._sp_yaw, period)
            goal = np.array([target[0], target[1], target[2] + p["hover"]])
            if self._reached(sim_env, goal, self._grasp_yaw, 0.015) or self.phase_steps > 80:
                self._next("descend")
                return None
            return goal, self._grasp_yaw, _GRIP_OPEN, self.speed
        if self.phase == "descend":
            goal = np.array([target[0], target[1], target[2] + p["grasp_dz"]])
            if self._reached(sim_env, goal, None, 0.006) or self.phase_steps > 60:
                self._next("close")
                return None
            return goal, self._grasp_yaw, _GRIP_OPEN, 0.6 * self.speed
        if self.phase == "close":
            if self.phase_steps >= 12:
                if self._grasp_failed(sim_env):
                    self._regrasp()
                    return None
                self._lift_ref = float(eef[2])
                self._next("lift")
                return None
            return self._sp_pos.copy(), self._grasp_yaw, _GRIP_CLOSE, self.speed
        return None

    def _holding(self, sim_env: Any, drop: float) -> bool:
        """The object rose with the gripper (it is held)."""
        eef = self._eef(sim_env)[0]
        obj = self._object(sim_env)[0]
        return not self._grasp_failed(sim_env) and eef[2] - obj[2] < drop

    def _plan_Lift(self, sim_env: Any):
        obj, rot = self._object(sim_env)
        if self.phase in ("approach", "descend", "close"):
            return self._common(sim_env, obj, _object_yaw(rot), math.pi / 2)
        if self.phase == "lift":
            goal = self._sp_pos.copy()
            goal[2] = self._lift_ref + self.params["lift_z"]
            if self._reached(sim_env, goal, None, 0.01) or self.phase_steps > 60:
                self._regrasp()  # still running: the cube did not come up (else: success)
                return None
            if self.phase_steps > 8 and not self._holding(sim_env, 0.03):
                self._regrasp()
                return None
            return goal, self._grasp_yaw, _GRIP_CLOSE, 0.7 * self.speed
        return self._sp_pos.copy(), self._grasp_yaw, _GRIP_OPEN, self.speed  # give_up

    def _lift_to_carry_height(self, sim_env: Any):
        """Lift phase of the pick-and-place experts: straight up to ``carry_z``, re-grasping if
        the object slips out; on to "carry" once there (or after 60 steps)."""
        goal = np.array([self._sp_pos[0], self._sp_pos[1], self.params["carry_z"]])
        if self.phase_steps > 8 and not self._holding(sim_env, 0.04):
            self._regrasp()
            return None
        if self._reached(sim_env, goal, None, 0.02) or self.phase_steps > 60:
            self._next("carry")
            return None
        return goal, self._grasp_yaw, _GRIP_CLOSE, 0.8 * self.speed

    def _release_and_retreat(self, yaw: float):
        """Last phases of the pick-and-place experts: open for 8 steps where the hand is, then
        rise to ``carry_z`` with the wrist at ``yaw``; the grasp yaw once given up."""
        if self.phase == "release":
            if self.phase_steps >= 8:
                self._next("retreat")
                return None
            return self._sp_pos.copy(), yaw, _GRIP_OPEN, self.speed
        if self.phase == "retreat":
            goal = self._sp_pos.copy()
            goal[2] = self.params["carry_z"]
            return goal, yaw, _GRIP_OPEN, self.speed
        return self._sp_pos.copy(), self._grasp_yaw, _GRIP_OPEN, self.speed  # give_up

    def _plan_PickPlaceCan(self, sim_env: Any):
        p = self.params
        obj, _ = self._object(sim_env)
        eef = self._eef(sim_env)[0]
        if self.phase in ("approach", "descend", "close"):
            return self._common(sim_env, obj, 0.0, math.pi)
        if self.phase == "lift":
            return self._lift_to_carry_height(sim_env)
        if self.phase == "carry":
            if not self._holding(sim_env, 0.05):
                self._regrasp()
                return None
            offset = self._target - obj[:2]
            goal = np.array([eef[0] + offset[0], eef[1] + offset[1], p["carry_z"]])
            if np.linalg.norm(offset) < 0.01 or self.phase_steps > 120:
                self._next("lower")
                return None
            return goal, 0.0, _GRIP_CLOSE, self.speed
        if self.phase == "lower":
            offset = self._target - obj[:2]
            dz = self._rest_z + p["place_dz"] - obj[2]
            goal = np.array([eef[0] + offset[0], eef[1] + offset[1], eef[2] + dz])
            if dz > -0.005 or self.phase_steps > 60:
                self._next("release")
                return None
            return goal, 0.0, _GRIP_CLOSE, 0.6 * self.speed
        return self._release_and_retreat(self._grasp_yaw)

    def _plan_nut_turn(self, nut_yaw: float) -> None:
        """Choose how to hold the handle and how to turn the nut onto the square peg.

        The fingers close across the handle, so the wrist yaw is the nut's yaw minus an offset of
        0 or pi (which side of the handle the hand faces). The nut goes onto the peg with its
        handle toward the robot (nut yaw pi, wrist yaw 0: the nearest reach) when the grasp
        keeps the wrist inside its comfortable range, else with the handle along -y (nut yaw
        -pi/2, wrist yaw -pi/2): both keep the hand within the Panda's reach over the peg.
        """
        low, high = self.params["wrist_range"]
        if low <= wrap_angle(nut_yaw - math.pi) <= high:
            self._nut_offset, self._nut_yaw = math.pi, math.pi
        else:
            self._nut_offset, self._nut_yaw = 0.0, -math.pi / 2

    def _plan_NutAssemblySquare(self, sim_env: Any):
        p = self.params
        obj, rot = self._object(sim_env)
        eef, eef_rot = self._eef(sim_env)
        nut_yaw = _object_yaw(rot)
        if self.phase in ("approach", "descend", "close"):
            if self.phase == "approach":
                self._plan_nut_turn(nut_yaw)
            handle = np.array(sim_env.sim.data.site_xpos[self._handle], dtype=np.float64)
            return self._common(sim_env, handle, wrap_angle(nut_yaw - self._nut_offset),
                                2 * math.pi)
        if self.phase == "lift":
            return self._lift_to_carry_height(sim_env)
        if self.phase in ("carry", "lower"):
            if not self._holding(sim_env, 0.05):
                self._regrasp()
                return None
            # The nut turns with the wrist: the planned wrist yaw, corrected for any slip of the
            # nut in the hand (computed from small angles only, so no +-pi ambiguity).
            slip = wrap_angle(nut_yaw - yaw_of(eef_rot) - self._nut_offset)
            yaw = wrap_angle(self._nut_yaw - self._nut_offset) - slip
            offset = self._target - obj[:2]
            if self.phase == "carry":
                goal = np.array([eef[0] + offset[0], eef[1] + offset[1], p["carry_z"]])
                aligned = abs(wrap_angle(nut_yaw - self._nut_yaw)) < 0.05
                if (np.linalg.norm(offset) < 0.004 and aligned) or self.phase_steps > 150:
                    self._next("lower")
                    return None
                return goal, yaw, _GRIP_CLOSE, self.speed
            dz = p["place_z"] - obj[2]
            if dz > -0.003 or self.phase_steps > 80:
                self._next("release")
                return None
            if obj[2] > p["peg_top"] and np.linalg.norm(offset) > 0.004:
                dz = 0.0  # centre the nut over the peg before it goes down around it
            goal = np.array([eef[0] + offset[0], eef[1] + offset[1], eef[2] + dz])
            return goal, yaw, _GRIP_CLOSE, 0.4 * self.speed
        return self._release_and_retreat(self._sp_yaw)

    # ----- actions ----------------------------------------------------------------------------
    def act(self, sim_env: Any) -> np.ndarray:
        """The action for the current step (float64, 7-D delta or 8-D abs_pose)."""
        Rotation = _rot()
        eef, eef_rot = self._eef(sim_env)
        if self._sp_pos is None:
            self._sp_pos, self._sp_rot = eef.copy(), Rotation.from_matrix(eef_rot)
            self._sp_yaw = yaw_of(eef_rot)
        goal_pos, goal_orientation, gripper, speed = self._goal(sim_env)
        self.phase_steps += 1
        # Move the setpoint toward the goal, at most `speed` m and `turn_speed` rad per step.
        step = goal_pos - self._sp_pos
        dist = float(np.linalg.norm(step))
        self._sp_pos = goal_pos.copy() if dist <= speed else self._sp_pos + step * (speed / dist)
        self._turn_setpoint(goal_orientation)
        return self._command(sim_env, eef, eef_rot, gripper)

    def _turn_setpoint(self, goal_yaw: float) -> None:
        """Turn the setpoint orientation toward the downward grip of yaw ``goal_yaw``.

        The yaw moves linearly (never the other way round through +-pi, where the wrist joint
        ends); the orientation follows it, removing any initial tilt on the way.
        """
        Rotation = _rot()
        self._sp_yaw += float(np.clip(goal_yaw - self._sp_yaw, -self.turn_speed, self.turn_speed))
        target = Rotation.from_matrix(down_rotation(self._sp_yaw))
        turn = (target * self._sp_rot.inv()).as_rotvec()
        angle = float(np.linalg.norm(turn))
        if angle > 2 * self.turn_speed:
            turn *= 2 * self.turn_speed / angle
        self._sp_rot = Rotation.from_rotvec(turn) * self._sp_rot

    def _command(self, sim_env: Any, eef: np.ndarray, eef_rot: np.ndarray,
                 gripper: float) -> np.ndarray:
        """The setpoint (plus the expert's noise) as a delta or abs_pose action."""
        Rotation = _rot()
        pos, rot = self._sp_pos.copy(), self._sp_rot
        if self.noise_std > 0:
            pos = pos + self.rng.normal(0.0, self.noise_std, 3)
        if self.rot_noise_std > 0:
            rot = Rotation.from_rotvec(self.rng.normal(0.0, self.rot_noise_std, 3)) * rot
        if self.action_space == "delta":
            dpos = self._base_rot.T @ (pos - eef) / OSC_POS_SCALE
            drot = self._base_rot.T @ (rot * Rotation.from_matrix(eef_rot).inv()).as_rotvec()
            drot = drot / OSC_ROT_SCALE
            return np.concatenate([np.clip(dpos, -1, 1), np.clip(drot, -1, 1), [gripper]])
        hand = Rotation.from_matrix(rot.as_matrix() @ self._hand_to_site.T).as_quat()  # xyzw
        current = np.array(sim_env.sim.data.get_body_xquat(self._hand_name))[[1, 2, 3, 0]]
        if float(hand @ current) < 0:
            hand = -hand
        return np.concatenate([pos, hand, [gripper]])


class PoseExpert(RobosuiteExpert):
    """`RobosuiteExpert` whose goal orientation is any rotation (a scipy ``Rotation`` of the grip
    site), not only a downward grip with a yaw: the base of the mug and ToolHang experts."""

    def _reached_pose(self, sim_env: Any, pos: np.ndarray, rot, tol: float,
                      rot_tol: float = 0.08) -> bool:
        """The setpoint is at ``pos`` and the grip site within ``tol`` of it (and of ``rot``)."""
        eef, eef_rot = self._eef(sim_env)
        if np.linalg.norm(self._sp_pos - pos) > 1e-3 or np.linalg.norm(eef - pos) > tol:
            return False
        if rot is None:
            return True
        return (rot * _rot().from_matrix(eef_rot).inv()).magnitude() < rot_tol

    def _turn_setpoint(self, goal_rot) -> None:
        """Turn the setpoint orientation toward ``goal_rot`` (any rotation), at most
        ``turn_speed`` rad per step."""
        turn = (goal_rot * self._sp_rot.inv()).as_rotvec()
        angle = float(np.linalg.norm(turn))
        if angle > self.turn_speed:
            turn *= self.turn_speed / angle
        self._sp_rot = _rot().from_rotvec(turn) * self._sp_rot
        self._sp_yaw = yaw_of(self._sp_rot.as_matrix())


def _sibling(name: str):
    """recipes/robosuite/<name>.py (experts_mug, experts_hard, experts_toolhang), imported by its
    path: the recipe's scripts are not a package, and the module imports this one as
    ``experts``."""
    if name not in sys.modules:
        spec = importlib.util.spec_from_file_location(name, Path(__file__).with_name(f"{name}.py"))
        module = importlib.util.module_from_spec(spec)
        previous = sys.modules.get("experts")  # another recipe's `experts` may be loaded
        sys.modules["experts"] = sys.modules[__name__]
        try:
            spec.loader.exec_module(module)
        finally:
            if previous is None:
                del sys.modules["experts"]
            else:
                sys.modules["experts"] = previous
        sys.modules[name] = module
    return sys.modules[name]


def make_expert(task: str, action_space: str = "delta", **expert_kwargs: Any):
    """The scripted expert of ``task``: `RobosuiteExpert`; for PickPlaceMug and MugFlip
    experts_mug.py's `MugExpert`; for TwoArmTransport ``experts_hard.TransportExpert``; for
    ToolHang ``experts_toolhang.ToolHangExpert`` (the same ``reset`` / ``act`` / ``info``
    interface). ``expert_kwargs`` are their common arguments.

    Example:
        >>> type(make_expert("Lift")).__name__
        'RobosuiteExpert'
    """
    _check(task, action_space)
    if task in ROBOSUITE_MUG_TASKS:
        return _sibling("experts_mug").MugExpert(task, action_space, **expert_kwargs)
    if task == "TwoArmTransport":
        return _sibling("experts_hard").TransportExpert(task, action_space, **expert_kwargs)
    if task == "ToolHang":
        return _sibling("experts_toolhang").ToolHangExpert(task, action_space, **expert_kwargs)
    if task not in _PARAMS:
        known = sorted([*_PARAMS, *ROBOSUITE_MUG_TASKS, "TwoArmTransport", "ToolHang"])
        raise ValueError(f"no scripted expert for robosuite task {task!r}; experts exist for "
                         f"{known}")
    return RobosuiteExpert(task, action_space, **expert_kwargs)


class ExpertPolicy:
    """A batched TorchRL policy running one expert (`make_expert`) per instance of a
    `RobosuiteEnv`.

    Each expert is reset when its instance reports ``step_count == 0`` (a fresh episode).

    Args:
        env: the `RobosuiteEnv` (or a ``TransformedEnv`` around one).
        **expert_kwargs: `RobosuiteExpert` arguments (``noise_std``, ``seed``, ...); instance
            ``i`` gets ``seed + i`` when a seed is given.

    Example::

        env = RobosuiteEnv("Lift", [2], action_space="abs_pose")
        out = env.rollout(300, ExpertPolicy(env), break_when_any_done=False,
                          break_when_all_done=True)
        out["next", "success"][:, -1, 0]  # tensor([True, True])
    """

    def __init__(self, env: Any, **expert_kwargs: Any) -> None:
        self.env = getattr(env, "base_env", env)
        seed = expert_kwargs.pop("seed", None)
        self.experts = [
            make_expert(self.env.task, self.env.action_space_name,
                        seed=None if seed is None else seed + i, **expert_kwargs)
            for i in range(self.env.batch_size[0])
        ]

    def __call__(self, tensordict: TensorDictBase) -> TensorDictBase:
        """Write ``action (N, A)`` into ``tensordict``."""
        return act_batched(tensordict, self.experts, self.env.sims)


def _run_episode(env: RobosuiteEnv, expert: Any, seed: int,
                 images: bool) -> tuple[TensorDict, bool]:
    """One expert episode from ``seed`` (batch-1 env) -> (robomimic episode, success)."""
    td = env.reset(TensorDict({"seed": torch.tensor([seed])}, [1]))
    sim = env.sims[0]
    expert.reset(sim)
    obs_keys = list(env.all_low_dim_keys)
    if images:
        obs_keys += [f"{cam}_image" for cam in env.cameras]
    steps: list[dict[str, Any]] = []
    while True:
        state = np.array(sim.sim.get_state().flatten())
        action = torch.as_tensor(expert.act(sim), dtype=torch.float32)[None]
        out = env.step(td.set(keys.ACTION, action))
        nxt = out["next"]
        steps.append({
            "obs": {k: td[k][0].clone() for k in obs_keys},
            "next_obs": {k: nxt[k][0].clone() for k in obs_keys},
            keys.ACTION: action[0].clone(),
            "reward": nxt["reward"][0].clone(),
            "done": nxt["done"][0].clone(),
            "states": torch.as_tensor(state),
        })
        td = nxt
        if bool(td["done"].any()):
            break
    episode = torch.stack([TensorDict(s, []) for s in steps])
    for group in ("obs", "next_obs"):  # robomimic stores images as (T, H, W, 3)
        for cam in env.cameras if images else ():
            key = f"{cam}_image"
            episode.set((group, key), episode.get((group, key)).permute(0, 2, 3, 1).contiguous())
    return episode, bool(td["success"].item())


def evaluate_expert(
    task: str,
    action_space: str = "delta",
    n_episodes: int = 100,
    *,
    seed_start: int = 0,
    verbose: bool = True,
    **expert_kwargs: Any,
) -> dict[str, Any]:
    """Run the expert on seeds ``seed_start, ..., seed_start + n_episodes - 1``.

    Returns:
        ``success_rate``, ``successes``, ``attempts``, ``failed_seeds``, ``mean_steps`` (of the
        successful episodes), ``seconds_per_episode``.

    Example::

        evaluate_expert("Lift", "delta", 5)["success_rate"]  # 1.0
    """
    expert = make_expert(task, action_space, **expert_kwargs)
    env = RobosuiteEnv(task, [1], action_space)
    failed, lengths = [], []
    start = time.perf_counter()
    for seed in range(seed_start, seed_start + n_episodes):
        episode, success = _run_episode(env, expert, seed, images=False)
        if success:
            lengths.append(episode.batch_size[0])
        else:
            failed.append(seed)
        if verbose:
            print(f"[{task}/{action_space}] seed {seed}: {'ok' if success else 'FAILED'} "
                  f"({episode.batch_size[0]} steps, phase {expert.phase})", flush=True)
    seconds = time.perf_counter() - start
    env.close()
    result = {"task": task, "action_space": action_space,
              **success_summary(n_episodes, failed, lengths, seconds)}
    if verbose:
        print(json.dumps(result), flush=True)
    return result


def generate_demos(
    task: str,
    n_success: int,
    action_space: str = "delta",
    *,
    images: bool = False,
    seed_start: int = 0,
    path: str,
    max_attempts: int | None = None,
    image_size: int = 84,
    compression: str | None = "gzip",
    verbose: bool = True,
    **expert_kwargs: Any,
) -> dict[str, Any]:
    """Collect ``n_success`` successful expert episodes and write them as a robomimic file.

    The expert runs from seeds ``seed_start, seed_start + 1, ...``; failed episodes are dropped.
    Demo ``i`` of the file is the ``i``-th success. Observations use robomimic's names
    (``robot0_eef_pos``, ``robot0_eef_quat``, ``robot0_gripper_qpos``, ``object``, and with
    ``images`` ``agentview_image``, ``robot0_eye_in_hand_image`` as ``(T, H, W, 3) uint8``);
    ``next_obs``, ``states`` (MuJoCo states before each step), ``actions``, sparse ``rewards``
    and ``dones`` are written too. ``env_args`` holds ``env_name``, ``env_type`` (1,
    robosuite), ``env_kwargs`` (robot, controller config, ``control_freq``, cameras),
    ``action_space`` and ``expert`` (its settings, success rate, attempts and kept seeds).

    Args:
        task: the robosuite task.
        n_success: how many successful episodes to keep.
        action_space: ``"delta"`` or ``"abs_pose"``.
        images: also record both cameras.
        seed_start: the first seed.
        path: the ``.hdf5`` file to write.
        max_attempts: give up after this many episodes (default ``2 * n_success + 20``).
        image_size: camera resolution.
        compression: h5py filter of the datasets (``"gzip"``, ``"lzf"`` or ``None``).
        verbose: print one line per episode and the summary.
        **expert_kwargs: `RobosuiteExpert` arguments (``noise_std``, ``seed``, ...).

    Returns:
        ``path``, ``successes``, ``attempts``, ``success_rate`` (successes / attempts),
        ``seeds`` (kept), ``failed_seeds``, ``steps`` (in the file), ``seconds_per_episode``.

    Raises:
        RuntimeError: fewer than ``n_success`` successes within ``max_attempts`` (nothing is
            written).

    Example::

        info = generate_demos("Lift", 2, "abs_pose", path="/tmp/lift_abs.hdf5")
        info["successes"], info["success_rate"]  # (2, 1.0)
    """
    from rfmp_rl.data.robomimic import write_robomimic

    _check(task, action_space)
    max_attempts = attempts_limit(n_success, max_attempts)
    cameras = task_cameras(task) if images else ()
    expert = make_expert(task, action_space, **expert_kwargs)
    env = RobosuiteEnv(task, [1], action_space, cameras=cameras, image_size=image_size)

    def run(seed: int) -> tuple[TensorDict, bool, int]:
        episode, success = _run_episode(env, expert, seed, images)
        return episode, success, episode.batch_size[0]

    episodes, kept, failed, seconds = collect_successes(
        run, n_success, max_attempts, seed_start=seed_start, close=env.close,
        label=f"[{task}/{action_space}]", context=f" ({task}, {action_space})", verbose=verbose)
    attempts = len(kept) + len(failed)
    rate = len(episodes) / attempts
    env_args = {
        "env_name": task,
        "env_type": 1,
        "env_kwargs": {
            "robots": ["Panda"] * num_arms(task),
            "controller_configs": osc_pose_controller_config(action_space),
            "control_freq": ROBOSUITE_CONTROL_FREQ,
            "has_renderer": False,
            "has_offscreen_renderer": bool(images),
            "use_camera_obs": bool(images),
            "camera_names": list(cameras),
            "camera_heights": image_size,
            "camera_widths": image_size,
            "reward_shaping": False,
            "ignore_done": True,
        },
        "action_space": action_space,
        "max_steps": ROBOSUITE_MAX_STEPS[task],
        "expert": {
            **expert.info(),
            "success_rate": rate,
            "successes": len(episodes),
            "attempts": attempts,
            "seeds": kept,
        },
    }
    write_robomimic(path, episodes, env_args=env_args, compression=compression)
    result = {
        "path": str(path),
        "task": task,
        "action_space": action_space,
        "successes": len(episodes),
        "attempts": attempts,
        "success_rate": rate,
        "seeds": kept,
        "failed_seeds": failed,
        "steps": int(sum(ep.batch_size[0] for ep in episodes)),
        "seconds_per_episode": seconds / attempts,
    }
    if verbose:
        print_summary(result)
    return result


def default_demo_path(task: str, action_space: str, images: bool = False) -> Path:
    """The demonstration file that ``train.py task=<task> action_space=<action_space>`` reads
    (with ``obs=image`` when ``images``): ``data/robosuite/<task>_<action_space>[_images].hdf5``
    under the repository root."""
    suffix = "_images" if images else ""
    return DATA_DIR / f"{task.lower()}_{action_space}{suffix}.hdf5"


def main(argv: Sequence[str] | None = None) -> dict[str, Any]:
    """Command line: generate demos, or ``--evaluate N`` to measure the expert's success rate.

    Example::

        main(["--task", "Lift", "--evaluate", "5"])
    """
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--task", required=True, choices=list(ROBOSUITE_MAX_STEPS))
    parser.add_argument("--action-space", default="delta", choices=["delta", "abs_pose"])
    parser.add_argument("--n", type=int, default=200, help="successful demos to collect")
    parser.add_argument("--out", default=None,
                        help="output .hdf5 (default: the file train.py reads, "
                             "data/robosuite/<task>_<action space>[_images].hdf5)")
    parser.add_argument("--overwrite", action="store_true",
                        help="replace the output file when it exists (default: refuse)")
    parser.add_argument("--images", action="store_true", help="record the task's cameras")
    parser.add_argument("--seed-start", type=int, default=0)
    parser.add_argument("--max-attempts", type=int, default=None)
    parser.add_argument("--noise-std", type=float, default=0.0, help="position noise (m)")
    parser.add_argument("--rot-noise-std", type=float, default=0.0, help="rotation noise (rad)")
    parser.add_argument("--evaluate", type=int, default=None, metavar="N",
                        help="only run the expert on N seeds and print its success rate")
    parser.add_argument("--quiet", action="store_true", help="print the summary line only")
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    kwargs = {"noise_std": args.noise_std, "rot_noise_std": args.rot_noise_std,
              "seed": args.seed_start}
    if args.evaluate is not None:
        result = evaluate_expert(args.task, args.action_space, args.evaluate,
                                 seed_start=args.seed_start, verbose=not args.quiet, **kwargs)
    else:
        out = Path(args.out) if args.out else default_demo_path(args.task, args.action_space,
                                                                 args.images)
        if out.exists() and not args.overwrite:
            raise SystemExit(f"experts.py: {out} exists; give another --out, or --overwrite to "
                             "replace it")
        result = generate_demos(args.task, args.n, args.action_space, images=args.images,
                                seed_start=args.seed_start, path=str(out),
                                max_attempts=args.max_attempts, verbose=not args.quiet, **kwargs)
    if args.quiet:  # the summary only
        print_summary(result)
    return result


if __name__ == "__main__":
    main()
