"""TorchRL `LossModule`s: RFMP, SRFMP, the Diffusion Policy (DDIM) baseline and the Consistency
Policy's distillation, and the training-time options they own (`LossConfig`)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from tensordict.utils import NestedKey

from rfmp_rl.modules.policy_model import unwrap_policy_model
from rfmp_rl.objectives.common import FlowLoss, ImitationLoss, camera_field
from rfmp_rl.objectives.config import TIME_SAMPLINGS, LossConfig
from rfmp_rl.objectives.consistency import ConsistencyDistillationLoss
from rfmp_rl.objectives.diffusion import DiffusionPolicyLoss
from rfmp_rl.objectives.rfmp import RFMPLoss
from rfmp_rl.objectives.srfmp import SRFMPLoss

__all__ = ["ImitationLoss", "FlowLoss", "RFMPLoss", "SRFMPLoss", "DiffusionPolicyLoss",
           "ConsistencyDistillationLoss", "LossConfig", "TIME_SAMPLINGS", "camera_field",
           "make_loss"]

#: Algorithm -> its loss.
LOSSES = {"rfmp": RFMPLoss, "srfmp": SRFMPLoss, "ddim": DiffusionPolicyLoss,
          "cp": ConsistencyDistillationLoss}


def make_loss(
    actor: Any,
    loss_cfg: LossConfig | Mapping[str, Any] | None = None,
    camera_keys: Mapping[str, NestedKey] | None = None,
    **kwargs: Any,
) -> ImitationLoss:
    """The loss matching the algorithm of ``actor`` (a `FlowPolicy`, a wrapper of one such as
    ``MultiStepActorWrapper``, or the policy model: `unwrap_policy_model`), with the
    training-time options ``loss_cfg`` (default: `LossConfig` with the model's ``lambda_x``).
    ``kwargs`` (``reduction``; ``teacher`` for CP) go to the loss.

    Example:
        >>> from rfmp_rl.modules import FlowPolicy, ModelConfig, build_model
        >>> policy = FlowPolicy(build_model(ModelConfig("srfmp", "S2", obs_dim=3, horizon=4,
        ...                                             down_dims=[32, 64])))
        >>> type(make_loss(policy, LossConfig(time_max=2.0))).__name__
        'SRFMPLoss'
    """
    model = unwrap_policy_model(actor, "make_loss")
    cls = LOSSES[model.cfg.algorithm]
    return cls(actor, loss_cfg, camera_keys=camera_keys, **kwargs)
