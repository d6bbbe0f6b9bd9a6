"""Scripted expert for robosuite's ToolHang (robomimic's Tool Hang).

Part of the robosuite recipe (not of the library): `experts.make_expert` returns it for
``ToolHang``, so `experts.generate_demos` and `experts.evaluate_expert` write and measure its
demonstrations in the same robomimic HDF5 format as the other tasks::

    python recipes/robosuite/experts.py --task ToolHang --action-space abs_pose --evaluate 100

The scene: a stand (a base with a square tube, 1.0 cm inside, 15 cm tall), the hook frame (an
upside-down L: a 0.75 cm square leg with a cone tip, a 9.5 cm arm at its top and a 1.2 cm post
standing on the arm's free end) and the tool (a wrench: a 3 x 3 x 8 cm grip on a handle with a
ring at each end), both lying on the table. Success is robosuite's: the frame's leg in the tube
and the larger ring hanging on the arm, untouched by the robot.

`ToolHangExpert` plans on the TRUE poses in the simulator like `experts.RobosuiteExpert` (a
setpoint moving toward a per-phase goal at a bounded speed), with goal orientations of any
rotation (`experts.PoseExpert`). A held object's goal pose is turned into a grip-site goal
through the object's pose in the hand, measured when the fingers close.

Phases:

- frame: above the frame's grip, the fingers closing across the leg; descend, close, lift; turn
  the frame upright (its arm along +y) while carrying its tip over the tube; lower it into the
  tube (closed loop on the tip: an integral term removes the arm's steady offset under load),
  open, back the hand out and rise.
- tool: above the tool's grip, the fingers closing across the handle; descend, close, lift;
  carry the tool, flat, with its larger ring over the post and the handle pointing along the
  arm, away from the leg; lower the ring around the post onto the arm; turn the tool 90 degrees
  about the horizontal axis across the arm so that the handle swings down past the arm's end,
  the ring's centre following `SWING`; slide the ring along the arm toward the leg, open, back
  away. The ring's position is closed loop (integral term) from the lowering on, and the tool's
  pose in the hand is re-measured every step of the turn (the grip pivots in the fingers).

`SWING` is the ring centre's path during the turn, in the frame's arm plane (cm, ``u`` along the
arm from its free end outward, ``w`` up from the arm's top), found by a search over ring poses:
the ring (0.98 cm inner radius at its flats, 1.62 cm outer, 0.7 cm thick) stays clear of the arm
and the post by at least 2.1 mm along the whole path. Held square to the arm and slid over its
end, the ring would clear the post and the arm together by 0.1 mm (1.96 cm inside against
1.95 cm); turned about the corner where the post stands on the arm, it clears them by 2.1 mm.

A grasp that closes on nothing sends the expert back to that object's approach (at most
``max_regrasps`` times in all).

Measured (``python recipes/robosuite/experts.py --task ToolHang --action-space <space>
--evaluate 100``, seeds 0-99): see recipes/robosuite/README.md.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from experts import _GRIP_CLOSE, _GRIP_OPEN, PoseExpert, _rot

from rfmp_rl.envs.robosuite import _check

__all__ = ["ToolHangExpert", "TOOLHANG_PARAMS", "SWING"]

#: Geometry and gains (m, rad, steps).
TOOLHANG_PARAMS: dict[str, Any] = {
    "hover": 0.08,          # approach height above a grip
    "min_gap": 0.01,        # finger opening below which a grasp closed on nothing
    "carry_z": 1.24,        # grip-site height while the frame is turned upright
    "transit_z": 1.25,      # grip-site height of the move from the stand to the tool
    "tip_above_tube": 0.03,  # the frame's tip this far above the tube before lowering
    "tip_above_base": 0.02,  # ... and lowered until this far above the stand's base
    "tip_gain": 0.1,        # integral gain on the tip's horizontal error (per step)
    "ring_gain": 0.1,       # integral gain on the ring's position error (per step)
    "ring_correction": 0.01,  # bound of the ring's integral correction (m)
    "swing_steps": 60,      # steps of the 90-degree turn
}

#: The ring centre's path during the turn: (turn angle in degrees, u, w), u and w in cm from the
#: top of the arm's free end (module docstring).
SWING = np.array([
    (0, -0.60, 0.37), (6, -0.66, 0.29), (12, -0.67, 0.21), (18, -0.61, 0.12), (24, -0.55, 0.02),
    (30, -0.49, -0.06), (36, -0.50, -0.16), (42, -0.55, -0.25), (48, -0.64, -0.33),
    (54, -0.78, -0.41), (60, -0.94, -0.47), (66, -1.10, -0.55), (72, -1.26, -0.61),
    (78, -1.42, -0.66), (84, -1.58, -0.70), (90, -1.68, -0.73),
])

# Ring centre targets (turn angle, u, w) before and after the turn: over the post, just above
# it, then (after the turn) slid along the arm past robosuite's "inserted far enough" mark.
_ABOVE_POST, _AT_POST, _HUNG = (0.0, -0.5, 4.0), (0.0, -0.5, 2.1), (90.0, -2.4, -0.85)
_ARM_HALF, _POST_HEIGHT = 0.00375, 0.012  # frame geometry (m): half the arm's thickness, post


def _down(closing: np.ndarray) -> np.ndarray:
    """Grip-site rotation pointing down with the fingers closing along ``closing`` (made
    horizontal)."""
    c = np.array([closing[0], closing[1], 0.0])
    c /= np.linalg.norm(c)
    down = np.array([0.0, 0.0, -1.0])
    return np.stack([c, np.cross(down, c), down], 1)


class ToolHangExpert(PoseExpert):
    """Waypoint planner for ToolHang (see the module docstring). ``task`` must be
    ``"ToolHang"``, ``action_space`` is ``"delta"`` or ``"abs_pose"``; the other arguments are
    `RobosuiteExpert`'s. Call ``reset`` after each env reset, then ``act`` every step::

        env = RobosuiteEnv("ToolHang", [1], action_space="abs_pose", seeds=[0])
        env.reset()
        expert = ToolHangExpert("ToolHang", "abs_pose")
        expert.reset(env.sims[0])
        expert.act(env.sims[0]).shape  # (8,): position, hand quaternion xyzw, gripper
    """

    _TASK_PARAMS = {"ToolHang": TOOLHANG_PARAMS}

    def __init__(self, task: str = "ToolHang", action_space: str = "delta",
                 **expert_kwargs: Any) -> None:
        _check(task, action_space)
        if task != "ToolHang":
            raise ValueError(f"ToolHangExpert: task must be 'ToolHang', got {task!r}")
        super().__init__(task, action_space, **expert_kwargs)

    def reset(self, sim_env: Any) -> None:
        """Start a new episode on ``sim_env`` (a robosuite ToolHang env, just reset)."""
        super().reset(sim_env)
        self.phase = "frame_approach"
        walls = [self._geom(sim_env, f"stand_wall{i}")[0] for i in range(4)]
        self._tube = np.mean(walls, 0)[:2]
        wall = sim_env.sim.model.geom_name2id("stand_wall0")
        self._tube_top = float(walls[0][2] + sim_env.sim.model.geom_size[wall][2])
        self._base_z = float(self._geom(sim_env, "stand_base")[0][2])
        self._held = None        # (position, rotation) of the held object in the grip-site frame
        self._grasp_rot = None
        self._tip_correction = np.zeros(2)
        self._ring_correction = np.zeros(3)
        self._tool_frame = None  # the tool's handle and up axes, and the ring centre, in its frame

    # ----- simulator reads --------------------------------------------------------------------
    @staticmethod
    def _body_pose(sim_env: Any, name: str) -> tuple[np.ndarray, np.ndarray]:
        data, model = sim_env.sim.data, sim_env.sim.model
        i = model.body_name2id(name)
        return np.array(data.body_xpos[i]), np.array(data.body_xmat[i]).reshape(3, 3)

    @staticmethod
    def _geom(sim_env: Any, name: str) -> tuple[np.ndarray, np.ndarray]:
        data, model = sim_env.sim.data, sim_env.sim.model
        i = model.geom_name2id(name)
        return np.array(data.geom_xpos[i]), np.array(data.geom_xmat[i]).reshape(3, 3)

    @staticmethod
    def _site(sim_env: Any, name: str) -> np.ndarray:
        return np.array(sim_env.sim.data.site_xpos[sim_env.sim.model.site_name2id(name)])

    def _in_hand(self, sim_env: Any, body: str) -> tuple[np.ndarray, np.ndarray]:
        """The pose of ``body`` in the grip-site frame."""
        eef, eef_rot = self._eef(sim_env)
        pos, rot = self._body_pose(sim_env, body)
        return eef_rot.T @ (pos - eef), eef_rot.T @ rot

    @staticmethod
    def _site_goal(held, pos: np.ndarray, rot: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The grip-site pose that puts an object held at ``held`` at (``pos``, ``rot``)."""
        held_pos, held_rot = held
        site_rot = rot @ held_rot.T
        return pos - site_rot @ held_pos, site_rot

    def _settled(self, pos: np.ndarray, rot, tol: float = 0.002) -> bool:
        """The setpoint has arrived at the goal (``pos``, ``rot``)."""
        return (np.linalg.norm(self._sp_pos - pos) < tol
                and (rot * self._sp_rot.inv()).magnitude() < 0.02)

    # ----- planning ---------------------------------------------------------------------------
    def _grasp(self, sim_env: Any, name: str, grip: np.ndarray, closing: np.ndarray,
               body: str, after: str, either_way: bool = False):
        """approach / descend / close on a grip at ``grip``, the fingers closing along
        ``closing`` (or ``-closing`` when ``either_way`` and it is the nearer turn); ``None``
        when the phase ended."""
        Rotation = _rot()
        p, eef = self.params, self._eef(sim_env)[0]
        step = self.phase.removeprefix(name + "_")
        if step == "approach":
            rot = Rotation.from_matrix(_down(closing))
            flipped = Rotation.from_matrix(_down(-closing))
            if either_way and (flipped * self._sp_rot.inv()).magnitude() \
                    < (rot * self._sp_rot.inv()).magnitude():
                rot = flipped
            goal = grip + np.array([0.0, 0.0, p["hover"]])
            far = np.linalg.norm(eef[:2] - goal[:2]) > 0.03 \
                or (rot * Rotation.from_matrix(self._eef(sim_env)[1]).inv()).magnitude() > 0.3
            if far and name == "tool":  # travel high: the frame stands in the tube below
                goal[2] = max(goal[2], p["transit_z"])
            if self._reached_pose(sim_env, goal, rot, 0.01) or self.phase_steps > 100:
                self._grasp_rot = rot
                self._next(f"{name}_descend")
                return None
            return goal, rot, _GRIP_OPEN, self.speed
        if step == "descend":
            if self._reached_pose(sim_env, grip, None, 0.005) or self.phase_steps > 60:
                self._next(f"{name}_close")
                return None
            return grip, self._grasp_rot, _GRIP_OPEN, 0.5 * self.speed
        if self.phase_steps >= 12:
            if self._grasp_failed(sim_env):
                self.regrasps += 1
                self._next(f"{name}_approach" if self.regrasps <= self.max_regrasps
                           else "give_up")
                return None
            self._held = self._in_hand(sim_env, body)
            self._next(after)
            return None
        return self._sp_pos.copy(), self._grasp_rot, _GRIP_CLOSE, self.speed

    def _release(self, after: str):
        """Open the fingers where the hand is; after 10 steps, phase ``after``."""
        if self.phase_steps >= 10:
            self._retreat_from, self._retreat_rot = self._sp_pos.copy(), self._sp_rot
            self._next(after)
            return None
        return self._sp_pos.copy(), self._sp_rot, _GRIP_OPEN, self.speed

    def _rise(self, sim_env: Any, z: float, rot, grip: float, tol: float, limit: int,
              after: str):
        """Straight up from where the hand is when the phase starts to the height ``z``;
        phase ``after`` once within ``tol`` of it or after ``limit`` steps."""
        if self.phase_steps == 0:
            eef = self._eef(sim_env)[0]
            self._lift_goal = np.array([eef[0], eef[1], z])
        if self._reached_pose(sim_env, self._lift_goal, None, tol) or self.phase_steps > limit:
            self._next(after)
            return None
        return self._lift_goal, rot, grip, self.speed

    def _plan_frame(self, sim_env: Any):
        Rotation = _rot()
        p = self.params
        eef_rot = self._eef(sim_env)[1]
        frame_pos, frame_rot = self._body_pose(sim_env, "frame_root")
        if self.phase in ("frame_approach", "frame_descend", "frame_close"):
            grip = self._geom(sim_env, "frame_grip_frame")[0]
            return self._grasp(sim_env, "frame", grip, -frame_rot[:, 0], "frame_root",
                               "frame_lift", either_way=True)
        if self.phase == "frame_lift":
            return self._rise(sim_env, p["carry_z"], self._grasp_rot, _GRIP_CLOSE, 0.02, 60,
                              "frame_turn")
        if self.phase in ("frame_turn", "frame_insert"):
            # upright (the frame's z up), its arm (the frame's -x) along +y
            upright = np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
            tip = self._site(sim_env, "frame_tip_site")
            tip_in_frame = frame_rot.T @ (tip - frame_pos)
            height = (self._tube_top + p["tip_above_tube"] if self.phase == "frame_turn"
                      else self._base_z + p["tip_above_base"])
            tip_goal = np.array([self._tube[0], self._tube[1], height])
            pos, rot = self._site_goal(self._held, tip_goal - upright @ tip_in_frame, upright)
            pos[:2] += self._tip_correction
            rot = Rotation.from_matrix(rot)
            error = tip_goal[:2] - tip[:2]
            if self._settled(pos, rot, 0.005):
                self._tip_correction = np.clip(self._tip_correction + p["tip_gain"] * error,
                                               -0.03, 0.03)
            if self.phase == "frame_turn":
                if (self._settled(pos, rot, 0.003) and np.linalg.norm(error) < 0.003) \
                        or self.phase_steps > 150:
                    self._next("frame_insert")
                    return None
                return pos, rot, _GRIP_CLOSE, self.speed
            if tip[2] < self._base_z + p["tip_above_base"] + 0.01 or self.phase_steps > 120:
                self._next("frame_release")
                return None
            return pos, rot, _GRIP_CLOSE, 0.3 * self.speed
        if self.phase == "frame_release":
            return self._release("frame_back")
        if self.phase == "frame_back":  # out along the hand's pointing direction, a little up
            goal = self._retreat_from - 0.08 * eef_rot[:, 2] + np.array([0.0, 0.0, 0.03])
            if self._reached_pose(sim_env, goal, None, 0.02) or self.phase_steps > 40:
                self._next("frame_rise")
                return None
            return goal, self._retreat_rot, _GRIP_OPEN, self.speed
        return self._rise(sim_env, p["transit_z"], self._retreat_rot, _GRIP_OPEN, 0.03, 40,
                          "tool_approach")  # frame_rise

    def _tool_goal(self, sim_env: Any, turn: float, ring: np.ndarray, arm: np.ndarray,
                   up: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The tool's root pose with its larger ring's centre at ``ring``, the handle along
        ``arm`` (away from the leg) turned ``turn`` rad down about ``up x arm``."""
        Rotation = _rot()
        if self._tool_frame is None:
            pos, rot = self._body_pose(sim_env, "tool_root")
            centre = self._site(sim_env, "tool_hole1_center")
            handle = rot.T @ (pos - centre)
            handle /= np.linalg.norm(handle)
            tool_up = rot.T @ np.array([0.0, 0.0, 1.0])
            tool_up -= handle * (tool_up @ handle)
            tool_up /= np.linalg.norm(tool_up)
            axes = np.stack([handle, np.cross(tool_up, handle), tool_up], 1)
            self._tool_frame = (axes, rot.T @ (centre - pos))
        axes, centre = self._tool_frame
        world = np.stack([arm, np.cross(up, arm), up], 1)
        rot = Rotation.from_rotvec(np.cross(up, arm) * turn).as_matrix() @ world @ axes.T
        return ring - rot @ centre, rot

    def _plan_tool(self, sim_env: Any):
        Rotation = _rot()
        p = self.params
        if self.phase in ("tool_approach", "tool_descend", "tool_close"):
            pos, _ = self._body_pose(sim_env, "tool_root")
            handle = pos - self._site(sim_env, "tool_hole1_center")
            closing = np.cross([0.0, 0.0, 1.0], handle)
            closing *= 1.0 if closing[1] >= 0 else -1.0  # toward +y: the wrist's middle range
            grip = self._geom(sim_env, "tool_grip_g0")[0]
            return self._grasp(sim_env, "tool", grip, closing, "tool_root", "tool_lift")
        frame_rot = self._body_pose(sim_env, "frame_root")[1]
        arm, up = -frame_rot[:, 0], frame_rot[:, 2]
        # the top of the arm at its free end
        end = self._geom(sim_env, "frame_hook_frame")[0] + arm * _ARM_HALF \
            - up * _POST_HEIGHT / 2
        if self.phase == "tool_lift":
            return self._rise(sim_env, end[2] + _POST_HEIGHT + 0.06, self._grasp_rot,
                              _GRIP_CLOSE, 0.02, 60, "tool_carry")
        if self.phase in ("tool_carry", "tool_over", "tool_lower", "tool_turn", "tool_slide"):
            if self.phase == "tool_turn":
                turn = min(90.0, 90.0 * self.phase_steps / p["swing_steps"])
                u, w = np.interp(turn, SWING[:, 0], SWING[:, 1]), np.interp(turn, SWING[:, 0],
                                                                               SWING[:, 2])
            else:
                turn, u, w = {"tool_carry": _ABOVE_POST, "tool_over": _AT_POST,
                              "tool_lower": tuple(SWING[0]), "tool_slide": _HUNG}[self.phase]
            ring_goal = end + arm * u / 100 + up * w / 100
            tool_pos, tool_rot = self._tool_goal(sim_env, math.radians(turn), ring_goal, arm, up)
            held = self._in_hand(sim_env, "tool_root") \
                if self.phase in ("tool_turn", "tool_slide") else self._held
            pos, rot = self._site_goal(held, tool_pos, tool_rot)
            error = ring_goal - self._site(sim_env, "tool_hole1_center")
            if self.phase != "tool_carry":
                bound = p["ring_correction"]
                self._ring_correction = np.clip(self._ring_correction + p["ring_gain"] * error,
                                                -bound, bound)
            pos = pos + self._ring_correction
            rot = Rotation.from_matrix(rot)
            if self.phase == "tool_carry":
                if (self._settled(pos, rot) and np.linalg.norm(error) < 0.015) \
                        or self.phase_steps > 150:
                    self._next("tool_over")
                    return None
                return pos, rot, _GRIP_CLOSE, self.speed
            if self.phase in ("tool_over", "tool_lower"):
                if (self._settled(pos, rot) and np.linalg.norm(error) < 0.002) \
                        or self.phase_steps > (80 if self.phase == "tool_over" else 40):
                    self._next("tool_lower" if self.phase == "tool_over" else "tool_turn")
                    return None
                speed = 0.4 if self.phase == "tool_over" else 0.2
                return pos, rot, _GRIP_CLOSE, speed * self.speed
            if self.phase == "tool_turn":
                if self.phase_steps >= p["swing_steps"]:
                    self._next("tool_slide")
                    return None
                return pos, rot, _GRIP_CLOSE, 0.2 * self.speed
            if self.phase_steps > 15:
                self._next("tool_release")
                return None
            return pos, rot, _GRIP_CLOSE, 0.2 * self.speed
        if self.phase == "tool_release":
            return self._release("tool_back")
        if self.phase == "tool_back":  # out along the hand's pointing direction
            goal = self._retreat_from - 0.10 * self._eef(sim_env)[1][:, 2]
            return goal, self._retreat_rot, _GRIP_OPEN, 0.5 * self.speed
        # give_up
        return self._sp_pos.copy(), self._sp_rot, _GRIP_OPEN, self.speed

    def _plan_ToolHang(self, sim_env: Any):
        if self.phase.startswith("frame_"):
            return self._plan_frame(sim_env)
        return self._plan_tool(sim_env)
