"""A kinematic point on S^2 driven toward the north pole: closed-loop LASA-on-the-sphere rollouts.

The state is a point ``x`` on the unit sphere; the action is the commanded next point. The env
moves to ``projx(action)`` when it lies within ``max_move`` (geodesic distance) of ``x``, and
otherwise ``max_move`` along the geodesic toward it — exactly how `rfmp_rl.data.lasa_episodes`
encodes the demonstrations (``action_i = x_{i+1}``), so replaying a demonstration's actions
reproduces it. The goal is the north pole, where every LASA demonstration ends.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence

import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.data import Bounded, Categorical, Composite, Unbounded
from torchrl.envs import CatTensors, Compose, EnvBase, TransformedEnv

from rfmp_rl import keys
from rfmp_rl.envs.transforms import observation_windows
from rfmp_rl.manifolds.base import safe_norm
from rfmp_rl.manifolds.sphere import Sphere

__all__ = ["LasaSphereEnv", "make_lasa_sphere_env"]

_S2 = Sphere(2)


class LasaSphereEnv(EnvBase):
    """Kinematic S^2 environment: observe the current point, command the next point.

    One step, with ``x`` the current point, ``y = projx(action)`` and ``d = dist(x, y)``:
    ``x' = y`` if ``d <= max_move`` else ``Exp_x(max_move * Log_x(y) / d)`` (branch-free:
    ``torch.where``). Reward ``-dist(x', goal)``. ``terminated`` when ``dist(x', goal) <=
    goal_tolerance``, ``truncated`` when the episode has taken ``max_steps`` steps; ``done`` is
    their union.

    Entries: ``observation (*B, 3)`` the current point, ``step_count (*B, 1)`` int64 steps
    taken since reset, and ``start (*B, 3)`` the episode's start point (the only state entry;
    it is written by reset and carried along). The dynamics read the state from the input
    tensordict, so partial resets and partial steps work. The action is ``action (*B, 3)``;
    its spec is ``Bounded(-1, 1)`` (unit vectors fit in the cube; anything else is projected
    onto the sphere, a zero vector to the north pole).

    Resets: ``env.reset(TensorDict(start=points, batch_size=env.batch_size))`` starts at
    ``projx(start)`` exactly; otherwise (including TorchRL's automatic resets) batch element
    ``i`` (in flattened order) starts at ``start_points[i % K]``, moved by a random geodesic
    offset of length ``start_noise * sqrt(U)``, ``U ~ Uniform(0, 1)``, in a uniformly random
    direction (roughly uniform over the geodesic disc), drawn from the env's own generator
    (`set_seed`).

    For a batch that finishes at different times, roll out with
    ``env.rollout(n, policy, break_when_all_done=True)``: finished elements are frozen (partial
    steps) instead of being reset.

    Args:
        start_points: ``(K, 3)`` or ``(3,)`` default start points (projected onto S^2).
        batch_size: the env batch size, e.g. ``[N]``; ``[]`` for a single point.
        max_move: the largest geodesic move per step (rad). The default 0.12 is a bit above the
            largest step of any LASA demonstration at ``downsample=10`` (0.099 rad, GShape);
            scale it with the downsampling factor (about ``0.012 * downsample``).
        goal_tolerance: geodesic radius (rad) around the goal that terminates an episode.
        max_steps: episode length before ``truncated``; ``None`` never truncates.
        start_noise: geodesic radius (rad) of the random start perturbation; 0 disables it.
        goal: the goal point, default the north pole ``(0, 0, 1)``.
        seed: seed of the env's generator; ``None`` draws one from torch's global generator.
        device: torch device of the env.
        context: optional constant conditioning ``(*B, K)`` or ``(K,)`` (e.g. a one-hot shape
            id), emitted as the ``context`` observation at every reset and step.
        max_step: deprecated name of ``max_move`` (a `DeprecationWarning`).

    Example:
        >>> env = LasaSphereEnv(torch.tensor([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]), batch_size=[2])
        >>> td = env.rollout(3, lambda td: td.set("action", env.goal.expand(2, 3)))
        >>> td["next", "observation"].shape, td["next", "step_count"][0, -1].item()
        (torch.Size([2, 3, 3]), 3)
        >>> round(-td["next", "reward"][0, 0].item(), 4)  # pi/2 - max_move
        1.4508
    """

    def __init__(
        self,
        start_points: torch.Tensor,
        batch_size: Sequence[int] | torch.Size = (),
        *,
        max_move: float = 0.12,
        goal_tolerance: float = 0.02,
        max_steps: int | None = 300,
        start_noise: float = 0.0,
        goal: torch.Tensor | None = None,
        seed: int | None = None,
        device: torch.device | str | None = None,
        context: torch.Tensor | None = None,
        max_step: float | None = None,
    ) -> None:
        if max_step is not None:
            warnings.warn("LasaSphereEnv: max_step is deprecated, use max_move (the largest "
                          "geodesic move per step, rad)", DeprecationWarning, stacklevel=2)
            max_move = max_step
        super().__init__(device=device, batch_size=torch.Size(batch_size))
        if context is not None:
            context = torch.as_tensor(context, dtype=torch.float32, device=self.device)
            context = context.expand(*self.batch_size, context.shape[-1]).clone()
        self.context = context
        start_points = torch.as_tensor(start_points, dtype=torch.float32, device=self.device)
        if start_points.ndim == 1:
            start_points = start_points.unsqueeze(0)
        if start_points.ndim != 2 or start_points.shape[-1] != 3 or start_points.shape[0] == 0:
            raise ValueError(
                "LasaSphereEnv: start_points must be (K, 3) or (3,), "
                f"got {tuple(start_points.shape)}"
            )
        if not max_move > 0:
            raise ValueError(f"LasaSphereEnv: max_move must be > 0, got {max_move}")
        if max_steps is not None and int(max_steps) < 1:
            raise ValueError(f"LasaSphereEnv: max_steps must be >= 1 or None, got {max_steps}")
        self.start_points = _S2.projx(start_points)  # (K, 3)
        self.max_move = float(max_move)
        self.goal_tolerance = float(goal_tolerance)
        self.max_steps = None if max_steps is None else int(max_steps)
        self.start_noise = float(start_noise)
        if goal is None:
            goal = _S2.origin(dtype=torch.float32, device=self.device)
        self.goal = _S2.projx(torch.as_tensor(goal, dtype=torch.float32, device=self.device))
        self._make_specs()
        if seed is None:
            seed = int(torch.randint(0, 2**62, ()).item())
        self.set_seed(seed)

    # ----- specs -------------------------------------------------------------------------------
    def _make_specs(self) -> None:
        batch = self.batch_size
        self.observation_spec = Composite(
            {
                keys.OBSERVATION: Unbounded((*batch, 3), dtype=torch.float32, device=self.device),
                "step_count": Unbounded((*batch, 1), dtype=torch.int64, device=self.device),
            },
            shape=batch,
            device=self.device,
        )
        if self.context is not None:
            self.observation_spec["context"] = Unbounded(
                (*batch, self.context.shape[-1]), dtype=torch.float32, device=self.device
            )
        # `start` is an input of `reset` only; declaring it as state lets it pass TransformedEnv.
        self.state_spec = Composite(
            start=Unbounded((*batch, 3), dtype=torch.float32, device=self.device),
            shape=batch,
            device=self.device,
        )
        self.action_spec = Bounded(-1.0, 1.0, (*batch, 3), dtype=torch.float32, device=self.device)
        self.reward_spec = Unbounded((*batch, 1), dtype=torch.float32, device=self.device)
        self.full_done_spec = Composite(
            {
                name: Categorical(2, (*batch, 1), dtype=torch.bool, device=self.device)
                for name in ("done", "terminated", "truncated")
            },
            shape=batch,
            device=self.device,
        )

    # ----- seeding -----------------------------------------------------------------------------
    def _set_seed(self, seed: int | None) -> None:
        rng = torch.Generator(device=self.device)
        if seed is None:
            rng.seed()
        else:
            rng.manual_seed(int(seed))
        self.rng = rng

    # ----- dynamics ----------------------------------------------------------------------------
    def _default_starts(self, shape: torch.Size) -> torch.Tensor:
        n = int(torch.Size(shape).numel())
        idx = torch.arange(n, device=self.device) % self.start_points.shape[0]
        x = self.start_points[idx].reshape(*shape, 3)  # (*B, 3)
        if self.start_noise > 0:
            z = torch.randn(x.shape, generator=self.rng, device=self.device)
            direction = _S2.proju(x, z)
            direction = direction / safe_norm(direction)
            u = torch.rand((*shape, 1), generator=self.rng, device=self.device)
            x = _S2.expmap(x, direction * (self.start_noise * u.sqrt()))
        return x

    def _reset(self, tensordict: TensorDictBase | None, **kwargs) -> TensorDictBase:
        shape = self.batch_size
        start = None if tensordict is None else tensordict.get("start", None)
        if start is None:
            x = self._default_starts(shape)
        else:
            start = start.to(device=self.device, dtype=torch.float32)
            x = _S2.projx(start.expand(*shape, 3))
        false = torch.zeros((*shape, 1), dtype=torch.bool, device=self.device)
        out = TensorDict(
            {
                keys.OBSERVATION: x,
                "start": x.clone(),
                "step_count": torch.zeros((*shape, 1), dtype=torch.int64, device=self.device),
                "done": false.clone(),
                "terminated": false.clone(),
                "truncated": false.clone(),
            },
            batch_size=shape,
            device=self.device,
        )
        if self.context is not None:
            out.set("context", self.context.clone())
        return out

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        x = tensordict.get(keys.OBSERVATION)  # (*B, 3)
        target = _S2.projx(tensordict.get(keys.ACTION).to(x.dtype))  # (*B, 3)
        dist = _S2.dist(x, target)  # (*B, 1)
        limited = _S2.expmap(x, _S2.logmap(x, target) * (self.max_move / dist.clamp_min(1e-12)))
        x_next = torch.where(dist <= self.max_move, target, limited)
        count = tensordict.get("step_count")
        moving = tensordict.get("_step", None)  # partial steps: frozen elements keep their state
        if moving is None:
            count = count + 1
        else:
            moving = moving.reshape(*count.shape[:-1], 1)
            x_next = torch.where(moving, x_next, x)
            count = count + moving.to(count.dtype)
        to_goal = _S2.dist(x_next, self.goal.expand_as(x_next))  # (*B, 1)
        terminated = to_goal <= self.goal_tolerance
        if self.max_steps is None:
            truncated = torch.zeros_like(terminated)
        else:
            truncated = count >= self.max_steps
        out = TensorDict(
            {
                keys.OBSERVATION: x_next,
                "step_count": count,
                "reward": -to_goal,
                "done": terminated | truncated,
                "terminated": terminated,
                "truncated": truncated,
            },
            batch_size=tensordict.batch_size,
            device=self.device,
        )
        if self.context is not None:
            out.set("context", self.context.clone())
        return out


def make_lasa_sphere_env(
    start_points: torch.Tensor,
    batch_size: Sequence[int] | torch.Size,
    *,
    obs_horizon: int = 2,
    **env_kwargs,
) -> TransformedEnv:
    """`LasaSphereEnv` with the transforms an RFMP policy reads.

    ``InitTracker`` writes ``is_init`` (needed by ``MultiStepActorWrapper``);
    ``obs_window (*B, 2, 3)`` = ``[o^{s-T_o}, o^{s-1}]`` holds the oldest and the latest of the
    last ``obs_horizon`` (T_o) observations (after a reset the first observation is repeated)
    and, with T_o > 2, ``obs_gap (*B,)`` = T_o (`rfmp_rl.envs.observation_windows`).

    Args:
        start_points: see `LasaSphereEnv`.
        batch_size: see `LasaSphereEnv`.
        obs_horizon: T_o, the observations the window's context is taken from.
        **env_kwargs: forwarded to `LasaSphereEnv` (``max_move``, ``goal_tolerance``,
            ``max_steps``, ``start_noise``, ``goal``, ``seed``, ``device``, ``context``). With a
            ``context`` (e.g. a one-hot shape id per batch element), each window step is
            ``[point, context]`` (``CatTensors``), so one policy can serve several shapes.

    Example:
        >>> env = make_lasa_sphere_env(torch.tensor([1.0, 0.0, 0.0]), batch_size=[4], seed=0)
        >>> env.reset()["obs_window"].shape
        torch.Size([4, 2, 3])
    """
    env = LasaSphereEnv(start_points, batch_size, **env_kwargs)
    source = keys.OBSERVATION
    extra = []
    if env.context is not None:  # the policy sees [point, context] per step
        extra = [
            CatTensors(
                in_keys=[keys.OBSERVATION, "context"],
                out_key="obs_cond",
                sort=False,
                del_keys=False,
            )
        ]
        source = "obs_cond"
    windows = observation_windows(obs_horizon, {source: keys.OBS_WINDOW})
    return TransformedEnv(env, Compose(*extra, windows))
