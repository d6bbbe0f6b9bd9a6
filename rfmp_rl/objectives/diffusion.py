"""Diffusion Policy baseline loss: epsilon prediction on the DDPM forward process."""

from __future__ import annotations

import torch
from tensordict import TensorDict, TensorDictBase

from rfmp_rl.modules.policy_model import DiffusionModel, unwrap_policy_model
from rfmp_rl.objectives.common import ImitationLoss

__all__ = ["DiffusionPolicyLoss"]


class DiffusionPolicyLoss(ImitationLoss):
    """``E ||eps_theta(sqrt(ab_k) a + sqrt(1 - ab_k) eps, k | o) - eps||^2``, k ~ U{0..K-1}.

    The same UNet as RFMP/SRFMP, 100 training steps with the squaredcos_cap_v2 schedule, as in
    Diffusion Policy. Sphere coordinates are treated as Euclidean (the baseline ignores the
    geometry; sampling projects at the end). Returns ``loss_diffusion``. Takes the actor (a
    `FlowPolicy`, a wrapper of one, or the model); the `LossConfig`'s flow-time options do not
    apply (``check('ddim')`` refuses them). See `ImitationLoss` for the keys, ``camera_keys``
    and ``reduction``.

    Example:
        >>> from tensordict import TensorDict
        >>> from rfmp_rl.modules import FlowPolicy, ModelConfig, build_model
        >>> cfg = ModelConfig("ddim", "R2", obs_dim=3, horizon=4, down_dims=[32, 64])
        >>> model = build_model(cfg)
        >>> loss = DiffusionPolicyLoss(FlowPolicy(model, nfe=10))
        >>> loss(TensorDict({"observation": torch.randn(8, 2, 3),
        ...     "action": torch.randn(8, 4, 2)}, [8]))["loss_diffusion"].shape
        torch.Size([])
    """

    _loss_out_keys = ("loss_diffusion",)

    def __init__(self, actor, loss_cfg=None, *, camera_keys=None, reduction: str = "mean"
                 ) -> None:
        model = unwrap_policy_model(actor, "DiffusionPolicyLoss")
        if not isinstance(model, DiffusionModel) or model.cfg.algorithm != "ddim":
            raise TypeError("DiffusionPolicyLoss needs a DiffusionModel (algorithm='ddim'), got "
                            f"algorithm {model.cfg.algorithm!r}")
        super().__init__(actor, loss_cfg, camera_keys=camera_keys, reduction=reduction)

    def forward(self, tensordict: TensorDictBase) -> TensorDict:
        model = self.model
        cond, x1, valid = self._read(tensordict)
        batch = x1.shape[0]
        eps = torch.randn_like(x1)
        k = torch.randint(0, model.cfg.num_diffusion_steps, (batch,), device=x1.device)
        pred = model.predict_noise(model.add_noise(x1, eps, k), k, cond)
        per_step = ((pred - eps) ** 2).unflatten(-1, (model.horizon, model.action_dim)).mean(-1)
        loss = self._reduce_steps(per_step, tensordict, valid)
        return TensorDict({"loss_diffusion": loss}, batch_size=[])
