"""Normalisers, EMA, the policy networks and their TensorDict modules."""

from rfmp_rl.modules.actor import RecedingHorizonActor, make_actor
from rfmp_rl.modules.consistency import ConsistencyModel
from rfmp_rl.modules.ema import EMA
from rfmp_rl.modules.normalizer import Normalizer, euclidean_mask
from rfmp_rl.modules.policy_model import (
    DiffusionModel,
    FlowModel,
    ModelConfig,
    PolicyModel,
    build_model,
    unwrap_policy_model,
)
from rfmp_rl.modules.tensordict_modules import FlowPolicy, VectorField

__all__ = [
    "EMA",
    "Normalizer",
    "euclidean_mask",
    "ModelConfig",
    "PolicyModel",
    "FlowModel",
    "DiffusionModel",
    "ConsistencyModel",
    "build_model",
    "unwrap_policy_model",
    "VectorField",
    "FlowPolicy",
    "RecedingHorizonActor",
    "make_actor",
]
