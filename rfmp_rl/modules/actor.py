"""Receding-horizon acting in any TorchRL env: `make_actor`.

A `FlowPolicy` writes a chunk of T_p actions; TorchRL's ``MultiStepActorWrapper`` executes T_a of
them, one per env step, and re-plans (on ``is_init`` too)::

    env step   s   s+1  ...  s+T_a-1 | s+T_a ...
    policy     plan                  | plan
    executed   a^s a^s+1 ... a^s+T_a-1| ...

The wrapper keeps the chunk and a step counter in the rollout's TensorDict. Batched envs that
copy only the entries their specs declare (``ParallelEnv``) need the two registered as env state:
that is the ``TensorDictPrimer`` `make_actor` returns beside the actor.
"""

from __future__ import annotations

import torch
from tensordict import TensorDictBase
from torchrl.data import Unbounded
from torchrl.envs import TensorDictPrimer
from torchrl.modules import MultiStepActorWrapper

from rfmp_rl.modules.policy_model import PolicyModel
from rfmp_rl.modules.tensordict_modules import FlowPolicy

__all__ = ["RecedingHorizonActor", "make_actor"]


class RecedingHorizonActor(MultiStepActorWrapper):
    """``MultiStepActorWrapper`` around a `FlowPolicy` that also acts in an unbatched env (batch
    size ``[]``: such an input is run as a batch of one and written back) and makes the primer of
    its state (`make_tensordict_primer`).

    Example:
        >>> from tensordict import TensorDict
        >>> from rfmp_rl.modules import ModelConfig, build_model
        >>> model = build_model(ModelConfig("srfmp", "R1", obs_dim=3, horizon=4,
        ...                                 down_dims=[16, 32]))
        >>> actor = RecedingHorizonActor(FlowPolicy(model), n_steps=4, replan_interval=2)
        >>> td = actor(TensorDict({"observation": torch.randn(2, 3),
        ...                        "is_init": torch.ones(1, dtype=torch.bool)}, []))
        >>> td["action"].shape, td["action_orig"].shape, td["counter"].tolist()
        (torch.Size([1]), torch.Size([4, 1]), [1])
    """

    def make_tensordict_primer(self) -> TensorDictPrimer:
        """The env state this actor keeps between steps: its chunk ``(T_p, D)`` (``action_orig``)
        and step counter ``(1,)``, registered in the env so batched envs that copy only declared
        entries (``ParallelEnv``) carry them. TorchRL finds it by this name
        (``torchrl.modules.utils.get_primers_from_module``, a ``Collector`` with
        ``auto_register_policy_transforms=True``)."""
        policy = self.actor
        chunk = (self.n_steps, policy.model.action_dim)  # (T_p, D)
        return TensorDictPrimer(
            {
                self._actor_keys_map[policy.action_key]: Unbounded(chunk, dtype=torch.float32),
                self.counter_key: Unbounded((1,), dtype=torch.int32),
            },
            expand_specs=True,
        )

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        if tensordict.batch_dims:
            return super().forward(tensordict)
        out = super().forward(tensordict.unsqueeze(0)).squeeze(0)
        for key in self.out_keys:
            tensordict.set(key, out.get(key))
        return tensordict


def make_actor(
    policy: FlowPolicy | PolicyModel,
    *,
    action_steps: int | None = None,
    **policy_kwargs,
) -> tuple[RecedingHorizonActor, TensorDictPrimer]:
    """The receding-horizon actor of ``policy`` and the primer its env needs.

    Args:
        policy: a `FlowPolicy`, or a policy model (`FlowModel` / `DiffusionModel`) to wrap in
            ``FlowPolicy(policy, **policy_kwargs)`` (solver, keys, ``spec``, ``safe``).
        action_steps: T_a, the actions executed per chunk (default: the model's
            ``action_steps``).

    Returns:
        ``(actor, primer)``: the actor executes T_a of every T_p actions and re-plans after a
        reset; append ``primer`` to the env (``env.append_transform(primer)``, or to each
        worker's env) so a ``ParallelEnv`` carries the actor's chunk and counter from step to
        step. The env must also emit the policy's inputs and ``is_init``
        (`rfmp_rl.envs.window_transforms`).

    Example:
        >>> from torchrl.envs import GymEnv, TransformedEnv
        >>> from rfmp_rl.envs import window_transforms
        >>> from rfmp_rl.modules import ModelConfig, build_model
        >>> model = build_model(ModelConfig("srfmp", "R1", obs_dim=3, horizon=4,
        ...                                 down_dims=[16, 32]))
        >>> actor, primer = make_actor(model, observation_key="obs_window", nfe=1)
        >>> env = TransformedEnv(GymEnv("Pendulum-v1"), window_transforms(actor))
        >>> env.append_transform(primer).rollout(5, actor)["action"].shape
        torch.Size([5, 1])
    """
    if isinstance(policy, PolicyModel):
        policy = FlowPolicy(policy, **policy_kwargs)
    elif policy_kwargs:
        raise TypeError(f"make_actor: {sorted(policy_kwargs)} configure a FlowPolicy built from a "
                        f"model; this one is built already")
    if not isinstance(policy, FlowPolicy):
        raise TypeError(f"make_actor takes a FlowPolicy or a policy model (FlowModel or "
                        f"DiffusionModel); got {type(policy).__name__}")
    cfg = policy.model.cfg
    steps = int(cfg.action_steps if action_steps is None else action_steps)
    actor = RecedingHorizonActor(policy, n_steps=cfg.horizon, replan_interval=steps)
    return actor, actor.make_tensordict_primer()
