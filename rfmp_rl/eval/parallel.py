"""Evaluation envs whose per-seed results do not depend on how the seeds are batched.

Two pieces make an evaluation over seeds independent of the number of worker processes and of
how many envs step side by side:

- `PriorNoise`, a TorchRL transform that writes the flows' prior noise (``prior_noise``) from one
  generator per env, seeded by that env's reset seed. The policy reads it (`FlowPolicy` uses
  ``prior_noise`` when present), so the noise an episode sees is a function of its seed alone,
  never of its neighbours in the batch.
- `evaluation_env`, which builds one batched env over the seeds, or, with ``workers > 1``, a
  TorchRL ``ParallelEnv`` whose workers each step a share of them (robosuite's simulators are
  not vectorised; the policy still runs once per step on the whole batch in the main process).

Example::

    env = evaluation_env(make_robosuite_env, seeds=range(100000, 100050), workers=2,
                         noise_dim=model.noise_dim, noise_seed=0, task="Lift", obs_horizon=2)
    out = env.rollout(300, actor, break_when_any_done=False)   # batch (50,), any worker count
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Sequence

import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase
from torchrl.data import Unbounded
from torchrl.envs import EnvBase, ParallelEnv
from torchrl.envs.transforms import Transform

from rfmp_rl import keys

__all__ = ["PriorNoise", "FlatBatch", "evaluation_env", "flatten_workers"]


class PriorNoise(Transform):
    """Per-env prior noise ``(N, noise_dim)`` from generators seeded by each env's reset seed.

    At a reset, env ``i`` (reset with seed ``s_i``, read from the ``seed`` entry the env writes)
    gets a generator seeded with ``s_i + 1_000_003 * noise_seed``; every step then draws the next
    standard-normal vector for every env. Episodes of the same seed therefore see the same noise
    wherever and with whichever neighbours they run.

    Args:
        noise_dim: the policy's ``noise_dim``.
        noise_seed: a run-level offset (the evaluation's ``seed``).
        out_key: where the noise goes (`rfmp_rl.keys.PRIOR_NOISE`).
    """

    def __init__(self, noise_dim: int, noise_seed: int = 0,
                 out_key=keys.PRIOR_NOISE) -> None:
        super().__init__(in_keys=[], out_keys=[out_key])
        self.noise_dim, self.noise_seed, self.out_key = int(noise_dim), int(noise_seed), out_key
        self._generators: list[torch.Generator] = []
        self._last: torch.Tensor | None = None

    def _draw(self, like: TensorDictBase, rows: list[bool] | None = None) -> torch.Tensor:
        """The next noise of every env (or of the ``rows`` envs; the others keep theirs, so an
        env's stream never depends on when its neighbours reset)."""
        fresh = [torch.randn(self.noise_dim, generator=g) if rows is None or rows[i]
                 else self._last[i] for i, g in enumerate(self._generators)]
        self._last = torch.stack(fresh)
        return self._last.to(like.device).reshape(*like.batch_size, self.noise_dim)

    def _reset(self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase
               ) -> TensorDictBase:
        seeds = tensordict_reset.get("seed", None)
        if seeds is None:
            raise KeyError("PriorNoise needs the env to write its reset seeds in 'seed'")
        seeds = seeds.reshape(-1).tolist()
        mask = tensordict.get("_reset", None) if tensordict is not None else None
        if mask is None or len(self._generators) != len(seeds):
            mask = [True] * len(seeds)
        else:  # a partial reset: only the envs that restart get a new stream
            mask = mask.reshape(len(seeds), -1).any(-1).tolist()
        generators = list(self._generators) or [None] * len(seeds)
        for i, (seed, restart) in enumerate(zip(seeds, mask, strict=True)):
            if restart:
                generators[i] = torch.Generator().manual_seed(
                    int(seed) + 1_000_003 * self.noise_seed)
        partial = self._last is not None and not all(mask)
        self._generators = generators
        tensordict_reset.set(self.out_key, self._draw(tensordict_reset, mask if partial else None))
        return tensordict_reset

    def _step(self, tensordict: TensorDictBase, next_tensordict: TensorDictBase
              ) -> TensorDictBase:
        next_tensordict.set(self.out_key, self._draw(next_tensordict))
        return next_tensordict

    def transform_observation_spec(self, observation_spec):
        observation_spec[self.out_key] = Unbounded(
            shape=(*observation_spec.shape, self.noise_dim), dtype=torch.float32,
            device=observation_spec.device)
        return observation_spec


class FlatBatch(TensorDictModuleBase):
    """Runs an actor on the flattened batch of a ``ParallelEnv`` (``(workers, per)`` -> ``(N,)``)
    and writes its outputs back, so batch-1-D actors such as ``MultiStepActorWrapper`` (whose
    action queue lives in the tensordict) work unchanged."""

    def __init__(self, module) -> None:
        super().__init__()
        self.module = module
        self.in_keys, self.out_keys = list(module.in_keys), list(module.out_keys)

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        if tensordict.batch_dims <= 1:
            return self.module(tensordict)
        out = self.module(tensordict.reshape(-1))
        tensordict.update(out.reshape(tensordict.shape))
        return tensordict


def _make(make_env: Callable[..., EnvBase], seeds: list[int] | None = None, *,
          noise_dim: int | None, noise_seed: int, kwargs: dict) -> EnvBase:
    env = make_env(batch_size=[len(seeds)], seeds=seeds, **kwargs)
    if noise_dim:
        env.append_transform(PriorNoise(noise_dim, noise_seed))
    return env


def evaluation_env(make_env: Callable[..., EnvBase], seeds: Sequence[int], workers: int = 1, *,
                   noise_dim: int | None = None, noise_seed: int = 0, **kwargs
                   ) -> tuple[EnvBase, int]:
    """One env over ``seeds``: ``make_env([N], seeds=..., **kwargs)`` in this process, or with
    ``workers > 1`` a ``ParallelEnv`` of ``workers`` processes stepping ``ceil(N / workers)``
    seeds each. When N does not divide, the last worker runs extra seeds past the end of
    ``seeds``; `flatten_workers` drops them.

    Args:
        make_env: a picklable env factory taking ``batch_size`` and ``seeds``.
        seeds: the reset seeds, one episode each.
        workers: worker processes (1: no subprocess).
        noise_dim: add `PriorNoise` with this size (None: the policy draws its own noise).
        noise_seed: `PriorNoise`'s run-level offset.
        **kwargs: passed to ``make_env``.

    Returns:
        ``(env, N)``; roll it out and pass the result through ``flatten_workers(out, N)``.
    """
    seeds = [int(s) for s in seeds]
    if int(workers) < 1:
        raise ValueError(f"eval.workers must be >= 1, got {workers}")
    per = math.ceil(len(seeds) / int(workers))
    workers = math.ceil(len(seeds) / per)  # no worker of padding seeds only
    if workers == 1:
        return _make(make_env, seeds, noise_dim=noise_dim, noise_seed=noise_seed,
                     kwargs=kwargs), len(seeds)
    padded = seeds + [seeds[-1] + 1 + i for i in range(per * workers - len(seeds))]
    shares = [{"seeds": padded[w * per:(w + 1) * per]} for w in range(workers)]
    # one factory with per-worker arguments: TorchRL reads the specs of one env, not of each;
    # num_threads: leave this process's torch threads as they are; each worker steps on one
    factory = functools.partial(_make, make_env, noise_dim=noise_dim, noise_seed=noise_seed,
                                kwargs=kwargs)
    env = ParallelEnv(workers, factory, create_env_kwargs=shares,
                      num_threads=torch.get_num_threads(), num_sub_threads=1)
    return env, len(seeds)


def flatten_workers(rollout: TensorDictBase, n: int) -> TensorDictBase:
    """A rollout of batch ``(workers, per, T)`` (or ``(N, T)``) as ``(N, T)``: seed order,
    padding seeds dropped."""
    if rollout.batch_dims == 3:
        rollout = rollout.flatten(0, 1)
    return rollout[:n]
