"""Closed-loop evaluation over seeds and the NFE x end-time sweep.

One function rolls a policy out over a list of seeds (`evaluate`), one sweeps it over the
(NFE, T) settings of an `EvalConfig` (`sweep`); the task enters through two callables:

- ``env_fn(batch_size=[N], seeds=[...], **kwargs)``: a picklable env factory (the batched TorchRL
  env of the task), wrapped by `rfmp_rl.eval.parallel.evaluation_env` (``ParallelEnv`` workers,
  per-seed prior noise);
- ``metrics(rollout, steps)``: the task's per-seed figures from the rollout ``(N, L)`` and the
  executed steps ``(N,)`` (the env's ``step_count``, else ``L``), e.g. Push-T's maximum
  coverage, robosuite's success or a DTW distance to demonstrations.

The env writes each episode's reset ``seed`` (read by `PriorNoise` for random sampling).

Per-seed results depend on the seed alone: each episode's prior noise comes from its own seed
(`PriorNoise`), so neither ``workers`` nor ``num_envs`` changes them.

Example::

    cfg = EvalConfig(seeds=50, nfes=[1, 3], t_ends=[1.0, 1.6], max_steps=300)
    rows = sweep(functools.partial(make_pusht_env, obs_type="state"), model,
                 lambda nfe, t: make_actor(model, nfe, t), cfg, pusht_metrics)
    write_tables(rows, out, title, command, columns)
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import torch
from tensordict import TensorDictBase
from torchrl.envs.utils import ExplorationType, set_exploration_type

from rfmp_rl.eval.parallel import FlatBatch, evaluation_env, flatten_workers
from rfmp_rl.solvers import SolverConfig

__all__ = ["EvalConfig", "SeedResults", "sweep_settings", "reached_time", "evaluate", "sweep",
           "seed_mean", "seed_max", "seed_std"]

#: ``metrics(rollout (N, L), executed steps (N,))`` -> per-seed values, one list per figure.
Metrics = Callable[[TensorDictBase, torch.Tensor], Mapping[str, Sequence[float]]]
#: Per-seed values -> the row's figures (default: `seed_mean` of each).
Summary = Callable[[Mapping[str, Sequence[float]]], dict[str, float]]


@dataclass
class EvalConfig:
    """An evaluation: which seeds, which (NFE, T) settings, how the envs are stepped.

    Example:
        >>> cfg = EvalConfig(seeds=3, seed_start=7, nfes=[1, 2], t_ends=[1.0, 1.6])
        >>> cfg.seed_list, cfg.settings("srfmp")
        ([7, 8, 9], [(1, 1.0), (2, 1.0), (1, 1.6), (2, 1.6)])
    """

    seeds: int = 50  # episodes, one per seed
    seed_start: int = 100000  # first seed (the paper's / Diffusion Policy's test seeds)
    nfes: list[int] = field(default_factory=lambda: [1, 3, 5, 10])
    t_ends: list[float] = field(default_factory=lambda: [1.0])  # flows only; DDIM runs T = 1
    time_table: list[list] = field(default_factory=list)  # extra [NFE, T] pairs
    max_steps: int | None = None  # env steps per episode (None: the task's own limit)
    sampling: str = "random"  # random (prior noise from each seed) | deterministic (prior mode)
    workers: int = 1  # processes stepping the envs (TorchRL ParallelEnv)
    num_envs: int | None = None  # envs stepped side by side (None: every seed at once)
    final_eval: bool = True  # train.py evaluates best.pt at the end
    out: str | None = None  # output folder (None: <checkpoint folder>/eval)

    def __post_init__(self) -> None:
        self.nfes = [int(n) for n in self.nfes]
        self.t_ends = [float(t) for t in self.t_ends]
        self.time_table = [[int(n), float(t)] for n, t in (self.time_table or [])]
        if int(self.seeds) < 1:
            raise ValueError(f"eval.seeds must be >= 1, got {self.seeds}")
        if not self.nfes or min(self.nfes) < 1:
            raise ValueError(f"eval.nfes must be a non-empty list of NFEs >= 1, got {self.nfes}")
        if not self.t_ends or min(self.t_ends) <= 0:
            raise ValueError(f"eval.t_ends must be a non-empty list of end times > 0, got "
                             f"{self.t_ends}")
        if self.sampling not in ("random", "deterministic"):
            raise ValueError(f"eval.sampling must be 'random' or 'deterministic', got "
                             f"{self.sampling!r}")
        if not isinstance(self.workers, int) or self.workers < 1:
            raise ValueError(f"eval.workers must be an integer >= 1, got {self.workers!r}")
        if self.num_envs is not None and int(self.num_envs) < 1:
            raise ValueError(f"eval.num_envs must be >= 1, got {self.num_envs}")

    @classmethod
    def from_config(cls, mapping: Mapping[str, Any] | None) -> EvalConfig:
        """From a config mapping (e.g. hydra's ``cfg.eval``); an unknown key is an error."""
        data = dict(mapping or {})
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(data) - names)
        if unknown:
            raise ValueError(f"eval.{unknown[0]} is not an evaluation setting; the settings are "
                             f"{sorted(names)}")
        return cls(**{k: (list(v) if isinstance(v, Sequence) and not isinstance(v, str) else v)
                      for k, v in data.items()})

    @property
    def seed_list(self) -> list[int]:
        return list(range(int(self.seed_start), int(self.seed_start) + int(self.seeds)))

    def settings(self, algorithm: str) -> list[tuple[int, float]]:
        """The sweep's (NFE, T) pairs for ``algorithm`` (`sweep_settings`)."""
        return sweep_settings(algorithm, self.nfes, self.t_ends, self.time_table)


def sweep_settings(algorithm: str, nfes: Sequence[int], t_ends: Sequence[float],
                   time_table: Sequence[Sequence] = ()) -> list[tuple[int, float]]:
    """(NFE, T) pairs: every NFE at every T (T-major), then the ``time_table`` pairs not yet
    listed; DDIM and CP (samplers without an end time) run every NFE at T = 1 only.

    Example:
        >>> sweep_settings("rfmp", [1, 3], [1.0, 1.6], [[4, 1.6]])
        [(1, 1.0), (3, 1.0), (1, 1.6), (3, 1.6), (4, 1.6)]
        >>> sweep_settings("ddim", [1, 3], [1.0, 1.6])
        [(1, 1.0), (3, 1.0)]
    """
    if algorithm in ("ddim", "cp"):
        return [(int(nfe), 1.0) for nfe in nfes]
    settings = [(int(nfe), float(t)) for t in t_ends for nfe in nfes]
    for nfe, t_end in time_table or []:
        if (int(nfe), float(t_end)) not in settings:
            settings.append((int(nfe), float(t_end)))
    return settings


def reached_time(model, nfe: int, t_end: float) -> float:
    """The flow time a policy model actually reaches at (NFE, T): SRFMP's first step is
    ``1 / lambda_x``, so NFE 1 ends there; DDIM reports 1."""
    solver = SolverConfig(nfe=int(nfe), t_end=float(t_end)).resolve(model.cfg.algorithm)
    return solver.reached(getattr(model.cfg, "lambda_x", None))


@dataclass
class SeedResults:
    """Per-seed results of one (NFE, T) setting, in seed order."""

    nfe: int
    t_end: float
    t_reached: float
    seeds: list[int]
    values: dict[str, list[float]]  # figure -> one value per seed
    env_steps: list[int]  # executed env steps per seed
    seconds: float  # wall-clock time of the rollouts

    def extend(self, other: SeedResults) -> None:
        """Append the seeds of ``other`` (the same setting, the next seeds)."""
        if (other.nfe, other.t_end) != (self.nfe, self.t_end):
            raise ValueError(f"cannot join NFE={other.nfe} T={other.t_end} to NFE={self.nfe} "
                             f"T={self.t_end}")
        self.seeds += other.seeds
        for name, values in other.values.items():
            self.values.setdefault(name, []).extend(values)
        self.env_steps += other.env_steps
        self.seconds += other.seconds

    def row(self, labels: Mapping[str, Any] | None = None,
            summary: Summary | None = None) -> dict:
        """A table row: ``labels``, NFE, T, T reached, the summary figures, env steps, seconds,
        the seed range and ``per_seed`` (the values; the table writers leave it out)."""
        return {**dict(labels or {}), "nfe": self.nfe, "t_end": self.t_end,
                "t_reached": self.t_reached, **(summary or _mean_summary)(self.values),
                "env_steps": int(sum(self.env_steps)), "seconds": self.seconds,
                "seeds": f"{self.seeds[0]}-{self.seeds[-1]}",
                "per_seed": {"seed": list(self.seeds), **self.values}}


def _finite(values: Sequence[float]) -> torch.Tensor:
    # float32, as the env's figures are: a row's mean and spread are those of the seeds' values
    # taken as one float32 batch, whichever way the seeds were grouped
    return torch.tensor([float(v) for v in values if not math.isnan(float(v))])


def seed_mean(values: Sequence[float]) -> float:
    """The mean over seeds of the defined (non-NaN) values; NaN when there are none."""
    kept = _finite(values)
    return float(kept.mean()) if kept.numel() else float("nan")


def seed_std(values: Sequence[float]) -> float:
    """The standard deviation over seeds (unbiased; NaN for fewer than two values)."""
    kept = _finite(values)
    return float(kept.std()) if kept.numel() > 1 else float("nan")


def seed_max(values: Sequence[float]) -> float:
    """The largest value over seeds (NaN when none is defined)."""
    kept = [float(v) for v in values if not math.isnan(float(v))]
    return max(kept) if kept else float("nan")


def _mean_summary(values: Mapping[str, Sequence[float]]) -> dict[str, float]:
    return {name: seed_mean(v) for name, v in values.items()}


@torch.no_grad()
def _rollout(env, actor, n: int, nfe: int, t_end: float, t_reached: float, seeds: list[int],
             cfg: EvalConfig, max_steps: int, metrics: Metrics, seed: int) -> SeedResults:
    mode = (ExplorationType.DETERMINISTIC if cfg.sampling == "deterministic"
            else ExplorationType.RANDOM)
    torch.manual_seed(int(seed))
    start = time.perf_counter()
    with set_exploration_type(mode):
        out = env.rollout(max_steps, FlatBatch(actor), break_when_any_done=False,
                          break_when_all_done=True)
    out = flatten_workers(out, n)  # (N, L), seed order
    seconds = time.perf_counter() - start
    if ("next", "step_count") in out.keys(True):  # executed steps per episode
        steps = out["next", "step_count"][:, -1].reshape(n)
    else:  # an env without a StepCounter: every episode ran the whole rollout
        steps = torch.full((n,), out.shape[1], dtype=torch.int64)
    values = {name: [float(v) for v in vals] for name, vals in metrics(out, steps).items()}
    for name, vals in values.items():
        if len(vals) != n:
            raise ValueError(f"metrics gave {len(vals)} values of {name!r} for {n} seeds")
    return SeedResults(nfe, t_end, t_reached, list(seeds), values,
                       [int(s) for s in steps.tolist()], seconds)


def _noise_dim(model, cfg: EvalConfig) -> int | None:
    """Prior noise per episode from its seed (random sampling); None for the prior's mode."""
    return None if cfg.sampling == "deterministic" else int(model.noise_dim)


def _chunks(seeds: list[int], cfg: EvalConfig) -> list[list[int]]:
    size = int(cfg.num_envs or len(seeds))
    return [seeds[i:i + size] for i in range(0, len(seeds), size)]


def evaluate(env_fn: Callable, model, make_actor: Callable[[int, float], Any], nfe: int,
             t_end: float, cfg: EvalConfig, metrics: Metrics, *, seed: int = 0,
             max_steps: int | None = None, env_kwargs: Mapping[str, Any] | None = None
             ) -> SeedResults:
    """Roll the policy out at (NFE, T) once per seed of ``cfg`` and measure each episode.

    Args:
        env_fn: picklable factory ``env_fn(batch_size=[N], seeds=[...], **env_kwargs)``.
        model: the policy model (its ``noise_dim`` and solver defaults).
        make_actor: ``(nfe, t_end) -> actor`` acting in the env (e.g. a
            ``MultiStepActorWrapper``).
        nfe, t_end: the solver setting.
        cfg: seeds, step limit, sampling, workers, envs side by side.
        metrics: the task's per-seed figures (see `Metrics`).
        seed: the run's seed (torch seed of the rollout, offset of the prior noise).
        max_steps: the episode length when ``cfg.max_steps`` is None.
        env_kwargs: passed to ``env_fn``.

    Returns:
        `SeedResults` with one value per seed and figure.
    """
    results = _sweep(env_fn, model, make_actor, [(int(nfe), float(t_end))], cfg, metrics,
                     seed=seed, max_steps=max_steps, env_kwargs=env_kwargs)
    return results[0]


def _sweep(env_fn, model, make_actor, settings, cfg: EvalConfig, metrics: Metrics, *, seed: int,
           max_steps: int | None, env_kwargs, chunk_done=None) -> list[SeedResults]:
    steps = cfg.max_steps or max_steps
    if not steps:
        raise ValueError("eval.max_steps is not set and the task gives no episode limit")
    results: list[SeedResults | None] = [None] * len(settings)
    for chunk in _chunks(cfg.seed_list, cfg):  # one env per chunk, shared by every setting
        env, n = evaluation_env(env_fn, chunk, int(cfg.workers), noise_dim=_noise_dim(model, cfg),
                                noise_seed=int(seed), **dict(env_kwargs or {}))
        try:
            for k, (nfe, t_end) in enumerate(settings):
                part = _rollout(env, make_actor(nfe, t_end), n, nfe, t_end,
                                reached_time(model, nfe, t_end), chunk, cfg, int(steps),
                                metrics, seed)
                if results[k] is None:
                    results[k] = part
                else:
                    results[k].extend(part)
                if chunk_done is not None:
                    chunk_done(part)
        finally:
            env.close()  # worker processes end even when a rollout fails
    return results


def sweep(env_fn: Callable, model, make_actor: Callable[[int, float], Any], cfg: EvalConfig,
          metrics: Metrics, *, seed: int = 0, labels: Mapping[str, Any] | None = None,
          summary: Summary | None = None, max_steps: int | None = None,
          env_kwargs: Mapping[str, Any] | None = None, progress=None) -> list[dict]:
    """`evaluate` at every (NFE, T) of ``cfg.settings(model.cfg.algorithm)``; one table row each.

    The seeds are stepped ``cfg.num_envs`` at a time (default all at once); each group's env is
    built once and reset for every setting. ``labels`` open every row (e.g. ``{"algo": ...}``),
    ``summary`` turns the per-seed values into the row's figures (default: their means), and
    ``progress(row)`` is called as each row is complete.
    """
    settings = cfg.settings(model.cfg.algorithm)
    many = len(_chunks(cfg.seed_list, cfg)) > 1
    rows: list[dict] = []

    def chunk_done(part: SeedResults) -> None:
        if many:
            print(f"  NFE={part.nfe} T={part.t_end:g}: seeds {part.seeds[0]}-{part.seeds[-1]} "
                  "done")
        elif progress is not None:  # one group of seeds: this setting's row is complete
            progress(part.row(labels, summary))

    results = _sweep(env_fn, model, make_actor, settings, cfg, metrics, seed=seed,
                     max_steps=max_steps, env_kwargs=env_kwargs, chunk_done=chunk_done)
    for result in results:
        rows.append(result.row(labels, summary))
        if many and progress is not None:
            progress(rows[-1])
    return rows
