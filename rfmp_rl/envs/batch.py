"""The bookkeeping `FrankaKitchenEnv` and `RobosuiteEnv` share: a batch of ``N`` simulators
stepped one after the other in one TorchRL env, each with its own reset seed, frozen once done,
and reset selectively by a ``_reset`` mask."""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
from tensordict import TensorDictBase
from torchrl.envs import EnvBase

from rfmp_rl import keys

__all__ = ["SimulatorBatchEnv"]


class SimulatorBatchEnv(EnvBase):
    """Base of the envs that run ``N`` simulators side by side (`FrankaKitchenEnv`,
    `RobosuiteEnv`).

    A subclass keeps its simulators in the attribute named by ``simulators_attr``, its reset
    seeds in ``seeds``, its episode limit in ``max_steps`` and per instance ``_count`` (steps),
    ``_reward`` and ``_truncated`` arrays; it gives ``_pack()`` (the TensorDict of the current
    outputs, ``reward`` included; `_done_entries` builds the done flags), ``_done(i)`` (instance
    ``i`` succeeded), ``_reset_instance(i)`` (reset simulator ``i`` from ``seeds[i]``) and
    ``_step_instance(i, action)`` (step simulator ``i``, set its ``_reward``). A step runs
    every instance that is not done, counts its steps and truncates it at ``max_steps``.

    Example::

        env = RobosuiteEnv("Lift", [2], seeds=[0, 1])  # a SimulatorBatchEnv
        env.reset()
        td = env.reset(TensorDict({"_reset": torch.tensor([[True], [False]])}, [2]))
        td["seed"]  # tensor([0, 1]): only instance 0 was reset
    """

    simulators_attr = "sims"  # the list of simulators (closed by `close`)

    def _set_seed(self, seed: int | None) -> None:
        if seed is not None:
            self.seeds = [int(seed) + i for i in range(self.batch_size[0])]

    def _done_entries(self, success: np.ndarray, **extra: torch.Tensor) -> dict[str, Any]:
        """``success``, ``step_count``, ``extra``, ``reward`` and the done flags, ``(N, 1)``
        each (``success``: one bool per instance; a finished instance is done, not truncated)."""
        n, dev = self.batch_size[0], self.device
        success = torch.as_tensor(success, device=dev).reshape(n, 1)
        truncated = torch.as_tensor(self._truncated, device=dev).reshape(n, 1)
        return {
            "success": success,
            "step_count": torch.as_tensor(self._count, dtype=torch.int64,
                                          device=dev).reshape(n, 1),
            **extra,
            "reward": torch.as_tensor(self._reward, dtype=torch.float32, device=dev).reshape(n, 1),
            "terminated": success.clone(),
            "truncated": truncated,
            "done": success | truncated,
        }

    def _reset(self, tensordict: TensorDictBase | None, **kwargs) -> TensorDictBase:
        n = self.batch_size[0]
        if tensordict is not None and tensordict.get("seed", None) is not None:
            self.seeds = [int(s) for s in tensordict.get("seed").reshape(-1).tolist()]
        which = range(n)
        if tensordict is not None and tensordict.get("_reset", None) is not None:
            which = np.flatnonzero(tensordict.get("_reset").reshape(n).cpu().numpy()).tolist()
        for i in which:
            self._count[i] = 0
            self._reward[i] = 0.0
            self._truncated[i] = False
            self._reset_instance(i)
        td = self._pack()
        del td["reward"]  # TorchRL: no reward at reset
        td.set("seed", torch.as_tensor(self.seeds, dtype=torch.int64, device=self.device))
        return td

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        action = tensordict.get(keys.ACTION).detach().to(torch.float64).cpu().numpy()
        for i in range(self.batch_size[0]):
            if self._done(i) or self._truncated[i]:
                self._reward[i] = 0.0
                continue  # frozen
            self._step_instance(i, action[i])
            self._count[i] += 1
            self._truncated[i] = self._count[i] >= self.max_steps and not self._done(i)
        return self._pack()

    def close(self, *, raise_if_closed: bool = True) -> None:
        """Close the simulators and the TorchRL env."""
        for sim in getattr(self, self.simulators_attr, []):
            sim.close()
        setattr(self, self.simulators_attr, [])
        super().close(raise_if_closed=raise_if_closed)
