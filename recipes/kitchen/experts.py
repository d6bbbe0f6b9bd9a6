"""A scripted expert for Franka Kitchen's four subtasks, and Minari-format demo generation.

Part of the kitchen recipe (not of the library): `utils.py` beside it calls `generate_demos`
when the demonstration data set is missing.

`KitchenExpert` plans in end-effector pose space (`rfmp_rl.envs.kitchen`'s ``ee_pose`` action:
site position, quaternion ``xyzw``, two finger positions). Each subtask is a list of segments
whose targets are computed, when the segment starts, from the TRUE positions of the kitchen's
MuJoCo sites (``microhandle_site``, ``kettle_site``, ``light_site``, ``slide_site``) and hinge
bodies; a setpoint moves to each target at a bounded speed (3.5 cm and 0.15 rad per step in
free space, 1.2 to 2.5 cm per step in contact; slerp for the orientation) and then waits, up to
a few steps, until the gripper is within about 1.5 cm of it. Orientations: *forward* (the
gripper pointing along +y, into the kitchen, fingers closing along x) for the microwave handle,
the light switch and the slide cabinet;
*down* (fingers closing along y) for the kettle handle. The gripper is symmetric: of a
target orientation and its half turn about the approach axis, the one closer to the current
setpoint is used.

1. microwave: in front of the vertical handle bar, onto it, close, pull the handle along the
   door's arc (about the door hinge; the gripper keeps its orientation, the bar turns between
   the fingers) to -0.7 rad, open, back off;
2. kettle: above the handle, down onto it, close, lift 8 cm, carry towards the top-left burner
   (18 cm short of the goal position, within the 0.3 threshold and clear of the range hood),
   lower, open, lift 7 cm, back off;
3. light switch: to the right of the switch lever, push it 16 cm to the left, back off;
4. slide cabinet: to the left of the handle, push it 22 cm to the right, back off.

`generate_demos` runs the expert from consecutive seeds and writes the successful episodes in
Minari's dataset layout (`write_minari_kitchen`: the ``D4RL/kitchen`` observation layout, actions
as a Dict of ``ee_pose`` and ``joint_velocity``). Command line::

    python recipes/kitchen/experts.py --n 100 --out ~/.minari/datasets/rfmp/kitchen-expert-v0
    python recipes/kitchen/experts.py --evaluate 100 --seed-start 0
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from recipes.expert_demos import (
    act_batched,
    attempts_limit,
    collect_successes,
    print_summary,
    success_summary,
)
from rfmp_rl.envs.kitchen import (
    KITCHEN_MAX_STEPS,
    KITCHEN_TASKS,
    KitchenInstance,
    quat_xyzw_from_mat,
)

__all__ = ["KitchenExpert", "ExpertPolicy", "run_expert_episode", "evaluate_expert",
           "generate_demos", "write_minari_kitchen", "FORWARD", "DOWN", "HOME"]

#: Site frame columns (x, y, z) in the world: gripper pointing +y, fingers closing along x.
FORWARD = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])
#: Gripper pointing down (-z), fingers closing along y.
DOWN = np.array([[-1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, -1.0]])
OPEN, CLOSED = 0.04, 0.0
#: A via point between subtasks: near the site position of the kitchen's reset posture.
HOME = np.array([-0.40, 0.20, 2.05])


def _rz(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


@dataclass
class Segment:
    """A move of the setpoint: to ``target`` (computed when the segment starts) or along
    ``path`` (setpoints ``(pos, rot, fingers)`` computed when it starts)."""

    name: str
    target: Callable[[KitchenInstance], tuple[np.ndarray, np.ndarray, float]] | None = None
    path: Callable[[KitchenInstance], list[tuple[np.ndarray, np.ndarray, float]]] | None = None
    speed: float | None = None  # m per step (default: the expert's free-space speed)
    settle: int = 6  # at most this many extra steps waiting for the gripper
    tol: float = 0.015  # m
    hold: int = 0  # steps to hold the target after reaching it (fingers closing)


class KitchenExpert:
    """Waypoint expert over the four subtasks in order (module docstring).

    Args:
        speed: setpoint speed in free space, m per step (12.5 steps per second); moves in
            contact have their own, slower speeds.
        rot_speed: setpoint turn rate, rad per step.
        noise_std: Gaussian noise added to every commanded position (m), for diverse demos.
        seed: seed of that noise.

    Example::

        inst = KitchenInstance(); inst.reset(0)
        expert = KitchenExpert(); expert.reset(inst)
        for _ in range(280):
            inst.step_pose(expert.act(inst))
        inst.success  # True
    """

    def __init__(self, *, speed: float = 0.035, rot_speed: float = 0.15,
                 noise_std: float = 0.0, seed: int | None = None) -> None:
        self.speed, self.rot_speed = float(speed), float(rot_speed)
        self.noise_std = float(noise_std)
        self.rng = np.random.default_rng(seed)
        self.segments = self._plan()
        self.index = 0
        self.queue: list[np.ndarray] = []
        self.extra = 0
        self.setpoint: np.ndarray | None = None

    # ----- the plan --------------------------------------------------------------------------
    def _plan(self) -> list[Segment]:
        s = []
        # 1. microwave: grasp the vertical handle bar, pull it along the door's arc
        s.append(Segment("microwave: in front", lambda k: (
            k.site_pos("microhandle_site") + [0.0, -0.12, 0.0], FORWARD, OPEN)))
        s.append(Segment("microwave: onto handle", lambda k: (
            k.site_pos("microhandle_site") + [0.0, 0.01, 0.0], FORWARD, OPEN),
            speed=0.015, settle=8, tol=0.01))
        s.append(Segment("microwave: close", lambda k: (
            k.site_pos("microhandle_site") + [0.0, 0.01, 0.0], FORWARD, CLOSED), hold=4))
        s.append(Segment("microwave: pull", path=self._microwave_arc, settle=4, tol=0.03))
        s.append(Segment("microwave: open", lambda k: (
            self.setpoint[:3], self._setpoint_rot(), OPEN), hold=3))
        s.append(Segment("microwave: back off", lambda k: (
            self.setpoint[:3] + [0.0, -0.10, 0.08], FORWARD, OPEN), settle=0))
        # 2. kettle: top grasp of the handle, carry it to the top-left burner
        s.append(Segment("kettle: via home", lambda k: (HOME, FORWARD, OPEN), settle=0))
        s.append(Segment("kettle: above", lambda k: (
            k.site_pos("kettle_site") + [0.0, 0.0, 0.12], DOWN, OPEN)))
        s.append(Segment("kettle: onto handle", lambda k: (
            k.site_pos("kettle_site") + [0.0, 0.0, -0.01], DOWN, OPEN),
            speed=0.015, settle=8, tol=0.008))
        s.append(Segment("kettle: close", lambda k: (
            k.site_pos("kettle_site") + [0.0, 0.0, -0.01], DOWN, CLOSED), hold=3))
        s.append(Segment("kettle: lift", lambda k: (
            self.setpoint[:3] + [0.0, 0.0, 0.08], DOWN, CLOSED), speed=0.02))
        s.append(Segment("kettle: carry", lambda k: (
            self._kettle_goal_site() + [0.0, 0.0, 0.08], DOWN, CLOSED), speed=0.02))
        s.append(Segment("kettle: lower", lambda k: (
            self._kettle_goal_site() + [0.0, 0.0, 0.01], DOWN, CLOSED), speed=0.015,
            settle=8, tol=0.01))
        s.append(Segment("kettle: open", lambda k: (
            self.setpoint[:3], DOWN, OPEN), hold=3))
        s.append(Segment("kettle: lift off", lambda k: (
            self.setpoint[:3] + [0.0, 0.0, 0.07], DOWN, OPEN), speed=0.015, settle=8,
            tol=0.02))
        s.append(Segment("kettle: back off", lambda k: (
            self.setpoint[:3] + [0.0, -0.12, 0.02], DOWN, OPEN), settle=0))
        # 3. light switch: push the lever to the left
        s.append(Segment("light: via home", lambda k: (HOME, FORWARD, CLOSED), settle=0))
        s.append(Segment("light: right of lever", lambda k: (
            k.site_pos("light_site") + [0.07, -0.12, 0.0], FORWARD, CLOSED), settle=10,
            tol=0.03))
        s.append(Segment("light: beside lever", lambda k: (
            k.site_pos("light_site") + [0.06, 0.0, 0.005], FORWARD, CLOSED), speed=0.015,
            settle=12, tol=0.008))
        s.append(Segment("light: push", lambda k: (
            self.setpoint[:3] + [-0.16, 0.0, 0.0], FORWARD, CLOSED), speed=0.02, settle=4,
            tol=0.03))
        s.append(Segment("light: back off", lambda k: (
            self.setpoint[:3] + [0.0, -0.10, 0.0], FORWARD, CLOSED), settle=0))
        # 4. slide cabinet: push the handle to the right
        s.append(Segment("slide: left of handle", lambda k: (
            k.site_pos("slide_site") + [-0.07, -0.12, 0.0], FORWARD, CLOSED)))
        s.append(Segment("slide: beside handle", lambda k: (
            k.site_pos("slide_site") + [-0.06, 0.0, 0.0], FORWARD, CLOSED), speed=0.015,
            settle=8, tol=0.01))
        s.append(Segment("slide: push", lambda k: (
            self.setpoint[:3] + [0.22, 0.0, 0.0], FORWARD, CLOSED), speed=0.025, settle=4,
            tol=0.03))
        s.append(Segment("slide: back off", lambda k: (
            self.setpoint[:3] + [0.0, -0.10, 0.0], FORWARD, CLOSED), settle=0))
        return s

    def _setpoint_rot(self) -> np.ndarray:
        from scipy.spatial.transform import Rotation

        return Rotation.from_quat(self.setpoint[3:7]).as_matrix()

    @staticmethod
    def _kettle_goal_site() -> np.ndarray:
        """Where the expert puts ``kettle_site``: towards the top-left burner, 18 cm short of the
        goal position (-0.23, 0.75, 1.62) in y (within the 0.3 threshold on the 7-D kettle
        pose), which keeps the arm clear of the range hood."""
        return np.array([-0.25, 0.57, 1.62 + 0.259])

    def _microwave_arc(self, k: KitchenInstance) -> list[tuple[np.ndarray, np.ndarray, float]]:
        hinge = k.data.body("microdoorroot").xpos.copy()
        start = self.setpoint[:3].copy()
        angle0 = float(k.data.joint("microwave").qpos[0])
        goal = -0.7
        n = int(np.ceil(abs(goal - angle0) * np.linalg.norm((start - hinge)[:2])
                        / (0.75 * self.speed))) + 1
        out = []
        for a in np.linspace(0.0, goal - angle0, n)[1:]:  # the orientation is kept: the bar
            out.append((hinge + _rz(a) @ (start - hinge), FORWARD, CLOSED))  # turns in the grip
        return out

    # ----- running ---------------------------------------------------------------------------
    def reset(self, inst: KitchenInstance) -> None:
        """Start a new episode from the instance's current (reset) state."""
        self.index = 0
        self.queue = []
        self.extra = 0
        self.setpoint = inst.ee_target_now()
        self._start_segment(inst)

    @property
    def phase(self) -> str:
        """Name of the current segment (``"done"`` after the last)."""
        return self.segments[self.index].name if self.index < len(self.segments) else "done"

    def _interpolate(self, pos: np.ndarray, rot: np.ndarray, fingers: float,
                     speed: float) -> list[np.ndarray]:
        from scipy.spatial.transform import Rotation, Slerp

        p0, q0 = self.setpoint[:3], self.setpoint[3:7]
        q1 = quat_xyzw_from_mat(rot)
        flipped = quat_xyzw_from_mat(rot @ np.diag([-1.0, -1.0, 1.0]))  # the same grip
        if abs(float(flipped @ q0)) > abs(float(q1 @ q0)):
            q1 = flipped
        if float(q1 @ q0) < 0:
            q1 = -q1
        angle = 2 * np.arccos(np.clip(abs(float(q1 @ q0)), 0.0, 1.0))
        n = max(1, int(np.ceil(max(np.linalg.norm(pos - p0) / speed,
                                   angle / self.rot_speed))))
        slerp = Slerp([0.0, 1.0], Rotation.from_quat([q0, q1]))
        out = []
        for s in np.linspace(0.0, 1.0, n + 1)[1:]:
            q = slerp([s]).as_quat()[0]
            if float(q @ q0) < 0:
                q = -q
            out.append(np.concatenate([p0 + s * (pos - p0), q, [fingers, fingers]]))
        return out

    def _start_segment(self, inst: KitchenInstance) -> None:
        while self.index < len(self.segments):
            seg = self.segments[self.index]
            speed = self.speed if seg.speed is None else seg.speed
            if seg.path is not None:
                self.queue = []
                for pos, rot, fingers in seg.path(inst):
                    self.queue += self._interpolate(pos, rot, fingers, speed)
                    self.setpoint = self.queue[-1]
            else:
                pos, rot, fingers = seg.target(inst)
                self.queue = self._interpolate(np.asarray(pos, dtype=np.float64), rot,
                                               fingers, speed)
            self.queue += [self.queue[-1]] * seg.hold
            self.extra = 0
            return

    def act(self, inst: KitchenInstance) -> np.ndarray:
        """The next 9-D ``ee_pose`` action."""
        while self.index < len(self.segments):
            seg = self.segments[self.index]
            if self.queue:
                self.setpoint = self.queue.pop(0)
                break
            pos, _ = inst.controller.ee_pose()
            if self.extra < seg.settle and np.linalg.norm(pos - self.setpoint[:3]) > seg.tol:
                self.extra += 1
                break
            self.index += 1
            self._start_segment(inst)
        action = self.setpoint.copy()
        if self.noise_std > 0:
            action[:3] += self.rng.normal(0.0, self.noise_std, 3)
        return action

    def info(self) -> dict[str, Any]:
        """The expert's settings (written into the data set's metadata)."""
        return {"name": "KitchenExpert", "speed": self.speed, "rot_speed": self.rot_speed,
                "noise_std": self.noise_std, "segments": [s.name for s in self.segments]}


class ExpertPolicy:
    """A batched TorchRL policy running one `KitchenExpert` per instance of a
    `FrankaKitchenEnv` (``ee_pose`` actions).

    Each expert is reset when its instance reports ``step_count == 0`` (a fresh episode).

    Example::

        env = FrankaKitchenEnv([2], seeds=[0, 1])
        out = env.rollout(280, ExpertPolicy(env), break_when_any_done=False,
                          break_when_all_done=True)
        out["next", "success"][:, -1, 0]  # tensor([True, True])
    """

    def __init__(self, env: Any, **expert_kwargs: Any) -> None:
        self.env = getattr(env, "base_env", env)
        if self.env.action_space_name != "ee_pose":
            raise ValueError("ExpertPolicy acts with ee_pose actions; the env has "
                             f"action_space={self.env.action_space_name!r}")
        self.experts = [KitchenExpert(**expert_kwargs) for _ in self.env.instances]

    def __call__(self, tensordict: Any) -> Any:
        """Write ``action (N, 9)`` into ``tensordict``."""
        return act_batched(tensordict, self.experts, self.env.instances)

def run_expert_episode(inst: KitchenInstance, expert: KitchenExpert, seed: int,
                       max_steps: int = KITCHEN_MAX_STEPS) -> dict[str, Any]:
    """One expert episode from ``seed``: the Minari-layout record and the outcome.

    Returns:
        ``observations`` (``observation (T+1, 59)``, ``achieved_goal`` / ``desired_goal``
        dicts of ``(T+1, d)`` per task), ``actions`` (``ee_pose (T, 9)``,
        ``joint_velocity (T, 9)``), ``rewards (T,)``, ``terminations (T,)``, ``truncations
        (T,)``, ``success``, ``completed`` (per subtask), ``steps``, ``phase`` (where the expert
        was at the end).
    """
    inst.reset(seed)
    expert.reset(inst)
    obs = [inst.raw_obs]
    poses, joints, rewards, terms, truncs = [], [], [], [], []
    for t in range(max_steps):
        pose = expert.act(inst)
        inst.step_pose(pose)
        poses.append(pose)
        joints.append(inst.last_joint_action.copy())
        rewards.append(inst.last_reward)
        obs.append(inst.raw_obs)
        terms.append(inst.success)
        truncs.append(t + 1 >= max_steps and not inst.success)
        if inst.success:
            break

    def stack(key: str) -> Any:
        if key == "observation":
            return np.stack([np.asarray(o[key], dtype=np.float64) for o in obs])
        return {task: np.stack([np.asarray(o[key][task], dtype=np.float64) for o in obs])
                for task in KITCHEN_TASKS}

    return {
        "observations": {k: stack(k) for k in ("observation", "achieved_goal", "desired_goal")},
        "actions": {"ee_pose": np.stack(poses), "joint_velocity": np.stack(joints)},
        "rewards": np.asarray(rewards, dtype=np.float64),
        "terminations": np.asarray(terms, dtype=bool),
        "truncations": np.asarray(truncs, dtype=bool),
        "success": inst.success,
        "completed": dict(inst.completed),
        "steps": len(poses),
        "phase": expert.phase,
    }


def evaluate_expert(n_episodes: int = 100, *, seed_start: int = 0, verbose: bool = True,
                    instance_kwargs: dict[str, Any] | None = None,
                    **expert_kwargs: Any) -> dict[str, Any]:
    """Run the expert on seeds ``seed_start ..``; success = all four subtasks.

    Returns:
        ``success_rate``, ``subtask_rates`` (per subtask), ``failed_seeds`` (with the phase
        reached), ``mean_steps`` (successful episodes), ``seconds_per_episode``.
    """
    inst = KitchenInstance(**(instance_kwargs or {}))
    expert = KitchenExpert(**expert_kwargs)
    failed, lengths = {}, []
    counts = dict.fromkeys(KITCHEN_TASKS, 0)
    start = time.perf_counter()
    for seed in range(seed_start, seed_start + n_episodes):
        ep = run_expert_episode(inst, expert, seed)
        for task, done in ep["completed"].items():
            counts[task] += int(done)
        if ep["success"]:
            lengths.append(ep["steps"])
        else:
            failed[seed] = ep["phase"] + " | missing: " + ", ".join(
                t for t, d in ep["completed"].items() if not d)
        if verbose:
            print(f"[kitchen] seed {seed}: {'ok' if ep['success'] else 'FAILED'} "
                  f"({ep['steps']} steps, {ep['phase']})", flush=True)
    seconds = time.perf_counter() - start
    inst.close()
    result = success_summary(
        n_episodes, failed, lengths, seconds,
        subtask_rates={t: c / max(n_episodes, 1) for t, c in counts.items()})
    if verbose:
        print(json.dumps(result), flush=True)
    return result



def _spaces(inst: KitchenInstance) -> tuple[Any, Any]:
    """The data set's spaces: the kitchen env's observation Dict (as in ``D4RL/kitchen``) and
    the action Dict of ``ee_pose`` and ``joint_velocity``."""
    from gymnasium import spaces

    low = np.array([-np.inf] * 7 + [0.0, 0.0])
    high = np.array([np.inf] * 7 + [0.04, 0.04])
    action_space = spaces.Dict({
        "ee_pose": spaces.Box(low, high, dtype=np.float64),
        "joint_velocity": spaces.Box(-1.0, 1.0, (9,), dtype=np.float64),
    })
    return inst.sim.observation_space, action_space


def write_minari_kitchen(path: str | Path, records: Sequence[dict[str, Any]], *,
                         dataset_id: str = "rfmp/kitchen-expert-v0",
                         extra_metadata: dict[str, Any] | None = None) -> Path:
    """Write expert episodes (`run_expert_episode` records) as a Minari dataset at ``path``.

    The folder gets Minari's layout (``data/metadata.json``, ``data/main_data.hdf5``, one
    ``episode_<i>`` group per record), written through Minari's own storage class, so
    ``minari.MinariDataset(path / "data")`` and `rfmp_rl.data.read_minari` both read it.
    Observations follow ``D4RL/kitchen``'s Dict (``observation (T+1, 59)``,
    ``achieved_goal`` / ``desired_goal`` per task); actions are a Dict of ``ee_pose (T, 9)``
    and ``joint_velocity (T, 9)``. The episode's seed is stored as Minari does (its ``seed``
    attribute).

    Raises:
        FileExistsError: ``path`` already holds a dataset (nothing is overwritten).
    """
    try:
        from minari.data_collector.episode_buffer import EpisodeBuffer
        from minari.dataset.minari_storage import MinariStorage
    except ImportError as exc:
        raise ImportError("writing the kitchen dataset needs Minari: pip install minari==0.5.4 "
                          "(in rfmp_rl[dev]); reading it needs only h5py") from exc

    path = Path(path)
    data = path / "data"
    if (data / "metadata.json").exists():
        raise FileExistsError(f"{data / 'metadata.json'}: a Minari dataset is already there; "
                              "remove it or choose another --out")
    if data.exists() and any(data.iterdir()):
        raise FileExistsError(f"{data}: the folder is not empty; remove it or choose another "
                              "--out")
    if not records:
        raise ValueError("write_minari_kitchen: no episodes to write")
    inst = KitchenInstance()
    obs_space, act_space = _spaces(inst)
    inst.close()
    # Minari resolves its files against the storage folder: it gets an absolute one. The data
    # set is written into a private sibling folder and moved into place once complete, so an
    # interrupted run leaves no half-written dataset at ``path``.
    path.mkdir(parents=True, exist_ok=True)
    partial = path.resolve() / f".data.partial-{os.getpid()}"
    try:
        storage = MinariStorage.new(partial, observation_space=obs_space,
                                    action_space=act_space, jpeg_encoding=False)
        storage.update_episodes([
            EpisodeBuffer(id=i, seed=int(rec["seed"]), observations=rec["observations"],
                          actions=rec["actions"], rewards=rec["rewards"],
                          terminations=rec["terminations"], truncations=rec["truncations"],
                          infos={})
            for i, rec in enumerate(records)
        ])
        import minari

        storage.update_metadata({
            "dataset_id": dataset_id,
            "minari_version": minari.__version__,
            "algorithm_name": "KitchenExpert (recipes/kitchen/experts.py)",
            **(extra_metadata or {}),
        })
        os.replace(partial, data)  # onto a missing or empty folder: atomic
    finally:
        if partial.exists():
            shutil.rmtree(partial)
    return path


def generate_demos(
    n_success: int,
    path: str | Path,
    *,
    seed_start: int = 0,
    max_attempts: int | None = None,
    verbose: bool = True,
    **expert_kwargs: Any,
) -> dict[str, Any]:
    """Collect ``n_success`` successful expert episodes (all four subtasks) and write them with
    `write_minari_kitchen`.

    The expert runs from seeds ``seed_start, seed_start + 1, ...``; failed episodes are dropped
    (their seeds are listed). The metadata holds ``expert`` (settings, success rate, attempts,
    kept seeds) and ``control_freq_hz``.

    Raises:
        RuntimeError: fewer than ``n_success`` successes within ``max_attempts`` (default
            ``2 * n_success + 20``; nothing is written).

    Example::

        info = generate_demos(2, "/tmp/kitchen-demo")
        info["successes"]  # 2
    """
    from rfmp_rl.envs.kitchen import KITCHEN_CONTROL_FREQ

    max_attempts = attempts_limit(n_success, max_attempts)
    inst = KitchenInstance()
    expert = KitchenExpert(**expert_kwargs)

    def run(seed: int) -> tuple[dict[str, Any], bool, int]:
        rec = run_expert_episode(inst, expert, seed)
        rec["seed"] = seed
        return rec, rec["success"], rec["steps"]

    records, kept, failed, seconds = collect_successes(
        run, n_success, max_attempts, seed_start=seed_start, close=inst.close,
        label="[kitchen]", verbose=verbose)
    attempts = len(kept) + len(failed)
    rate = len(records) / attempts
    write_minari_kitchen(path, records, extra_metadata={
        "control_freq_hz": KITCHEN_CONTROL_FREQ,
        "expert": {**expert.info(), "success_rate": rate, "successes": len(records),
                   "attempts": attempts, "seeds": kept},
    })
    result = {"path": str(path), "successes": len(records), "attempts": attempts,
              "success_rate": rate, "seeds": kept, "failed_seeds": failed,
              "steps": int(sum(r["steps"] for r in records)),
              "seconds_per_episode": seconds / attempts}
    if verbose:
        print_summary(result)
    return result

def main(argv: Sequence[str] | None = None) -> dict[str, Any]:
    """Command line: generate demos, or ``--evaluate N`` to measure the expert's success rate.

    Example::

        python recipes/kitchen/experts.py --evaluate 100 > expert_eval.txt
    """
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--n", type=int, default=100, help="successful demos to collect")
    parser.add_argument("--out", default=None,
                        help="dataset folder (default data/kitchen/kitchen-expert-v0)")
    parser.add_argument("--seed-start", type=int, default=0)
    parser.add_argument("--max-attempts", type=int, default=None)
    parser.add_argument("--noise-std", type=float, default=0.0, help="position noise (m)")
    parser.add_argument("--evaluate", type=int, default=None, metavar="N",
                        help="only run N episodes and print the success rate")
    parser.add_argument("--quiet", action="store_true", help="print the summary line only")
    args = parser.parse_args(argv)
    if args.evaluate is not None:
        result = evaluate_expert(args.evaluate, seed_start=args.seed_start,
                                 verbose=not args.quiet, noise_std=args.noise_std)
    else:
        out = args.out or str(Path("data") / "kitchen" / "kitchen-expert-v0")
        result = generate_demos(args.n, out, seed_start=args.seed_start,
                                max_attempts=args.max_attempts, verbose=not args.quiet,
                                noise_std=args.noise_std)
    if args.quiet:
        print_summary(result)
    return result


if __name__ == "__main__":
    main()
