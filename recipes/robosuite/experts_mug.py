"""Scripted experts for the mug tasks (`rfmp_rl.envs.robosuite_mug`): PickPlaceMug and MugFlip.

Part of the robosuite recipe: `experts.make_expert` returns a `MugExpert` for these tasks, so
`generate_demos`, `evaluate_expert`, `ExpertPolicy` and the command line of experts.py serve
them as the other tasks::

    python recipes/robosuite/experts.py --task MugFlip --action-space abs_pose --evaluate 100

`MugExpert` plans on the true mug and plate poses like `RobosuiteExpert` (a setpoint moving
toward a per-phase goal at a bounded speed), but its goal orientation is any rotation, not only
a downward grip with a yaw:

- PickPlaceMug: above the mug with the fingers closing across it, perpendicular to its handle;
  descend until the fingers hold the top of the mug, close, lift, carry the mug (closed loop on
  its position) over the plate, lower it onto the plate, open, rise. The hand points down
  throughout (its yaw is the handle's, within 45 degrees).
- MugFlip: above the lying mug near its opening, the fingers closing across its body; descend,
  close, lift; turn the hand about the fingers' closing axis until the mug's axis is vertical
  (closed loop on the mug's measured axis: about 90 degrees) while carrying it over the plate,
  lower it onto the plate, open, back the hand away along its pointing direction and rise.

A grasp that closes on nothing or a mug that slips out sends the expert back to the approach (at
most ``max_regrasps`` times).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from experts import (
    _GRIP_CLOSE,
    _GRIP_OPEN,
    PoseExpert,
    _closest_yaw,
    _object_yaw,
    _rot,
    down_rotation,
)

from rfmp_rl.envs.robosuite import ROBOSUITE_MUG_TASKS, _check

__all__ = ["MugExpert", "MUG_PARAMS"]

#: Task geometry (m, rad; heights above the table top unless said otherwise).
MUG_PARAMS: dict[str, dict[str, Any]] = {
    # grasp: the grip site this far below the rim; place: the mug bottom this far above the
    # plate's top when it is let go.
    "PickPlaceMug": {"hover": 0.10, "below_rim": 0.025, "carry": 0.22, "place_gap": 0.004,
                     "min_gap": 0.02, "retreat": 0.10},
    # grasp: this far from the mug's centre toward its opening, and this far above its axis.
    "MugFlip": {"hover": 0.10, "along_axis": 0.03, "above_axis": 0.004, "carry": 0.22,
                "place_gap": 0.004, "min_gap": 0.02, "retreat": 0.08, "flip_tol": 0.04},
}


class MugExpert(PoseExpert):
    """Waypoint planner for PickPlaceMug and MugFlip (see the module docstring).

    Args:
        task: ``"PickPlaceMug"`` or ``"MugFlip"``.
        action_space: ``"delta"`` (7-D) or ``"abs_pose"`` (8-D), as `RobosuiteEnv`'s.
        noise_std, rot_noise_std, seed, speed, turn_speed, max_regrasps: as `RobosuiteExpert`.

    Runs as `RobosuiteExpert` (``reset`` after each env reset, then ``act`` every step).

    Example::

        env = RobosuiteEnv("MugFlip", [1], action_space="abs_pose", seeds=[0])
        env.reset()
        expert = MugExpert("MugFlip", "abs_pose")
        expert.reset(env.sims[0])
        expert.act(env.sims[0]).shape  # (8,): position, hand quaternion xyzw, gripper
    """

    _TASK_PARAMS = MUG_PARAMS

    def __init__(self, task: str, action_space: str = "delta", **expert_kwargs: Any) -> None:
        _check(task, action_space)
        if task not in ROBOSUITE_MUG_TASKS:
            raise ValueError(f"MugExpert: task must be one of {ROBOSUITE_MUG_TASKS}, got {task!r}")
        super().__init__(task, action_space, **expert_kwargs)

    def reset(self, sim_env: Any) -> None:
        """Start a new episode on ``sim_env`` (a robosuite mug env, just reset)."""
        super().reset(sim_env)
        from rfmp_rl.envs.robosuite_mug import MUG_HALF_HEIGHT, PLATE_HALF_HEIGHT

        self._half_height = MUG_HALF_HEIGHT
        self._plate_body = sim_env.plate_body_id
        self._plate_top_offset = PLATE_HALF_HEIGHT
        self._table_z = float(sim_env.table_offset[2])
        self._grasp_rot = None
        self._retreat_from: np.ndarray | None = None

    # ----- simulator reads --------------------------------------------------------------------
    def _plate(self, sim_env: Any) -> np.ndarray:
        return np.array(sim_env.sim.data.body_xpos[self._plate_body], dtype=np.float64)

    def _holding(self, sim_env: Any, drop: float = 0.0) -> bool:
        """The fingers have not closed on nothing and the mug is within reach of them."""
        eef = self._eef(sim_env)[0]
        mug = self._object(sim_env)[0]
        return not self._grasp_failed(sim_env) and np.linalg.norm(eef - mug) < 0.09

    # ----- planning ---------------------------------------------------------------------------
    def _grasp_point(self, sim_env: Any) -> tuple[np.ndarray, float]:
        """(grip-site position of the grasp, wrist yaw) for the mug as it lies now."""
        p = self.params
        mug, rot = self._object(sim_env)
        yaw_now = self._sp_yaw
        if self.task == "PickPlaceMug":  # fingers across the body, perpendicular to the handle
            point = mug + rot[:, 2] * (self._half_height - p["below_rim"])
            return point, _closest_yaw(_object_yaw(rot), yaw_now, math.pi)
        axis = rot[:, 2]  # lying: the fingers close across the axis, near the opening
        point = mug + axis * p["along_axis"] + np.array([0.0, 0.0, p["above_axis"]])
        return point, _closest_yaw(math.atan2(axis[1], axis[0]), yaw_now, math.pi)

    def _grasp_phases(self, sim_env: Any):
        """approach / descend / close (``None`` when past them)."""
        Rotation = _rot()
        p = self.params
        point, yaw = self._grasp_point(sim_env)
        if self.phase == "approach":
            self._grasp_yaw = yaw
            goal = point + np.array([0.0, 0.0, p["hover"]])
            rot = Rotation.from_matrix(down_rotation(yaw))
            if self._reached_pose(sim_env, goal, rot, 0.015) or self.phase_steps > 100:
                self._next("descend")
                return None
            return goal, rot, _GRIP_OPEN, self.speed
        rot = Rotation.from_matrix(down_rotation(self._grasp_yaw))
        if self.phase == "descend":
            if self._reached_pose(sim_env, point, None, 0.006) or self.phase_steps > 60:
                self._next("close")
                return None
            return point, rot, _GRIP_OPEN, 0.6 * self.speed
        if self.phase == "close":
            if self.phase_steps >= 12:
                if self._grasp_failed(sim_env):
                    self._regrasp()
                    return None
                self._grasp_rot = rot
                self._next("lift")
                return None
            return self._sp_pos.copy(), rot, _GRIP_CLOSE, self.speed
        return None

    def _upright_rotation(self, sim_env: Any):
        """The hand orientation that turns the mug's measured axis to vertical (the smallest
        turn from the hand's current orientation)."""
        Rotation = _rot()
        axis = self._object(sim_env)[1][:, 2]
        turn = np.cross(axis, [0.0, 0.0, 1.0])
        sin, cos = float(np.linalg.norm(turn)), float(axis[2])
        rotvec = turn / max(sin, 1e-9) * math.atan2(sin, cos)
        return Rotation.from_rotvec(rotvec) * Rotation.from_matrix(self._eef(sim_env)[1])

    def _carry_goal(self, sim_env: Any, height: float) -> np.ndarray:
        """Grip-site goal that puts the mug's centre over the plate's, the site at ``height``."""
        eef = self._eef(sim_env)[0]
        offset = self._plate(sim_env)[:2] - self._object(sim_env)[0][:2]
        return np.array([eef[0] + offset[0], eef[1] + offset[1], height])

    def _transport_phases(self, sim_env: Any):
        """lift / carry / lower / release / retreat."""
        p = self.params
        eef, eef_rot = self._eef(sim_env)
        mug = self._object(sim_env)[0]
        carry_z = self._table_z + p["carry"]
        flip = self.task == "MugFlip"
        if self.phase in ("lift", "carry", "lower") and self.phase_steps > 8 \
                and not self._holding(sim_env):
            self._regrasp()
            return None
        if self.phase == "lift":
            goal = np.array([self._sp_pos[0], self._sp_pos[1], carry_z])
            if self._reached_pose(sim_env, goal, None, 0.02) or self.phase_steps > 60:
                self._next("carry")
                return None
            return goal, self._grasp_rot, _GRIP_CLOSE, 0.8 * self.speed
        if self.phase == "carry":
            rot = self._upright_rotation(sim_env) if flip else self._grasp_rot
            goal = self._carry_goal(sim_env, carry_z)
            offset = float(np.linalg.norm(goal[:2] - eef[:2]))
            turned = not flip or (rot * _rot().from_matrix(eef_rot).inv()).magnitude() \
                < p["flip_tol"]
            if (offset < 0.008 and turned) or self.phase_steps > 150:
                self._carry_rot = rot
                self._next("lower")
                return None
            return goal, rot, _GRIP_CLOSE, self.speed
        if self.phase == "lower":
            plate_top = self._plate(sim_env)[2] + self._plate_top_offset
            bottom = mug[2] - self._half_height * max(self._object(sim_env)[1][2, 2], 0.5)
            dz = plate_top + p["place_gap"] - bottom
            if dz > -0.003 or self.phase_steps > 100:
                self._next("release")
                return None
            goal = self._carry_goal(sim_env, eef[2] + dz)
            return goal, self._carry_rot, _GRIP_CLOSE, 0.5 * self.speed
        if self.phase == "release":
            if self.phase_steps >= 10:
                self._retreat_from = self._sp_pos.copy()
                self._next("retreat")
                return None
            return self._sp_pos.copy(), self._carry_rot, _GRIP_OPEN, self.speed
        if self.phase == "retreat":
            # back out along the hand's pointing direction (MugFlip: it points sideways), rise
            pointing = eef_rot[:, 2] if flip else np.zeros(3)
            goal = self._retreat_from - p["retreat"] * pointing \
                + np.array([0.0, 0.0, p["retreat"]])
            return goal, self._carry_rot, _GRIP_OPEN, 0.6 * self.speed
        # give_up
        return self._sp_pos.copy(), _rot().from_matrix(eef_rot), _GRIP_OPEN, self.speed

    def _plan(self, sim_env: Any):
        if self.phase in ("approach", "descend", "close"):
            return self._grasp_phases(sim_env)
        return self._transport_phases(sim_env)

    _plan_PickPlaceMug = _plan
    _plan_MugFlip = _plan
