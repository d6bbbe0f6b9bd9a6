"""Robots that are not robots: a Gymnasium env (closed loop) and recorded data (open loop).

Both implement `rfmp_deploy.loop.RobotInterface`, so the same controller and run loop that
drive the arm can be checked in simulation and against demonstrations first.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from rfmp_deploy.controller import Controller

__all__ = ["BagReplay", "GymnasiumRobot", "ReplayReport"]


class GymnasiumRobot:
    """A Gymnasium env as a `RobotInterface`: run the deployed controller in simulation.

    The env is reset on construction (and by `reset`). ``read_observation`` returns
    ``observation_fn(latest gym observation)``; ``send_action`` calls ``env.step`` and records
    the reward and the termination flags. After the episode ends, ``send_action`` raises until
    `reset` is called; stop the loop with ``run(..., stop=lambda: robot.done)``.

    Args:
        env: a ``gymnasium.Env`` (``gymnasium`` itself is not imported here).
        observation_fn: gym observation -> the controller's observation dict (low-dim keys and
            camera frames, e.g. ``env.render()`` for a camera). Default: a dict observation is
            passed through; any other observation needs this function.
        action_fn: controller action -> env action (default: cast to the action space's dtype).
        seed: seed of the first reset.

    Attributes:
        rewards: rewards of the current episode.
        terminated, truncated: the flags of the last ``env.step``.
        info: the info dict of the last reset or step.

    Example:
        >>> import gymnasium as gym  # doctest: +SKIP
        >>> robot = GymnasiumRobot(gym.make("MyArmEnv-v0"), observation_fn=lambda o: {
        ...     "eef_pos": o[:3], "eef_quat": o[3:7], "gripper": o[7:8]})  # doctest: +SKIP
        >>> stats = run(Controller("policy.onnx"), robot, stop=lambda: robot.done)  # doctest: +SKIP
        >>> robot.episode_return, robot.terminated  # doctest: +SKIP
        (187.5, True)
    """

    def __init__(
        self,
        env: Any,
        observation_fn: Callable[[Any], Mapping[str, Any]] | None = None,
        action_fn: Callable[[np.ndarray], Any] | None = None,
        seed: int | None = None,
    ) -> None:
        self.env = env
        self.observation_fn = observation_fn
        self.action_fn = action_fn
        self.rewards: list[float] = []
        self.episodes = 0
        self.reset(seed)

    def reset(self, seed: int | None = None) -> None:
        """Reset the env and the episode's bookkeeping."""
        self._observation, self.info = self.env.reset(seed=seed)
        self.rewards = []
        self.terminated = self.truncated = False
        self.episodes += 1

    @property
    def done(self) -> bool:
        """Whether the episode ended (terminated or truncated)."""
        return self.terminated or self.truncated

    @property
    def episode_return(self) -> float:
        return float(sum(self.rewards))

    def read_observation(self) -> dict[str, Any]:
        if self.observation_fn is not None:
            return dict(self.observation_fn(self._observation))
        if isinstance(self._observation, Mapping):
            return dict(self._observation)
        raise TypeError(
            f"the env's observations are {type(self._observation).__name__}, not dicts: pass "
            f"GymnasiumRobot(env, observation_fn=...) mapping them to the model's keys"
        )

    def send_action(self, action: np.ndarray) -> None:
        if self.done:
            raise RuntimeError("the episode has ended; call reset() before sending actions")
        if self.action_fn is not None:
            env_action = self.action_fn(action)
        else:
            dtype = getattr(getattr(self.env, "action_space", None), "dtype", None)
            env_action = np.asarray(action, dtype=dtype) if dtype is not None else action
        self._observation, reward, terminated, truncated, self.info = self.env.step(env_action)
        self.rewards.append(float(reward))
        self.terminated, self.truncated = bool(terminated), bool(truncated)


@dataclass
class ReplayReport:
    """Open-loop errors of the controller's actions against recorded actions.

    Attributes:
        actions: ``(N, D)`` the controller's actions.
        recorded: ``(N, D)`` the recorded actions.
        euclidean_error: ``(N,)`` Euclidean norm of the difference over the Euclidean
            coordinates (raw units, e.g. metres).
        geodesic_error: ``(N, S)`` great-circle angle (radians) for each of the ``S`` sphere
            components; for a quaternion the rotation angle is
            ``2 * min(angle, pi - angle)``.

    Example:
        >>> report = ReplayReport(np.zeros((2, 7)), np.zeros((2, 7)),
        ...                       euclidean_error=np.array([0.01, 0.03]),
        ...                       geodesic_error=np.radians([[2.0], [4.0]]))
        >>> print(report.summary())
        2 steps: Euclidean error mean 0.02, max 0.03; sphere 0 angle mean 3 deg, max 4 deg
    """

    actions: np.ndarray
    recorded: np.ndarray
    euclidean_error: np.ndarray
    geodesic_error: np.ndarray

    @property
    def mean_euclidean_error(self) -> float:
        return float(self.euclidean_error.mean()) if self.euclidean_error.size else 0.0

    @property
    def max_euclidean_error(self) -> float:
        return float(self.euclidean_error.max()) if self.euclidean_error.size else 0.0

    @property
    def mean_geodesic_error(self) -> np.ndarray:
        """``(S,)`` mean angle per sphere component."""
        return self.geodesic_error.mean(axis=0) if len(self.geodesic_error) else np.zeros(0)

    @property
    def max_geodesic_error(self) -> np.ndarray:
        """``(S,)`` max angle per sphere component."""
        return self.geodesic_error.max(axis=0) if len(self.geodesic_error) else np.zeros(0)

    def summary(self) -> str:
        line = (f"{len(self.actions)} steps: Euclidean error mean {self.mean_euclidean_error:.4g}"
                f", max {self.max_euclidean_error:.4g}")
        for i, (m, x) in enumerate(zip(self.mean_geodesic_error, self.max_geodesic_error,
                                       strict=True)):
            line += f"; sphere {i} angle mean {np.degrees(m):.3g} deg, max {np.degrees(x):.3g} deg"
        return line


class BagReplay:
    """Open-loop replay of a recorded episode: feed its observations, compare the actions.

    It is a `RobotInterface` (``read_observation`` yields the recorded observations in order;
    ``send_action`` collects what the controller sends), so it can run under `run` at the
    real rate, or without timing through `replay`. Reading the recording (ROS bag, zarr, HDF5)
    is up to the caller: pass lists and arrays.

    Args:
        observations: the recorded observation dicts, one per step, in the controller's
            format (low-dim keys and camera frames).
        actions: ``(N, D)`` the actions recorded at the same steps.

    Example:
        >>> controller = Controller("policy.onnx", deterministic=True)
        >>> observations = [{"eef_pos": np.array([0.1, 0.0, 0.3]),
        ...                  "eef_quat": np.array([0, 0, 0, 1.0]), "gripper": np.array([0.04]),
        ...                  "wrist": np.zeros((96, 96, 3), np.uint8)}] * 4
        >>> recorded = np.stack([controller.step(o) for o in observations])
        >>> recorded[:, 0] += 0.01   # say the demonstrator was 1 cm further along x
        >>> report = BagReplay(observations, recorded).replay(controller)
        >>> print(f"{report.max_euclidean_error:.3f} m, {report.max_geodesic_error[0]:.3f} rad")
        0.010 m, 0.000 rad
    """

    def __init__(self, observations: Sequence[Mapping[str, Any]], actions: np.ndarray) -> None:
        actions = np.asarray(actions, dtype=np.float64)
        if actions.ndim != 2 or len(actions) != len(observations):
            raise ValueError(f"expected (N, D) actions for N={len(observations)} observations, "
                             f"got shape {actions.shape}")
        self.observations = list(observations)
        self.recorded = actions
        self.sent: list[np.ndarray] = []
        self._index = 0

    def __len__(self) -> int:
        return len(self.observations)

    @property
    def done(self) -> bool:
        """Whether every recorded observation has been read."""
        return self._index >= len(self.observations)

    def read_observation(self) -> dict[str, Any]:
        if self.done:
            raise IndexError("the recording has no more observations")
        observation = self.observations[self._index]
        self._index += 1
        return dict(observation)

    def send_action(self, action: np.ndarray) -> None:
        self.sent.append(np.array(action, dtype=np.float32))

    def rewind(self) -> None:
        """Start over: read from the first observation, forget the sent actions."""
        self._index = 0
        self.sent = []

    def replay(self, controller: Controller) -> ReplayReport:
        """Reset ``controller``, step it through every observation and report the errors."""
        self.rewind()
        controller.reset()
        while not self.done:
            self.send_action(controller.step(self.read_observation()))
        return self.report(controller)

    def report(self, controller: Controller) -> ReplayReport:
        """Errors of the actions sent so far against the recorded ones.

        Args:
            controller: supplies the action manifold (which coordinates are spheres).
        """
        space = controller.meta.action_space
        if self.recorded.shape[1] != space.dim:
            raise ValueError(f"recorded actions have {self.recorded.shape[1]} coordinates, the "
                             f"model's action manifold {space} has {space.dim}")
        n = len(self.sent)
        actions = np.stack(self.sent) if n else np.zeros((0, space.dim), np.float32)
        recorded = self.recorded[:n]
        euclidean, angles = space.errors(actions, recorded)
        return ReplayReport(actions, recorded, euclidean, angles)
