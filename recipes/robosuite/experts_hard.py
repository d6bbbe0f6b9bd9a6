"""Scripted expert for robosuite's two-arm TwoArmTransport (robomimic's Transport).

Part of the robosuite recipe (not of the library): `experts.make_expert` returns it for
``TwoArmTransport``, so `experts.generate_demos` and `experts.evaluate_expert` write and measure
its demonstrations in the same robomimic HDF5 format as the single-arm tasks.

Each arm is driven by `ArmDriver`, the setpoint machinery of `experts.RobosuiteExpert` (a
setpoint moved toward a goal grip-site pose at a bounded speed, downward orientation with a yaw,
converted to the 7-D OSC_POSE delta or the 8-D absolute pose of that arm); `TransportExpert`
plans both arms' goals from the TRUE object poses in the simulator. The scene (robosuite's
opposed configuration): robot 0 (at y = -0.81) faces its table with the start bin, whose lid
covers the payload (a hammer); robot 1 (at y = +0.81) faces the table with the target bin,
which holds the trash (a cube), and the trash bin. Success is robosuite's: the payload touches
the target bin's floor and the trash the trash bin's floor.

Phases, robot 0: grasp the lid handle, lift the lid, set it down beside the start bin; grasp the
hammer's handle near its head (fingers across the handle), lift it out of the bin, turn it so
that its handle points to robot 1, hold it over the gap between the tables; once robot 1 holds
it, open and retreat. Robot 1, meanwhile: pick the trash out of the target bin, drop it into the
trash bin, wait above the hand-over point; once robot 0 holds the hammer still, grasp the free
end of its handle, lift it once robot 0 has let go, carry it over the target bin (its centre
over the bin's), lower, open and retreat.

A grasp that closes on nothing sends that arm back to its approach (at most ``max_regrasps``
times per arm).

Measured (``python recipes/robosuite/experts.py --task TwoArmTransport --evaluate 100``, delta
actions): 98 of seeds 0-99 succeed, 438 steps on average (limit 700). The two failures (seeds 33
and 59) are the same: the trash cube slips out of robot 1's fingers while it is carried sideways
to the trash bin and lands on the table between the bins.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from experts import (  # recipes/robosuite/experts.py
    _GRIP_CLOSE,
    _GRIP_OPEN,
    RobosuiteExpert,
    _closest_yaw,
    _object_yaw,
    wrap_angle,
    yaw_of,
)

from rfmp_rl.envs.robosuite import _check

__all__ = ["ArmDriver", "TransportExpert"]


class ArmDriver(RobosuiteExpert):
    """One arm's setpoint driver: `RobosuiteExpert`'s smoothing and action conversion with the
    goal set from outside (``command``), for the arm of robot ``robot``.

    Args:
        robot: index of the robot in ``sim_env.robots``.
        action_space: ``"delta"`` or ``"abs_pose"``.
        noise_std, rot_noise_std, seed, speed, turn_speed: as `RobosuiteExpert`'s.
    """

    def __init__(self, robot: int, action_space: str = "delta", *, noise_std: float = 0.0,
                 rot_noise_std: float = 0.0, seed: int | None = None, speed: float = 0.015,
                 turn_speed: float = 0.06) -> None:
        self.robot, self.task, self.action_space = int(robot), "TwoArmTransport", action_space
        self.noise_std, self.rot_noise_std = float(noise_std), float(rot_noise_std)
        self.speed, self.turn_speed = float(speed), float(turn_speed)
        self.max_regrasps, self.params = 0, {}
        self.rng = np.random.default_rng(seed)
        self.phase, self.phase_steps = "start", 0
        self._sp_pos = None
        self.command: tuple[np.ndarray, float, float, float] | None = None

    def reset(self, sim_env: Any) -> None:
        """Start a new episode: read this arm's frames from ``sim_env`` (just reset)."""
        self.phase, self.phase_steps, self.regrasps = "start", 0, 0
        self._sp_pos = self._sp_rot = None
        self._sp_yaw = 0.0
        self.command = None
        self._read_arm(sim_env, self.robot)

    def start(self, sim_env: Any) -> None:
        """Place the setpoint at the current grip-site pose (before the first command)."""
        if self._sp_pos is None:
            from scipy.spatial.transform import Rotation

            eef, rot = self._eef(sim_env)
            self._sp_pos, self._sp_rot = eef.copy(), Rotation.from_matrix(rot)
            self._sp_yaw = yaw_of(rot)

    def _goal(self, sim_env: Any):
        return self.command

    def go(self, phase: str) -> None:
        """Enter ``phase`` (its step counter restarts)."""
        self.phase, self.phase_steps = phase, 0

    def at(self, sim_env: Any, goal: np.ndarray, tol: float, yaw: float | None = None) -> bool:
        """The setpoint has reached ``goal`` and the grip site is within ``tol`` of it."""
        return self._reached(sim_env, goal, yaw, tol)


# Scene constants (m): the hand-over line over the gap between the tables, the lid's rest place.
_TRANSPORT = {
    "hover": 0.09,           # approach height above a grasp point
    "bin_hover": 0.17,       # the same inside a bin: the fingers stay above its walls (0.96)
    "lid_dz": -0.002,        # grip site relative to the lid handle's centre
    "lid_drop": (-0.17, -0.47, 0.86),  # where the lid handle is let go (beside the start bin)
    "carry_z": 1.10,
    "grip0_along": 0.07,     # robot 0 grasps the handle this far from its centre toward the head
    "grip1_along": -0.08,    # robot 1 grasps this far (toward the free end)
    "handover": (0.0, -0.075, 1.15),  # robot 0's grip point while handing over
    "pay_dz": 0.004,         # grip site above the handle's centre line
    "trash_dz": 0.0,
    "trash_drop_z": 1.00,
    "place_z": 0.90,         # robot 1's grip height when letting the payload go in the bin
    "min_gap": 0.01,
}


class TransportExpert:
    """Two-arm waypoint planner for TwoArmTransport (see the module docstring).

    Args:
        task: ``"TwoArmTransport"``.
        action_space: ``"delta"`` (14-D) or ``"abs_pose"`` (16-D).
        noise_std, rot_noise_std, seed, speed, turn_speed: as `RobosuiteExpert`'s (per arm;
            robot 1's noise generator is seeded with ``seed + 1``).
        max_regrasps: how often each arm retries a grasp that closed on nothing.

    Example::

        env = RobosuiteEnv("TwoArmTransport", [1], seeds=[0])
        td = env.reset()
        expert = TransportExpert()
        expert.reset(env.sims[0])
        action = expert.act(env.sims[0])  # (14,)
    """

    def __init__(self, task: str = "TwoArmTransport", action_space: str = "delta", *,
                 noise_std: float = 0.0, rot_noise_std: float = 0.0, seed: int | None = None,
                 speed: float = 0.015, turn_speed: float = 0.06, max_regrasps: int = 2) -> None:
        _check(task, action_space)
        if task != "TwoArmTransport":
            raise ValueError(f"TransportExpert: task must be 'TwoArmTransport', got {task!r}")
        self.task, self.action_space = task, action_space
        self.max_regrasps = int(max_regrasps)
        self.params = dict(_TRANSPORT)
        kw = {"noise_std": noise_std, "rot_noise_std": rot_noise_std, "speed": speed,
              "turn_speed": turn_speed}
        self.arms = [ArmDriver(r, action_space, seed=None if seed is None else seed + r, **kw)
                     for r in range(2)]

    def info(self) -> dict[str, Any]:
        """The expert's settings, JSON-serialisable (stored with generated demos)."""
        a = self.arms[0]
        return {"name": type(self).__name__, "task": self.task,
                "action_space": self.action_space, "noise_std": a.noise_std,
                "rot_noise_std": a.rot_noise_std, "speed": a.speed, "turn_speed": a.turn_speed,
                "max_regrasps": self.max_regrasps,
                "params": {k: list(v) if isinstance(v, tuple) else v
                           for k, v in self.params.items()}}

    @property
    def phase(self) -> str:
        """Both arms' phases, ``"<robot 0>/<robot 1>"``."""
        return f"{self.arms[0].phase}/{self.arms[1].phase}"

    def reset(self, sim_env: Any) -> None:
        """Start a new episode on ``sim_env`` (a TwoArmTransport env, just reset)."""
        for arm in self.arms:
            arm.reset(sim_env)
        self.arms[0].go("lid_above")
        self.arms[1].go("trash_above")
        self.handed = False  # robot 1 has closed on the handle
        model = sim_env.sim.model
        tr = sim_env.transport
        self._payload = model.body_name2id(tr.payload.root_body)
        self._trash = model.body_name2id(tr.trash.root_body)

    # ----- simulator reads --------------------------------------------------------------------
    def _pose(self, sim_env: Any, body: int) -> tuple[np.ndarray, np.ndarray]:
        data = sim_env.sim.data
        return (np.array(data.body_xpos[body], dtype=np.float64),
                np.array(data.body_xmat[body], dtype=np.float64).reshape(3, 3))

    def _payload_axis(self, sim_env: Any) -> tuple[np.ndarray, np.ndarray]:
        """(handle centre, unit handle direction toward the head in the xy plane)."""
        pos, rot = self._pose(sim_env, self._payload)
        axis = rot[:2, 2]
        return pos, axis / max(float(np.linalg.norm(axis)), 1e-9)

    @staticmethod
    def _across(axis: np.ndarray) -> float:
        """Yaw closing the fingers across a handle along ``axis`` (xy)."""
        return math.atan2(float(axis[1]), float(axis[0]))

    def _regrasp(self, arm: ArmDriver, phase: str) -> None:
        arm.regrasps += 1
        arm.go(phase if arm.regrasps <= self.max_regrasps else "give_up")

    # ----- phase steps both arms use ------------------------------------------------------------
    @staticmethod
    def _move(sim: Any, arm: ArmDriver, goal: np.ndarray, tol: float, limit: int, then: str,
              gripper: float, speed: float, yaw: float | None = None):
        """Drive ``arm`` toward ``goal`` with the wrist at ``arm.yaw``; on to phase ``then`` once
        it is there (`ArmDriver.at` with ``tol`` and ``yaw``) or after ``limit`` steps."""
        if arm.at(sim, goal, tol, yaw) or arm.phase_steps > limit:
            arm.go(then)
            return None
        return goal, arm.yaw, gripper, speed

    @staticmethod
    def _hold(arm: ArmDriver, steps: int, then: str, gripper: float, yaw: float | None = None):
        """Keep ``arm``'s setpoint (wrist at ``yaw``, default ``arm.yaw``) with ``gripper`` for
        ``steps`` steps, then on to phase ``then``."""
        if arm.phase_steps >= steps:
            arm.go(then)
            return None
        return arm._sp_pos.copy(), arm.yaw if yaw is None else yaw, gripper, arm.speed

    def _up(self, arm: ArmDriver) -> np.ndarray:
        """The goal straight above ``arm``'s setpoint at the carrying height."""
        return np.array([arm._sp_pos[0], arm._sp_pos[1], self.params["carry_z"]])

    def _grasp(self, sim: Any, arm: ArmDriver, name: str, point: np.ndarray, hover: float,
               dz: float, above: tuple[float, int], down_speed: float, then: str):
        """Phases ``<name>_above`` (``hover`` over ``point``, the wrist at ``arm.yaw``; tolerance
        and step limit ``above``), ``<name>_down`` (to ``dz`` over ``point``) and ``<name>_close``
        (12 steps; back to ``<name>_above`` if the fingers closed on nothing, else on to
        ``then``)."""
        ph = arm.phase
        if ph == f"{name}_above":
            return self._move(sim, arm, point + [0.0, 0.0, hover], *above, f"{name}_down",
                              _GRIP_OPEN, arm.speed, arm.yaw)
        if ph == f"{name}_down":
            return self._move(sim, arm, point + [0.0, 0.0, dz], 0.006, 50, f"{name}_close",
                              _GRIP_OPEN, down_speed * arm.speed)
        if arm.phase_steps >= 12:
            if arm._gap(sim) < self.params["min_gap"]:
                self._regrasp(arm, f"{name}_above")
            else:
                arm.go(then)
            return None
        return arm._sp_pos.copy(), arm.yaw, _GRIP_CLOSE, arm.speed

    # ----- robot 0: lid, payload, hand-over ---------------------------------------------------
    def _plan0(self, sim: Any, arm: ArmDriver):
        p, ph = self.params, arm.phase
        eef = arm._eef(sim)[0]
        if ph in ("lid_above", "lid_down", "lid_close"):
            if ph == "lid_above":
                arm.yaw = _closest_yaw(math.pi / 2, arm._sp_yaw, math.pi)  # across the handle
            handle = np.array(sim.transport.lid_handle_pos, dtype=np.float64)
            return self._grasp(sim, arm, "lid", handle, p["hover"], p["lid_dz"], (0.015, 80),
                               0.6, "lid_lift")
        if ph == "lid_lift":
            return self._move(sim, arm, self._up(arm), 0.02, 50, "lid_move", _GRIP_CLOSE,
                              0.8 * arm.speed)
        if ph == "lid_move":
            drop = np.array(p["lid_drop"])
            return self._move(sim, arm, np.array([drop[0], drop[1], p["carry_z"]]), 0.03, 80,
                              "lid_lower", _GRIP_CLOSE, arm.speed)
        if ph == "lid_lower":
            return self._move(sim, arm, np.array(p["lid_drop"]), 0.015, 40, "lid_release",
                              _GRIP_CLOSE, 0.8 * arm.speed)
        if ph == "lid_release":
            return self._hold(arm, 8, "lid_clear", _GRIP_OPEN)
        if ph == "lid_clear":
            return self._move(sim, arm, self._up(arm), 0.03, 30, "pay_above", _GRIP_OPEN,
                              arm.speed)
        if ph.startswith("pay"):
            center, axis = self._payload_axis(sim)
            grip = center + p["grip0_along"] * np.array([axis[0], axis[1], 0.0])
            if ph in ("pay_above", "pay_down", "pay_close"):
                if ph == "pay_above":
                    if arm.phase_steps == 0:
                        self._plan_wrist(sim, arm, axis)
                    arm.yaw = _closest_yaw(self._across(axis), arm.yaw, math.pi)
                return self._grasp(sim, arm, "pay", grip, p["bin_hover"], p["pay_dz"],
                                   (0.012, 90), 0.6, "pay_lift")
            if ph == "pay_lift":
                if arm.phase_steps > 8 and (arm._gap(sim) < p["min_gap"]
                                            or eef[2] - center[2] > 0.05):
                    self._regrasp(arm, "pay_above")
                    return None
                return self._move(sim, arm, self._up(arm), 0.02, 50, "pay_carry", _GRIP_CLOSE,
                                  0.8 * arm.speed)
            if ph in ("pay_carry", "pay_hold"):
                # turn the hammer (closed loop on its axis) until its head points to robot 0,
                # the way round planned at the grasp (`_plan_wrist`)
                turn = wrap_angle(-math.pi / 2 - math.atan2(axis[1], axis[0]))
                yaw = _closest_yaw(arm._sp_yaw + turn, arm.hold_yaw, 2 * math.pi)
                hand = np.array(p["handover"])
                goal = np.array([hand[0], hand[1], p["carry_z"]]) if ph == "pay_carry" else hand
                if ph == "pay_carry" and (arm.at(sim, goal, 0.03) or arm.phase_steps > 120):
                    arm.go("pay_hold")
                    return None
                if ph == "pay_hold" and self.handed:
                    arm.go("pay_release")
                    return None
                return goal, yaw, _GRIP_CLOSE, arm.speed if ph == "pay_carry" else 0.5 * arm.speed
            if ph == "pay_release":
                return self._hold(arm, 10, "clear_up", _GRIP_OPEN, arm._sp_yaw)
        if ph == "clear_up":  # straight up first: the open fingers would drag the hammer's head
            if arm.phase_steps == 0:
                arm.clear_goal = arm._sp_pos + [0.0, 0.0, 0.08]
            if arm.at(sim, arm.clear_goal, 0.02) or arm.phase_steps > 25:
                arm.go("retreat")
                return None
            return arm.clear_goal.copy(), arm._sp_yaw, _GRIP_OPEN, arm.speed
        if ph == "retreat":
            goal = np.array([arm._sp_pos[0], -0.40, arm._sp_pos[2]])
            return goal, arm._sp_yaw, _GRIP_OPEN, arm.speed
        return arm._sp_pos.copy(), arm._sp_yaw, _GRIP_OPEN, arm.speed  # give_up

    @staticmethod
    def _plan_wrist(sim: Any, arm: ArmDriver, axis: np.ndarray) -> None:
        """Choose the payload grasp yaw (across the handle: two choices, pi apart) and the way
        the wrist then turns the hammer (head toward robot 0) so that the last wrist joint
        stays mid-range (its limits are +-2.9 rad; it turns opposite to the yaw)."""
        robot = sim.robots[arm.robot]
        q7 = float(sim.sim.data.qpos[robot._ref_joint_pos_indexes[-1]])
        turn = wrap_angle(-math.pi / 2 - math.atan2(axis[1], axis[0]))
        across = _closest_yaw(TransportExpert._across(axis), arm._sp_yaw, math.pi)
        best = None
        for grasp in (across - math.pi, across, across + math.pi):
            for hold in (grasp + turn - 2 * math.pi, grasp + turn, grasp + turn + 2 * math.pi):
                q_grasp, q_hold = q7 - (grasp - arm._sp_yaw), q7 - (hold - arm._sp_yaw)
                cost = max(abs(q_grasp), abs(q_hold)) + 0.2 * abs(grasp - arm._sp_yaw)
                if best is None or cost < best[0]:
                    best = (cost, grasp, hold)
        arm.yaw, arm.hold_yaw = best[1], best[2]

    def holding_still(self, sim: Any) -> bool:
        """Robot 0 holds the hammer at the hand-over point, its handle pointing to robot 1."""
        arm = self.arms[0]
        if arm.phase != "pay_hold" or arm.phase_steps < 10:
            return False
        center, axis = self._payload_axis(sim)
        aligned = abs(wrap_angle(math.atan2(axis[1], axis[0]) + math.pi / 2)) < 0.1
        return aligned and arm.at(sim, np.array(self.params["handover"]), 0.02)

    # ----- robot 1: trash, reception, placing -------------------------------------------------
    def _plan1(self, sim: Any, arm: ArmDriver):
        p, ph = self.params, arm.phase
        eef = arm._eef(sim)[0]
        if ph.startswith("trash"):
            pos, rot = self._pose(sim, self._trash)
            if ph in ("trash_above", "trash_down", "trash_close"):
                if ph == "trash_above":
                    arm.yaw = _closest_yaw(_object_yaw(rot), arm._sp_yaw, math.pi / 2)
                return self._grasp(sim, arm, "trash", pos, p["bin_hover"], p["trash_dz"],
                                   (0.012, 80), 0.6, "trash_lift")
            if ph == "trash_lift":
                if arm.phase_steps > 8 and eef[2] - pos[2] > 0.04:
                    self._regrasp(arm, "trash_above")
                    return None
                return self._move(sim, arm, self._up(arm), 0.02, 50, "trash_carry", _GRIP_CLOSE,
                                  0.8 * arm.speed)
            if ph == "trash_carry":
                bin_pos = np.array(sim.transport.trash_bin_pos, dtype=np.float64)
                goal = np.array([bin_pos[0], bin_pos[1], p["trash_drop_z"]])
                return self._move(sim, arm, goal, 0.02, 80, "trash_release", _GRIP_CLOSE,
                                  arm.speed)
            if ph == "trash_release":
                return self._hold(arm, 8, "wait", _GRIP_OPEN)
        center, axis = self._payload_axis(sim)
        grip = center + p["grip1_along"] * np.array([axis[0], axis[1], 0.0])
        if ph == "wait":
            hand = np.array(p["handover"])
            goal = np.array([hand[0], 0.12, p["carry_z"] + 0.05])
            arm.yaw = _closest_yaw(math.pi / 2, arm._sp_yaw, math.pi)  # across y
            if self.holding_still(sim):
                arm.go("recv_above")
                return None
            return goal, arm.yaw, _GRIP_OPEN, arm.speed
        if ph in ("recv_above", "recv_down", "recv_close"):
            if ph == "recv_above":
                arm.yaw = _closest_yaw(self._across(axis), arm._sp_yaw, math.pi)
            step = self._grasp(sim, arm, "recv", grip, p["hover"], p["pay_dz"], (0.012, 80),
                               0.5, "recv_wait")
            self.handed = self.handed or arm.phase == "recv_wait"  # closed on the handle
            return step
        if ph == "recv_wait":  # robot 0 lets go
            return self._hold(arm, 14, "recv_lift", _GRIP_CLOSE)
        if ph == "recv_lift":
            return self._move(sim, arm, self._up(arm), 0.03, 40, "place_carry", _GRIP_CLOSE,
                              0.6 * arm.speed)
        if ph in ("place_carry", "place_lower"):
            bin_pos = np.array(sim.transport.target_bin_pos, dtype=np.float64)
            shift = bin_pos[:2] - center[:2]  # the hammer's centre over the bin's
            z = p["carry_z"] if ph == "place_carry" else p["place_z"]
            goal = np.array([eef[0] + shift[0], eef[1] + shift[1], z])
            if arm._gap(sim) < p["min_gap"] or abs(eef[2] - center[2]) > 0.08:
                arm.go("give_up")  # the hammer slipped out of the hand
                return None
            if ph == "place_carry":
                if np.linalg.norm(shift) < 0.02 or arm.phase_steps > 120:
                    arm.go("place_lower")
                    return None
                return goal, arm.yaw, _GRIP_CLOSE, arm.speed
            if abs(eef[2] - z) < 0.015 or arm.phase_steps > 60:
                arm.go("place_release")
                return None
            return goal, arm.yaw, _GRIP_CLOSE, 0.6 * arm.speed
        if ph == "place_release":
            return self._hold(arm, 10, "place_clear", _GRIP_OPEN)
        if ph == "place_clear":
            return self._up(arm), arm.yaw, _GRIP_OPEN, arm.speed
        return arm._sp_pos.copy(), arm._sp_yaw, _GRIP_OPEN, arm.speed  # give_up

    # ----- actions ----------------------------------------------------------------------------
    def act(self, sim_env: Any) -> np.ndarray:
        """Both arms' actions for the current step, robot 0's then robot 1's (float64)."""
        actions = []
        for arm, plan in zip(self.arms, (self._plan0, self._plan1), strict=True):
            arm.start(sim_env)
            for _ in range(4):  # a phase may end at once: plan the next one in the same step
                arm.command = plan(sim_env, arm)
                if arm.command is not None:
                    break
            else:  # pragma: no cover
                raise RuntimeError(f"TransportExpert: robot {arm.robot} phases did not settle")
            actions.append(arm.act(sim_env))
        return np.concatenate(actions)
