"""SRFMP's stable Riemannian flow-matching loss (paper Eq. 20)."""

from __future__ import annotations

from tensordict import TensorDict, TensorDictBase

from rfmp_rl.modules.policy_model import FlowModel, unwrap_policy_model
from rfmp_rl.objectives.common import FlowLoss

__all__ = ["SRFMPLoss"]


class SRFMPLoss(FlowLoss):
    """``E ||v(xi_t | o) - u(xi_t | xi_1)||^2`` on the stable path over ``xi = [a, tau]``.

    The spatial target is ``lambda_x Log_{a_t}(a_1)`` (the paper's ``-lambda_x Log_{a_1}(a_t)``
    in the tangent space at ``a_t``) and the pseudo-time target is
    ``-lambda_tau (tau_t - tau_1)``. The network sees tau, not t (the field is autonomous).

    Returns ``loss_srfmp`` (spatial term, Riemannian metric, masked by ``action_is_pad``) and
    ``loss_tau`` (pseudo-time term), plus detached diagnostics ``tau_mean`` and ``target_norm``.
    Their sum is the paper's loss; TorchRL trainers sum every ``loss_*`` entry. The rates
    ``lambda_x`` / ``lambda_tau``, how times are drawn (``time_sampling``, ``time_max``,
    ``t0_fraction``) come from the `LossConfig`; ``lambda_x`` must equal the model's, which
    inference integrates with. See `ImitationLoss` for the keys, ``camera_keys`` and
    ``reduction``.

    Example:
        >>> from tensordict import TensorDict
        >>> from rfmp_rl.modules import FlowPolicy, ModelConfig, build_model
        >>> from rfmp_rl.objectives import LossConfig
        >>> cfg = ModelConfig("srfmp", "S2", obs_dim=3, horizon=4, down_dims=[32, 64])
        >>> model = build_model(cfg)
        >>> loss = SRFMPLoss(FlowPolicy(model), LossConfig(time_sampling="tau", time_max=2.0))
        >>> out = loss(TensorDict({"observation": torch.randn(8, 2, 3),
        ...     "action": model.chunk.unflatten(model.chunk.random_base(8))}, [8]))
        >>> sorted(k for k in out.keys() if k.startswith("loss"))
        ['loss_srfmp', 'loss_tau']
    """

    _loss_out_keys = ("loss_srfmp", "loss_tau", "tau_mean", "target_norm")

    def __init__(self, actor, loss_cfg=None, *, camera_keys=None, reduction: str = "mean"
                 ) -> None:
        model = unwrap_policy_model(actor, "SRFMPLoss")
        if not isinstance(model, FlowModel) or not model.stable:
            raise TypeError("SRFMPLoss needs an SRFMP policy (ModelConfig.algorithm='srfmp'), "
                            f"got algorithm {model.cfg.algorithm!r}")
        super().__init__(actor, loss_cfg, camera_keys=camera_keys, reduction=reduction)

    def forward(self, tensordict: TensorDictBase) -> TensorDict:
        model = self.model
        cond, target, valid = self._flow_target(tensordict)
        v_x, v_tau = model.velocity(target.x_t, target.tau_t, cond)
        per_step = self._per_step_sqnorm(target.x_t, v_x - target.u_t)  # (B, T_p)
        loss_x = self._reduce_steps(per_step, tensordict, valid)
        loss_tau = self._reduce_samples(((v_tau - target.u_tau) ** 2).mean(-1), tensordict)
        return TensorDict(
            {
                "loss_srfmp": loss_x,
                "loss_tau": loss_tau,
                "tau_mean": target.tau_t.mean().detach(),
                "target_norm": self._per_step_sqnorm(target.x_t, target.u_t).mean().sqrt().detach(),
            },
            batch_size=[],
        )
