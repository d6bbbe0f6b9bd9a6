"""RFMP's Riemannian conditional flow-matching loss (paper Eq. 7)."""

from __future__ import annotations

from tensordict import TensorDict, TensorDictBase

from rfmp_rl.modules.policy_model import FlowModel, unwrap_policy_model
from rfmp_rl.objectives.common import FlowLoss

__all__ = ["RFMPLoss"]


class RFMPLoss(FlowLoss):
    """``E ||v_t(a_t | o) - u_t(a_t | a_1)||^2_{g_{a_t}}`` on the geodesic path.

    For each sample: draw ``t ~ U[0, 1]`` (`LossConfig.t0_fraction` puts a share at 0) and
    ``a_0 ~ p_0`` (one base action repeated over the horizon), build ``a_t`` and ``u_t`` on the
    geodesic from ``a_0`` to the demonstrated chunk ``a_1``, and regress the network velocity
    (projected onto ``T_{a_t}``) in the Riemannian metric, summed over action dimensions and
    averaged over non-padded steps.

    Returns ``loss_rfmp`` plus detached diagnostics ``rfmp_time_mean`` and ``target_norm``.
    Takes the actor (a `FlowPolicy`, a wrapper of one, or the model) and a `LossConfig`; see
    `ImitationLoss` for the keys, ``camera_keys`` and ``reduction``.

    Example:
        >>> from tensordict import TensorDict
        >>> from rfmp_rl.modules import FlowPolicy, ModelConfig, build_model
        >>> from rfmp_rl.objectives import LossConfig
        >>> cfg = ModelConfig("rfmp", "S2", obs_dim=3, horizon=4, down_dims=[32, 64])
        >>> model = build_model(cfg)
        >>> loss = RFMPLoss(FlowPolicy(model), LossConfig(t0_fraction=0.1))
        >>> batch = TensorDict({"observation": torch.randn(8, 2, 3),
        ...                     "action": model.chunk.unflatten(model.chunk.random_base(8))}, [8])
        >>> loss(batch)["loss_rfmp"].shape
        torch.Size([])
    """

    _loss_out_keys = ("loss_rfmp", "rfmp_time_mean", "target_norm")

    def __init__(self, actor, loss_cfg=None, *, camera_keys=None, reduction: str = "mean"
                 ) -> None:
        model = unwrap_policy_model(actor, "RFMPLoss")
        if not isinstance(model, FlowModel) or model.stable:
            raise TypeError("RFMPLoss needs an RFMP policy (ModelConfig.algorithm='rfmp'), got "
                            f"algorithm {model.cfg.algorithm!r}")
        super().__init__(actor, loss_cfg, camera_keys=camera_keys, reduction=reduction)

    def forward(self, tensordict: TensorDictBase) -> TensorDict:
        model = self.model
        cond, target, valid = self._flow_target(tensordict)
        t = target.t
        v = model.velocity(target.x_t, target.t, cond)
        per_step = self._per_step_sqnorm(target.x_t, v - target.u_t)  # (B, T_p)
        loss = self._reduce_steps(per_step, tensordict, valid)
        return TensorDict(
            {
                "loss_rfmp": loss,
                "rfmp_time_mean": t.mean().detach(),
                "target_norm": self._per_step_sqnorm(target.x_t, target.u_t).mean().sqrt().detach(),
            },
            batch_size=[],
        )
