"""Closed-loop episodes of a deployed controller in a TorchRL env, one batch-1 env per seed.

The controller is any object with the ``rfmp_deploy.Controller`` interface (``reset()``,
``step(observation) -> action``, ``events``): this module does not import the torch-free deploy
package, so the same loop runs the controller a robot PC runs. The env is stepped with the
controller's actions exactly as a robot would be: per-step observations in, one action out. The
controller keeps its own observation window (the last ``obs_horizon`` steps, T_o), so ``observe``
returns one step's observation for any T_o, never a window.

Example:
    >>> import numpy as np, torch
    >>> from torchrl.envs import GymEnv
    >>> class Zero:  # a stand-in controller
    ...     events = []
    ...     def reset(self): pass
    ...     def step(self, observation): return np.zeros(1, np.float32)
    >>> result = run_controller(
    ...     Zero(), lambda seed: GymEnv("Pendulum-v1"), [0, 1], max_steps=5,
    ...     observe=lambda td: {"observation": td["observation"].numpy()},
    ...     outcome=lambda td: float(td["reward"]))
    >>> len(result.outcomes), len(result.step_seconds)
    (2, 10)
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch
from tensordict import TensorDictBase
from torchrl.envs import EnvBase

from rfmp_rl import keys

__all__ = ["ControllerRollouts", "run_controller", "split_fields"]


@dataclass
class ControllerRollouts:
    """What `run_controller` measured: one outcome per seed, every step's latency, and the
    controller's events as ``(seed, event)``."""

    seeds: list[int]
    outcomes: list[float]
    step_seconds: list[float] = field(default_factory=list)
    events: list[tuple[int, Any]] = field(default_factory=list)

    @property
    def mean(self) -> float:
        return float(np.mean(self.outcomes))


def split_fields(vector: np.ndarray, fields: Sequence[Any]) -> dict[str, np.ndarray]:
    """A concatenated observation vector -> the controller's named fields (objects with ``key``
    and ``dim``, in metadata order), each a float32 view copied out of ``vector``.

    Example:
        >>> from types import SimpleNamespace as F
        >>> out = split_fields(np.arange(3.0), [F(key="a", dim=2), F(key="b", dim=1)])
        >>> {k: v.tolist() for k, v in out.items()}
        {'a': [0.0, 1.0], 'b': [2.0]}
    """
    dims = [int(f.dim) for f in fields]
    if sum(dims) != vector.shape[-1]:
        raise ValueError(
            f"the observation has {vector.shape[-1]} coordinates but the controller's fields "
            f"{[(f.key, f.dim) for f in fields]} add up to {sum(dims)}"
        )
    out, start = {}, 0
    for f, dim in zip(fields, dims, strict=True):
        out[f.key] = np.array(vector[..., start:start + dim], dtype=np.float32)
        start += dim
    return out


def run_controller(
    controller,
    make_env: Callable[[int], EnvBase],
    seeds: Sequence[int],
    max_steps: int,
    observe: Callable[[TensorDictBase], dict[str, np.ndarray]],
    outcome: Callable[[TensorDictBase], float],
    action_key: str = keys.ACTION,
) -> ControllerRollouts:
    """One episode per seed: ``make_env(seed)`` (a batch-1 or unbatched TorchRL env whose
    ``reset`` starts the seed's episode), ``controller.reset()``, then up to ``max_steps`` steps
    of ``controller.step(observe(td))`` until the env is done. ``outcome`` reads the last step's
    TensorDict (``td["next"]``, e.g. success or the maximum coverage)."""
    result = ControllerRollouts(list(seeds), [])
    for seed in seeds:
        env = make_env(seed)
        try:
            td = env.reset()
            controller.reset()
            seen = len(controller.events)
            for _ in range(max_steps):
                observation = observe(td)
                start = time.perf_counter()
                action = controller.step(observation)
                result.step_seconds.append(time.perf_counter() - start)
                spec = env.full_action_spec[action_key]
                td[action_key] = torch.as_tensor(action, dtype=spec.dtype).reshape(spec.shape)
                td = env.step(td)["next"]
                if bool(td["done"].any()):
                    break
            result.outcomes.append(float(outcome(td)))
            result.events += [(seed, e) for e in controller.events[seen:]]
        finally:
            env.close()
    return result
