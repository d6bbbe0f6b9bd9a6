"""TorchRL `LossModule`s: RFMP, SRFMP and the Diffusion Policy (DDIM) baseline."""

from rfmp_rl.modules.policy_model import unwrap_policy_model
from rfmp_rl.objectives.common import ImitationLoss
from rfmp_rl.objectives.diffusion import DiffusionPolicyLoss
from rfmp_rl.objectives.rfmp import RFMPLoss
from rfmp_rl.objectives.srfmp import SRFMPLoss

__all__ = ["ImitationLoss", "RFMPLoss", "SRFMPLoss", "DiffusionPolicyLoss", "make_loss"]


def make_loss(model, camera_keys=None) -> ImitationLoss:
    """The loss matching the algorithm of ``model`` (a policy model, or a `FlowPolicy` /
    ``MultiStepActorWrapper`` around one: `unwrap_policy_model`)."""
    model = unwrap_policy_model(model, "make_loss")
    algorithm = model.cfg.algorithm
    cls = {"rfmp": RFMPLoss, "srfmp": SRFMPLoss, "ddim": DiffusionPolicyLoss}[algorithm]
    return cls(model, camera_keys)
