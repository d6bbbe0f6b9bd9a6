"""Simulated stand-ins for the paper's real-robot tasks (Sec. "Real Robotic Experiments"):
``PickPlaceMug`` and ``MugFlip``, two robosuite 1.5 environments with a single arm (a Panda in
`rfmp_rl.envs.robosuite`).

Both are built as robosuite's ``Lift`` is (a `ManipulationEnv` with a ``TableArena``, objects
placed by a placement sampler at every reset, a sparse reward and ``_check_success``):

- ``PickPlaceMug``: a mug stands upright on the left half of the table (``y > 0``, random
  position, handle turned by up to 45 degrees from ``+x``); a plate lies on the right half
  (``y < 0``, its position varied by a few centimetres). The robot picks the mug up and puts it
  on the plate; the gripper can point down the whole time, so the orientation stays nearly
  constant (the paper's "Pick & Place").
- ``MugFlip``: the mug lies on its side (its axis horizontal, its opening pointing left, 40 to
  110 degrees from ``+x``, resting on its body and its handle, the handle on a random side);
  the robot grasps it across its body, turns it upright (the hand turns by 90 degrees about the
  closing axis of the fingers) and puts it on the plate (the paper's "Mug Flipping").

Success (both): the mug rests on the plate (its centre within `PLATE_RADIUS` - 2 cm of the
plate's centre, its bottom within 1.5 cm of the plate's top), upright (its axis within 15
degrees of vertical) and released (no contact with the gripper).

The objects are robosuite primitives: the mug a `CompositeObject` (a cylinder 6 cm wide and
10 cm tall, a dark disc marking its opening and a handle of three boxes), the plate a thin
`CylinderObject`. Importing this module registers both environments with robosuite
(``robosuite.make("PickPlaceMug", robots="Panda", ...)``).

Example::

    import robosuite
    import rfmp_rl.envs.robosuite_mug  # registers the environments
    env = robosuite.make("MugFlip", robots="Panda", has_renderer=False,
                         has_offscreen_renderer=False, use_camera_obs=False)
    obs = env.reset()
    obs["mug_quat"].shape  # (4,)
"""

from __future__ import annotations

from collections import OrderedDict

import numpy as np

try:
    from robosuite.environments.manipulation.manipulation_env import ManipulationEnv
except ImportError as exc:  # pragma: no cover - robosuite ships with rfmp_rl[sim]
    raise ImportError(
        "the mug tasks need robosuite: pip install 'rfmp_rl[sim]' (robosuite==1.5.1)"
    ) from exc
from robosuite.models.arenas import TableArena
from robosuite.models.objects import CompositeObject, CylinderObject
from robosuite.models.tasks import ManipulationTask
from robosuite.utils.observables import Observable, sensor
from robosuite.utils.placement_samplers import SequentialCompositeSampler, UniformRandomSampler
from robosuite.utils.transform_utils import convert_quat, mat2quat

__all__ = [
    "MugObject",
    "PickPlaceMug",
    "MugFlip",
    "MUG_RADIUS",
    "MUG_HALF_HEIGHT",
    "PLATE_RADIUS",
    "PLATE_HALF_HEIGHT",
]

#: Mug body radius and half height (m).
MUG_RADIUS = 0.03
MUG_HALF_HEIGHT = 0.05
#: How far the handle reaches out of the body, and its half extent along the mug axis (m).
HANDLE_REACH = 0.025
HANDLE_HALF_SPAN = 0.022
HANDLE_HALF_WIDTH = 0.006
#: Plate radius and half thickness (m).
PLATE_RADIUS = 0.075
PLATE_HALF_HEIGHT = 0.006
#: Success tolerances: mug centre to plate centre (xy), mug bottom to plate top, tilt.
SUCCESS_XY = PLATE_RADIUS - 0.02
SUCCESS_DZ = 0.015
SUCCESS_TILT_COS = float(np.cos(np.deg2rad(15.0)))


class MugObject(CompositeObject):
    """A mug from primitives: a cylinder body, a dark disc at its opening, a three-box handle.

    The body frame sits at the centre of the cylinder, ``z`` along its axis toward the opening,
    the handle on the ``+x`` side (its density a tenth of the body's).

    Args:
        name: the object's name (prefix of its MuJoCo elements).
        rgba: body and handle colour.
        density: body density (kg/m^3).
        friction: sliding, torsional and rolling friction of the body.

    Example::

        mug = MugObject("mug")
        mug.root_body  # 'mug_root'
    """

    def __init__(self, name: str, rgba=(0.92, 0.92, 0.9, 1.0), density: float = 300.0,
                 friction=(1.5, 0.01, 0.0001)) -> None:
        r, h, reach, span = MUG_RADIUS, MUG_HALF_HEIGHT, HANDLE_REACH, HANDLE_HALF_SPAN
        arm = (reach / 2 + 0.002, HANDLE_HALF_WIDTH, 0.004)  # handle arms (4 mm into the body)
        bar = (0.004, HANDLE_HALF_WIDTH, span)
        dark = (0.25, 0.2, 0.18, 1.0)
        super().__init__(
            name=name,
            total_size=[r + reach, r + reach, h],
            geom_types=["cylinder", "cylinder", "box", "box", "box"],
            geom_sizes=[(r, h), (r - 0.004, 0.0008), arm, arm, bar],
            geom_locations=[(0, 0, 0), (0, 0, h), (r + reach / 2 - 0.002, 0, span - arm[2]),
                            (r + reach / 2 - 0.002, 0, -span + arm[2]), (r + reach - bar[0], 0, 0)],
            geom_names=["body", "opening", "handle_top", "handle_bottom", "handle_bar"],
            geom_rgbas=[rgba, dark, rgba, rgba, rgba],
            geom_frictions=[friction, None, friction, friction, friction],
            density=[density, 1.0, density / 10, density / 10, density / 10],
            obj_types=["all", "visual", "all", "all", "all"],
            locations_relative_to_center=True,
            sites=[{"name": "opening", "pos": (0, 0, h), "size": "0.004", "rgba": "0 0 1 0",
                    "type": "sphere"}],
        )


def _lying_rotation(direction: float, side: float) -> np.ndarray:
    """Orientation of a mug resting on its side: the axis (toward the opening) horizontal along
    yaw ``direction``, the handle down on the ``side`` (+1 left of the axis, -1 right) at the
    angle where its outer bar touches the table too (its stable rest)."""
    axis = np.array([np.cos(direction), np.sin(direction), 0.0])
    across = side * np.array([-np.sin(direction), np.cos(direction), 0.0])
    # The handle's angle from straight down where the lower edge of its bar (radius R, half
    # width w) touches the table: R cos(a) + w sin(a) = MUG_RADIUS.
    reach, half_width = MUG_RADIUS + HANDLE_REACH, HANDLE_HALF_WIDTH
    down = np.arctan2(half_width, reach) + np.arccos(MUG_RADIUS / np.hypot(reach, half_width))
    handle = np.cos(down) * np.array([0.0, 0.0, -1.0]) + np.sin(down) * across
    return np.stack([handle, np.cross(axis, handle), axis], axis=1)  # columns: x, y, z


class PickPlaceMug(ManipulationEnv):
    """Pick an upright mug and put it on a plate (see the module docstring).

    Args:
        robots: one single-arm robot (``"Panda"``).
        table_full_size: table size (m).
        table_friction: MuJoCo friction of the table top.
        use_object_obs: add the object observables ``mug_pos``, ``mug_quat``, ``plate_pos``,
            ``gripper_to_mug_pos``.
        reward_scale: scale of the reward (the sparse reward is ``reward_scale`` on success).
        reward_shaping: dense reward: reaching the mug (tanh of the distance, at most 1), grasping
            it (0.25) and carrying it toward the plate (at most 1), scaled to ``reward_scale``
            at most.
        placement_initializer: a sampler placing ``mug`` and ``plate`` (default: the regions of
            the module docstring).
        **kwargs: `ManipulationEnv` arguments (controller, cameras, rendering, ``control_freq``,
            ``horizon``, ``ignore_done``, ``hard_reset``, ...).

    Example::

        env = PickPlaceMug(robots="Panda", has_renderer=False, has_offscreen_renderer=False,
                           use_camera_obs=False)
        env.reset()
        env._check_success()  # False
    """

    #: Whether the mug starts on its side (MugFlip) or upright.
    lying = False
    #: Mug placement: x and y ranges (table frame, m) and yaw range of the handle (rad).
    mug_x_range = (-0.10, 0.06)
    mug_y_range = (0.04, 0.20)
    mug_yaw_range = (-np.pi / 4, np.pi / 4)
    #: Plate placement ranges (table frame, m).
    plate_x_range = (-0.04, 0.04)
    plate_y_range = (-0.20, -0.14)

    def __init__(
        self,
        robots,
        table_full_size=(0.8, 0.8, 0.05),
        table_friction=(1.0, 5e-3, 1e-4),
        use_object_obs: bool = True,
        reward_scale: float | None = 1.0,
        reward_shaping: bool = False,
        placement_initializer=None,
        **kwargs,
    ) -> None:
        self.table_full_size = table_full_size
        self.table_friction = table_friction
        self.table_offset = np.array((0, 0, 0.8))
        self.reward_scale = reward_scale
        self.reward_shaping = reward_shaping
        self.use_object_obs = use_object_obs
        self.placement_initializer = placement_initializer
        kwargs.setdefault("initialization_noise", "default")
        super().__init__(robots=robots, base_types="default", **kwargs)

    # ----- task -------------------------------------------------------------------------------
    def reward(self, action=None) -> float:
        """Sparse: 1 on success; with shaping, reaching + grasping + carrying (at most 1 before
        success); both scaled by ``reward_scale``."""
        if self._check_success():
            reward = 1.0
        elif self.reward_shaping:
            gripper = self.robots[0].gripper
            dist = self._gripper_to_target(gripper=gripper, target=self.mug.root_body,
                                           target_type="body", return_distance=True)
            reward = 1 - np.tanh(10.0 * dist)
            if self._check_grasp(gripper=gripper, object_geoms=self.mug):
                mug = self.sim.data.body_xpos[self.mug_body_id]
                plate = self.sim.data.body_xpos[self.plate_body_id]
                reward += 0.25 + 1 - np.tanh(10.0 * np.linalg.norm(mug[:2] - plate[:2]))
            reward /= 2.25
        else:
            reward = 0.0
        return reward * (self.reward_scale if self.reward_scale is not None else 1.0)

    def _load_model(self) -> None:
        super()._load_model()
        xpos = self.robots[0].robot_model.base_xpos_offset["table"](self.table_full_size[0])
        self.robots[0].robot_model.set_base_xpos(xpos)
        arena = TableArena(table_full_size=self.table_full_size,
                           table_friction=self.table_friction, table_offset=self.table_offset)
        arena.set_origin([0, 0, 0])
        self.mug = MugObject("mug")
        self.plate = CylinderObject(
            name="plate", size=[PLATE_RADIUS, PLATE_HALF_HEIGHT], rgba=[0.95, 0.55, 0.7, 1.0],
            density=3000.0, friction=(1.0, 0.005, 0.0001),
        )
        if self.placement_initializer is None:
            sampler = SequentialCompositeSampler(name="ObjectSampler")
            common = {"ensure_object_boundary_in_range": False, "ensure_valid_placement": True,
                      "reference_pos": self.table_offset, "rotation_axis": "z"}
            sampler.append_sampler(UniformRandomSampler(
                name="MugSampler", mujoco_objects=self.mug, x_range=self.mug_x_range,
                y_range=self.mug_y_range, rotation=self.mug_yaw_range, z_offset=0.001, **common))
            sampler.append_sampler(UniformRandomSampler(
                name="PlateSampler", mujoco_objects=self.plate, x_range=self.plate_x_range,
                y_range=self.plate_y_range, rotation=0.0, z_offset=0.001, **common))
            self.placement_initializer = sampler
        self.model = ManipulationTask(
            mujoco_arena=arena,
            mujoco_robots=[robot.robot_model for robot in self.robots],
            mujoco_objects=[self.mug, self.plate],
        )

    def _setup_references(self) -> None:
        super()._setup_references()
        self.mug_body_id = self.sim.model.body_name2id(self.mug.root_body)
        self.plate_body_id = self.sim.model.body_name2id(self.plate.root_body)

    def _setup_observables(self) -> OrderedDict:
        observables = super()._setup_observables()
        if not self.use_object_obs:
            return observables
        modality = "object"

        @sensor(modality=modality)
        def mug_pos(obs_cache):
            return np.array(self.sim.data.body_xpos[self.mug_body_id])

        @sensor(modality=modality)
        def mug_quat(obs_cache):
            return convert_quat(np.array(self.sim.data.body_xquat[self.mug_body_id]), to="xyzw")

        @sensor(modality=modality)
        def plate_pos(obs_cache):
            return np.array(self.sim.data.body_xpos[self.plate_body_id])

        sensors = [mug_pos, mug_quat, plate_pos]
        arm_prefixes = self._get_arm_prefixes(self.robots[0], include_robot_name=False)
        full_prefixes = self._get_arm_prefixes(self.robots[0])
        sensors += [
            self._get_obj_eef_sensor(full, "mug_pos", f"{arm}gripper_to_mug_pos", modality)
            for arm, full in zip(arm_prefixes, full_prefixes, strict=True)
        ]
        for s in sensors:
            observables[s.__name__] = Observable(name=s.__name__, sensor=s,
                                                 sampling_rate=self.control_freq)
        return observables

    def _reset_internal(self) -> None:
        super()._reset_internal()
        if self.deterministic_reset:
            return
        for pos, quat, obj in self.placement_initializer.sample().values():
            pos, quat = np.array(pos, dtype=np.float64), np.array(quat, dtype=np.float64)
            if obj is self.mug and self.lying:
                # the sampled yaw (wxyz about z) becomes the direction of the opening
                yaw = 2 * np.arctan2(quat[3], quat[0])
                side = 1.0 if np.random.uniform() < 0.5 else -1.0  # noqa: NPY002 (robosuite's RNG)
                quat = convert_quat(mat2quat(_lying_rotation(yaw, side)), to="wxyz")
                pos[2] = self.table_offset[2] + MUG_RADIUS + 0.001
            self.sim.data.set_joint_qpos(obj.joints[0], np.concatenate([pos, quat]))

    def visualize(self, vis_settings) -> None:
        super().visualize(vis_settings=vis_settings)
        if vis_settings["grippers"]:
            self._visualize_gripper_to_target(gripper=self.robots[0].gripper, target=self.mug)

    def mug_axis(self) -> np.ndarray:
        """The mug's axis (bottom to opening) as a world-frame unit vector."""
        return np.array(self.sim.data.body_xmat[self.mug_body_id]).reshape(3, 3)[:, 2]

    def _check_success(self) -> bool:
        """The mug stands upright on the plate and the gripper has let go of it."""
        mug = np.array(self.sim.data.body_xpos[self.mug_body_id])
        plate = np.array(self.sim.data.body_xpos[self.plate_body_id])
        on_plate = np.linalg.norm(mug[:2] - plate[:2]) < SUCCESS_XY
        resting = abs(mug[2] - MUG_HALF_HEIGHT - (plate[2] + PLATE_HALF_HEIGHT)) < SUCCESS_DZ
        upright = self.mug_axis()[2] > SUCCESS_TILT_COS
        if not (on_plate and resting and upright):
            return False
        grippers = self.robots[0].gripper  # {arm: gripper model}
        return not any(self.check_contact(g, self.mug) for g in grippers.values())


class MugFlip(PickPlaceMug):
    """Turn a mug lying on its side upright onto a plate (see the module docstring).

    The mug's opening points along a random yaw in ``mug_yaw_range`` (40 to 110 degrees from
    ``+x``); it rests on its body and its handle. Arguments as
    `PickPlaceMug`'s.

    Example::

        env = MugFlip(robots="Panda", has_renderer=False, has_offscreen_renderer=False,
                      use_camera_obs=False)
        env.reset()
        round(float(env.mug_axis()[2]), 3)  # 0.0: the mug lies on its side
    """

    lying = True
    # The opening points left (the hand ends pointing that way): turned toward +x or -y instead,
    # the hand's 90 degree turn runs the Panda's wrist (joint 6) into its limit.
    mug_yaw_range = (np.deg2rad(40.0), np.deg2rad(110.0))
    mug_x_range = (-0.08, 0.06)
    mug_y_range = (0.06, 0.20)

