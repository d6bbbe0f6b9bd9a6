"""Push-T and Sphere Push-T (the paper's first benchmark) as a batched TorchRL env.

The simulator is ``gym-pusht`` (pymunk; a 512 x 512 px workspace, a PD-controlled disc pushes a
T-shaped block onto a fixed goal pose; the action is the disc's target position in px; 10 Hz).
`PushTEnv` holds ``N`` simulator instances and steps them as one batch ``[N]`` so the policy
runs batched; instance ``i`` is reset with seed ``seeds[i]`` (deterministic seeding).

Observations, as Diffusion Policy uses them:

- ``obs_type="state"``: ``observation (N, 20)`` = the 9 block keypoints (18, px) followed by
  the agent position (2, px); the keypoints are the block pose applied to Diffusion Policy's 9
  local keypoints (`PUSHT_LOCAL_KEYPOINTS`, recovered from its data set: they reproduce its
  ``keypoint`` array to 1e-5 px at the median step).
- ``obs_type="image"``: ``pixels (N, 3, 96, 96) uint8`` and ``observation (N, 2)`` = the agent
  position.

Protocol (the paper's): at most 500 steps, the episode ends early when the coverage of the goal
exceeds 95%, and the score is the maximum coverage over the episode (``max_coverage``). The
reward is Diffusion Policy's clipped ``min(coverage / 0.95, 1)`` for comparison.

Sphere Push-T (``space="sphere"``): the workspace is normalised to ``[-1.5, 1.5]^2`` and mapped
from the plane ``z = 1`` onto S^2 by the stereographic projection (`pusht_to_sphere`); every
observed point (agent, keypoints) is a unit 3-vector and the action is a point on S^2 that is
mapped back to the plane (`sphere_to_pusht`) to drive the simulator.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.data import Bounded, Categorical, Composite, Unbounded
from torchrl.envs import EnvBase, TransformedEnv

from rfmp_rl import keys
from rfmp_rl.envs.transforms import observation_windows
from rfmp_rl.manifolds.stereographic import plane_to_sphere, sphere_to_plane

__all__ = [
    "PushTEnv",
    "make_pusht_env",
    "pusht_episodes",
    "pusht_to_sphere",
    "sphere_to_pusht",
    "block_keypoints",
    "PUSHT_LOCAL_KEYPOINTS",
    "PUSHT_MAX_STEPS",
    "PUSHT_SUCCESS_COVERAGE",
]

#: Diffusion Policy's 9 block keypoints in the block frame (px), median over its data set.
PUSHT_LOCAL_KEYPOINTS = torch.tensor(
    [
        [9.270, 90.041],
        [-60.983, -1.187],
        [60.913, -1.393],
        [-0.271, 25.544],
        [-14.065, 122.816],
        [39.003, 32.857],
        [-39.966, 32.730],
        [-16.824, 62.863],
        [23.541, -1.700],
    ],
    dtype=torch.float64,
)
PUSHT_MAX_STEPS = 500
PUSHT_SUCCESS_COVERAGE = 0.95
_WORKSPACE = 512.0
_EXTENT = 1.5  # Sphere Push-T: the workspace spans [-1.5, 1.5]^2 on the plane z = 1


def block_keypoints(block_pose: torch.Tensor) -> torch.Tensor:
    """``(..., 3)`` block poses ``(x, y, angle)`` -> ``(..., 9, 2)`` keypoints in px.

    Example:
        >>> kp = block_keypoints(torch.tensor([256.0, 256.0, 0.0], dtype=torch.float64))
        >>> kp.shape, kp[0].tolist()
        (torch.Size([9, 2]), [265.27, 346.041])
    """
    local = PUSHT_LOCAL_KEYPOINTS.to(block_pose.dtype)
    c, s = torch.cos(block_pose[..., 2:3]), torch.sin(block_pose[..., 2:3])  # (..., 1)
    x = c * local[:, 0] - s * local[:, 1] + block_pose[..., 0:1]  # (..., 9)
    y = s * local[:, 0] + c * local[:, 1] + block_pose[..., 1:2]
    return torch.stack([x, y], dim=-1)


def pusht_to_sphere(xy: torch.Tensor) -> torch.Tensor:
    """Push-T px ``(..., 2)`` -> S^2 ``(..., 3)``: normalise to ``[-1.5, 1.5]``, then project.

    Example:
        >>> pusht_to_sphere(torch.tensor([256.0, 256.0]))
        tensor([0., 0., 1.])
    """
    plane = (xy / _WORKSPACE * 2.0 - 1.0) * _EXTENT
    return plane_to_sphere(plane)


def sphere_to_pusht(p: torch.Tensor) -> torch.Tensor:
    """Inverse of `pusht_to_sphere`: S^2 ``(..., 3)`` -> px ``(..., 2)``."""
    plane = sphere_to_plane(p)
    return (plane / _EXTENT + 1.0) / 2.0 * _WORKSPACE


def pusht_episodes(
    episodes: Sequence[TensorDict], obs_type: str = "state", space: str = "euclidean"
) -> list[TensorDict]:
    """Diffusion Policy Push-T episodes (from `rfmp_rl.data.read_dp_zarr`) -> policy episodes.

    Output per step: ``observation`` (state: ``(20,)`` px keypoints + agent, or ``(30,)`` on
    S^2: 10 unit vectors; image: ``(2,)`` agent px or ``(3,)`` on S^2), ``pixels (96, 96, 3)
    uint8`` for images, and ``action`` ``(2,)`` px or ``(3,)`` on S^2.

    Example:
        >>> ep = TensorDict({"state": torch.tensor([[256.0, 256.0, 256.0, 256.0, 0.0]]),
        ...                  "keypoint": block_keypoints(torch.tensor([[256.0, 256.0, 0.0]])),
        ...                  "action": torch.tensor([[256.0, 256.0]])}, [1])
        >>> out = pusht_episodes([ep], "state", "sphere")[0]
        >>> out["observation"].shape, out["action"].tolist()
        (torch.Size([1, 30]), [[0.0, 0.0, 1.0]])
    """
    _check(obs_type, space)
    out = []
    for ep in episodes:
        n = ep.batch_size[0]
        agent = ep["state"][:, :2].float()  # (T, 2)
        action = ep["action"].float()  # (T, 2)
        if obs_type == "state":
            points = torch.cat([ep["keypoint"].float(), agent[:, None]], dim=1)  # (T, 10, 2)
        else:
            points = agent[:, None]  # (T, 1, 2)
        if space == "sphere":
            points = pusht_to_sphere(points.double()).float()
            action = pusht_to_sphere(action.double()).float()
        sample = TensorDict({keys.OBSERVATION: points.reshape(n, -1), keys.ACTION: action}, [n])
        if obs_type == "image":
            sample.set(keys.PIXELS, ep["img"])
        out.append(sample)
    return out


def _check(obs_type: str, space: str) -> None:
    if obs_type not in ("state", "image"):
        raise ValueError(f"Push-T obs_type must be 'state' or 'image', got {obs_type!r}")
    if space not in ("euclidean", "sphere"):
        raise ValueError(f"Push-T space must be 'euclidean' or 'sphere', got {space!r}")


class PushTEnv(EnvBase):
    """A batch of ``gym-pusht`` simulators as one TorchRL env.

    Args:
        batch_size: ``[N]``, the number of simulators.
        obs_type: ``"state"`` or ``"image"`` (see the module docstring).
        space: ``"euclidean"`` or ``"sphere"``.
        max_steps: episode limit (the paper: 500).
        seeds: ``N`` reset seeds (default ``100000 + i``); a ``seed`` entry ``(N,)`` in the reset
            TensorDict overrides them.

    Output keys: ``observation``, ``pixels`` (image), ``agent_pos (N, 2)`` px, ``coverage``,
    ``max_coverage`` (the score), ``success``, ``reward``, ``done``/``terminated``/``truncated``,
    ``step_count``. A finished simulator is frozen: later actions are ignored and it keeps
    reporting ``done``, so ``rollout(..., break_when_any_done=False)`` can run the whole batch.

    Example:
        >>> env = PushTEnv([2], seeds=[100000, 100001])
        >>> td = env.reset()
        >>> td["observation"].shape, td["max_coverage"].shape
        (torch.Size([2, 20]), torch.Size([2, 1]))
        >>> out = env.rollout(3, break_when_any_done=False)
        >>> out["next", "step_count"][:, -1, 0].tolist()
        [3, 3]
    """

    def __init__(
        self,
        batch_size: Sequence[int] | torch.Size,
        obs_type: str = "state",
        space: str = "euclidean",
        max_steps: int = PUSHT_MAX_STEPS,
        seeds: Sequence[int] | None = None,
        device: str | torch.device = "cpu",
    ) -> None:
        from gym_pusht.envs.pusht import PushTEnv as _Sim

        _check(obs_type, space)
        batch_size = torch.Size(batch_size)
        if len(batch_size) != 1:
            raise ValueError(f"PushTEnv: batch_size must be [N], got {list(batch_size)}")
        super().__init__(batch_size=batch_size, device=device)
        self.obs_type, self.space, self.max_steps = obs_type, space, int(max_steps)
        n = batch_size[0]
        self.seeds = list(range(100000, 100000 + n)) if seeds is None else [int(s) for s in seeds]
        if len(self.seeds) != n:
            raise ValueError(f"PushTEnv: {len(self.seeds)} seeds for a batch of {n}")
        sim_obs = "pixels_agent_pos" if obs_type == "image" else "state"
        self.sims = [_Sim(obs_type=sim_obs, render_mode="rgb_array") for _ in range(n)]
        self._finished = np.zeros(n, dtype=bool)
        self._last: list[dict] = [{} for _ in range(n)]
        self._make_specs()

    # ----- specs -------------------------------------------------------------------------------
    def _obs_dim(self) -> int:
        points = 10 if self.obs_type == "state" else 1
        return points * (3 if self.space == "sphere" else 2)

    def _make_specs(self) -> None:
        batch, dev = self.batch_size, self.device
        spec = {
            keys.OBSERVATION: Unbounded((*batch, self._obs_dim()), dtype=torch.float32, device=dev),
            "agent_pos": Unbounded((*batch, 2), dtype=torch.float32, device=dev),
            "coverage": Unbounded((*batch, 1), dtype=torch.float32, device=dev),
            "max_coverage": Unbounded((*batch, 1), dtype=torch.float32, device=dev),
            "success": Categorical(2, (*batch, 1), dtype=torch.bool, device=dev),
            "step_count": Unbounded((*batch, 1), dtype=torch.int64, device=dev),
        }
        if self.obs_type == "image":
            spec[keys.PIXELS] = Bounded(0, 255, (*batch, 3, 96, 96), dtype=torch.uint8, device=dev)
        self.observation_spec = Composite(spec, shape=batch, device=dev)
        self.state_spec = Composite(
            seed=Unbounded((*batch,), dtype=torch.int64, device=dev), shape=batch, device=dev
        )
        if self.space == "sphere":
            self.action_spec = Bounded(-1.0, 1.0, (*batch, 3), dtype=torch.float32, device=dev)
        else:
            self.action_spec = Bounded(0.0, _WORKSPACE, (*batch, 2), dtype=torch.float32,
                                       device=dev)
        self.reward_spec = Unbounded((*batch, 1), dtype=torch.float32, device=dev)
        self.full_done_spec = Composite(
            {
                name: Categorical(2, (*batch, 1), dtype=torch.bool, device=dev)
                for name in ("done", "terminated", "truncated")
            },
            shape=batch,
            device=dev,
        )

    def _set_seed(self, seed: int | None) -> None:
        if seed is not None:
            self.seeds = [int(seed) + i for i in range(self.batch_size[0])]

    # ----- observation assembly ---------------------------------------------------------------
    def _observe(self, i: int, sim_obs) -> dict:
        sim = self.sims[i]
        agent = np.asarray(sim.agent.position, dtype=np.float64)
        out = {"agent_pos": agent}
        if self.obs_type == "state":
            pose = torch.tensor([*sim.block.position, sim.block.angle], dtype=torch.float64)
            points = torch.cat([block_keypoints(pose), torch.from_numpy(agent)[None]])  # (10, 2)
        else:
            points = torch.from_numpy(agent)[None]  # (1, 2)
            out[keys.PIXELS] = np.ascontiguousarray(sim_obs["pixels"].transpose(2, 0, 1))
        if self.space == "sphere":
            points = pusht_to_sphere(points)
        out[keys.OBSERVATION] = points.reshape(-1).numpy()
        return out

    def _pack(self, coverage, max_cov, count, terminated, truncated) -> TensorDict:
        n, dev = self.batch_size[0], self.device
        f32 = {"dtype": torch.float32, "device": dev}
        td = TensorDict(
            {
                keys.OBSERVATION: torch.as_tensor(
                    np.stack([o[keys.OBSERVATION] for o in self._last]), **f32
                ),
                "agent_pos": torch.as_tensor(np.stack([o["agent_pos"] for o in self._last]), **f32),
                "coverage": torch.as_tensor(coverage, **f32).reshape(n, 1),
                "max_coverage": torch.as_tensor(max_cov, **f32).reshape(n, 1),
                "success": torch.as_tensor(max_cov > PUSHT_SUCCESS_COVERAGE, device=dev).reshape(
                    n, 1
                ),
                "step_count": torch.as_tensor(count, dtype=torch.int64, device=dev).reshape(n, 1),
                "reward": torch.as_tensor(
                    np.clip(coverage / PUSHT_SUCCESS_COVERAGE, 0.0, 1.0), **f32
                ).reshape(n, 1),
                "terminated": torch.as_tensor(terminated, device=dev).reshape(n, 1),
                "truncated": torch.as_tensor(truncated, device=dev).reshape(n, 1),
            },
            batch_size=self.batch_size,
            device=dev,
        )
        td.set("done", td["terminated"] | td["truncated"])
        if self.obs_type == "image":
            td.set(keys.PIXELS, torch.as_tensor(np.stack([o[keys.PIXELS] for o in self._last]),
                                                device=dev))
        return td

    # ----- dynamics ---------------------------------------------------------------------------
    def _reset(self, tensordict: TensorDictBase | None, **kwargs) -> TensorDictBase:
        n = self.batch_size[0]
        seeds = self.seeds
        if tensordict is not None and tensordict.get("seed", None) is not None:
            seeds = [int(s) for s in tensordict.get("seed").reshape(-1).tolist()]
        self.seeds = list(seeds)
        self._coverage = np.zeros(n)
        self._max_coverage = np.zeros(n)
        self._count = np.zeros(n, dtype=np.int64)
        self._terminated = np.zeros(n, dtype=bool)
        self._truncated = np.zeros(n, dtype=bool)
        for i, sim in enumerate(self.sims):
            sim_obs, _ = sim.reset(seed=seeds[i])
            self._coverage[i] = sim._get_coverage()
            self._last[i] = self._observe(i, sim_obs)
        self._max_coverage[:] = self._coverage
        td = self._pack(self._coverage, self._max_coverage, self._count, self._terminated,
                        self._truncated).exclude("reward")  # a reward comes with a step only
        td.set("seed", torch.as_tensor(seeds, dtype=torch.int64, device=self.device))
        return td

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        action = tensordict.get(keys.ACTION).detach().to(torch.float64)
        if self.space == "sphere":
            action = sphere_to_pusht(action)  # (N, 2) px
        action = action.cpu().numpy()
        for i, sim in enumerate(self.sims):
            if self._terminated[i] or self._truncated[i]:
                continue  # frozen
            sim_obs, _, _, _, info = sim.step(action[i])
            self._coverage[i] = float(info["coverage"])
            self._max_coverage[i] = max(self._max_coverage[i], self._coverage[i])
            self._count[i] += 1
            self._terminated[i] = self._coverage[i] > PUSHT_SUCCESS_COVERAGE
            self._truncated[i] = self._count[i] >= self.max_steps and not self._terminated[i]
            self._last[i] = self._observe(i, sim_obs)
        return self._pack(self._coverage, self._max_coverage, self._count, self._terminated,
                          self._truncated)


def make_pusht_env(
    batch_size: Sequence[int] | torch.Size,
    *,
    obs_horizon: int = 2,
    **env_kwargs,
) -> TransformedEnv:
    """`PushTEnv` with the observation windows an RFMP policy reads
    (`rfmp_rl.envs.observation_windows`).

    ``obs_window (N, 2, D)`` = ``[o^{s-T_o}, o^{s-1}]``, the oldest and the latest of the last
    ``obs_horizon`` (T_o) observations (after a reset the first is repeated); for images
    ``pixels_window (N, 2, 3, 96, 96)`` the same way; with T_o > 2 ``obs_gap (N,)`` = T_o.
    ``InitTracker`` writes ``is_init`` for ``MultiStepActorWrapper``.

    Example:
        >>> env = make_pusht_env([2], space="sphere", obs_horizon=4)
        >>> td = env.reset()
        >>> td["obs_window"].shape, td["obs_gap"].tolist()
        (torch.Size([2, 2, 30]), [4.0, 4.0])
    """
    env = PushTEnv(batch_size, **env_kwargs)
    cameras = {keys.PIXELS: keys.PIXELS_WINDOW} if env.obs_type == "image" else None
    windows = observation_windows(obs_horizon, {keys.OBSERVATION: keys.OBS_WINDOW}, cameras)
    return TransformedEnv(env, windows)
