"""SRFMP's stable Riemannian flow-matching loss (paper Eq. 20)."""

from __future__ import annotations

from tensordict import TensorDict, TensorDictBase

from rfmp_rl.modules.policy_model import FlowModel, unwrap_policy_model
from rfmp_rl.objectives.common import ImitationLoss

__all__ = ["SRFMPLoss"]


class SRFMPLoss(ImitationLoss):
    """``E ||v(xi_t | o) - u(xi_t | xi_1)||^2`` on the stable path over ``xi = [a, tau]``.

    The spatial target is ``lambda_x Log_{a_t}(a_1)`` (the paper's ``-lambda_x Log_{a_1}(a_t)``
    in the tangent space at ``a_t``) and the pseudo-time target is
    ``-lambda_tau (tau_t - tau_1)``. The network sees tau, not t (the field is autonomous).

    Returns ``loss_srfmp`` (spatial term, Riemannian metric, masked by ``action_is_pad``) and
    ``loss_tau`` (pseudo-time term), plus detached diagnostics ``tau_mean`` and ``target_norm``.
    Their sum is the paper's loss; TorchRL trainers sum every ``loss_*`` entry.

    Example:
        >>> from tensordict import TensorDict
        >>> from rfmp_rl.modules import ModelConfig, build_model
        >>> cfg = ModelConfig("srfmp", "S2", obs_dim=3, horizon=4, down_dims=[32, 64])
        >>> model = build_model(cfg)
        >>> out = SRFMPLoss(model)(TensorDict({"observation": torch.randn(8, 2, 3),
        ...     "action": model.chunk.unflatten(model.chunk.random_base(8))}, [8]))
        >>> sorted(k for k in out.keys() if k.startswith("loss"))
        ['loss_srfmp', 'loss_tau']
    """

    _out_keys = ("loss_srfmp", "loss_tau", "tau_mean", "target_norm")

    def __init__(self, model: FlowModel, camera_keys=None, reduction: str = "mean") -> None:
        model = unwrap_policy_model(model, "SRFMPLoss")  # a FlowPolicy or actor works too
        if not isinstance(model, FlowModel) or not model.stable:
            raise TypeError("SRFMPLoss needs an SRFMP FlowModel (ModelConfig.algorithm='srfmp')")
        super().__init__(model, camera_keys, reduction)

    def forward(self, tensordict: TensorDictBase) -> TensorDict:
        model = self.model
        cond, target, valid = self._flow_target(tensordict)
        v_x, v_tau = model.velocity(target.x_t, target.tau_t, cond)
        per_step = self._per_step_sqnorm(target.x_t, v_x - target.u_t)  # (B, T_p)
        loss_x = self._reduce_loss(per_step, tensordict, mask=valid)
        loss_tau = ((v_tau - target.u_tau) ** 2).mean()
        return TensorDict(
            {
                "loss_srfmp": loss_x,
                "loss_tau": loss_tau,
                "tau_mean": target.tau_t.mean().detach(),
                "target_norm": self._per_step_sqnorm(target.x_t, target.u_t).mean().sqrt().detach(),
            },
            batch_size=[],
        )
