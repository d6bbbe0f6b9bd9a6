"""Consistency Policy baseline loss: consistency distillation of a frozen Diffusion Policy (DDIM)
teacher into a one-step student (Song et al. 2023; Prasad et al. 2024)."""

from __future__ import annotations

import copy
import os
from dataclasses import replace
from pathlib import Path
from typing import Any

import torch
from tensordict import TensorDict, TensorDictBase

from rfmp_rl.modules.consistency import ConsistencyModel
from rfmp_rl.modules.policy_model import DiffusionModel, unwrap_policy_model
from rfmp_rl.objectives.common import ImitationLoss

__all__ = ["ConsistencyDistillationLoss", "load_teacher", "check_teacher"]


def load_teacher(path: str | os.PathLike) -> DiffusionModel:
    """The Diffusion Policy of a ddim checkpoint (its EMA weights), in eval mode.

    Raises:
        FileNotFoundError: no such file.
        ValueError: naming the file, when it is not a ddim checkpoint.
    """
    from rfmp_rl.checkpoint import load_checkpoint, read_checkpoint

    algorithm = read_checkpoint(path).get("algorithm")
    if algorithm != "ddim":
        raise ValueError(f"{path}: the Consistency Policy's teacher must be a Diffusion Policy "
                         f"checkpoint (algorithm 'ddim'); this one holds algorithm {algorithm!r}")
    return load_checkpoint(path, use_ema=True)[0]


def check_teacher(student: ConsistencyModel, teacher: DiffusionModel, what: str = "teacher"
                  ) -> None:
    """Raise a ``ValueError`` naming the differences when ``student`` cannot be distilled from
    ``teacher``: its config must be the teacher's with ``algorithm='cp'`` (same UNet, schedule,
    horizons, observations) and its normalisers the teacher's (distillation runs in the
    teacher's normalised action space). `ConsistencyModel.from_teacher` builds such a student."""
    if teacher.cfg.algorithm != "ddim" or not isinstance(teacher, DiffusionModel):
        raise ValueError(f"the {what} must be a Diffusion Policy (algorithm 'ddim'), got "
                         f"algorithm {teacher.cfg.algorithm!r}")
    mine, theirs = student.cfg.to_dict(), teacher.cfg.to_dict()
    differ = [f"{k}: student {mine[k]!r}, {what} {theirs[k]!r}" for k in mine
              if k != "algorithm" and mine[k] != theirs[k]]
    if differ:
        raise ValueError("the Consistency Policy student must have its teacher's architecture "
                         "(build it with ConsistencyModel.from_teacher); they differ in "
                         + "; ".join(differ))
    for name in ("action_normalizer", "obs_normalizer"):
        a, b = getattr(student, name).state_dict(), getattr(teacher, name).state_dict()
        if any(not torch.equal(a[k].cpu(), b[k].cpu()) for k in a):
            raise ValueError(f"the student's {name} differs from the {what}'s: distillation "
                             "runs in the teacher's normalised space; build the student with "
                             "ConsistencyModel.from_teacher (it copies the normalisers)")


class ConsistencyDistillationLoss(ImitationLoss):
    """Consistency distillation of a frozen DDIM teacher into a `ConsistencyModel` student.

    For each sample: draw a diffusion step ``k ~ U{0..K-1}`` and noise the demonstrated chunk
    (normalised, as DDIM trains) to ``x_k = sqrt(ab_k) a + sqrt(1 - ab_k) eps``; take one teacher
    DDIM step (eta = 0, the probability-flow discretisation the teacher samples with, clipping
    its clean estimate when its ``clip_sample`` says so) to the earlier step
    ``k' = k - teacher_step``, or to the clean end (``k' = -1``) when ``k < teacher_step``; and
    regress the student at the later point onto the target at the earlier one::

        loss_consistency = || f_theta(x_k, k) - stopgrad f_theta(x_hat_k', k') ||^2

    averaged over action dimensions and non-padded steps. The target is the student itself
    without gradient (an EMA rate of 0, as in Song & Dhariwal 2023's improved consistency
    training; the trainer's EMA of the weights remains the evaluated policy). At ``k' = -1`` the
    target is ``x_hat`` itself (the boundary condition ``f(x, -1) = x`` of the
    parameterisation), so the chain ``k -> k - teacher_step -> ... -> clean`` ties every step to
    the teacher's DDIM trajectories with ``teacher_step`` diffusion steps per DDIM step
    (`LossConfig.teacher_step`, default 10: the teacher's 10-step DDIM).

    The teacher is frozen: a copy of it is held by the loss in eval mode with
    ``requires_grad=False``; it is not part of the policy model, so optimisers built on the
    model's parameters (`rfmp_rl.training.Trainer`) never see it and checkpoints (which save the
    policy model) do not store it. They store its path in ``payload["loss"]["teacher"]``
    when it was given as one; the student acts without it.

    Args:
        actor: the student: a `FlowPolicy` around a `ConsistencyModel` (``algorithm='cp'``), a
            wrapper of one, or the model. Build it with `ConsistencyModel.from_teacher`, which
            initialises it from the teacher's weights (as Consistency Policy does) and copies the
            normalisers; the loss refuses a student whose architecture or normalisers differ
            (`check_teacher`).
        loss_cfg: `LossConfig`; ``teacher`` (a ddim checkpoint's path) and ``teacher_step`` apply.
        teacher: the teacher when not given by ``loss_cfg.teacher``: a `DiffusionModel`, a
            `FlowPolicy` around one (or a wrapper), or a checkpoint path (recorded in the loss
            config).
        camera_keys, reduction: see `ImitationLoss`. The batch's ``prior_noise`` entry, when
            present, is the noise ``eps`` and its ``flow_time`` ``t`` in [0, 1] picks
            ``k = min(floor(t K), K - 1)``.

    Example:
        >>> from tensordict import TensorDict
        >>> from rfmp_rl.modules import ConsistencyModel, FlowPolicy, ModelConfig, build_model
        >>> teacher = build_model(ModelConfig("ddim", "R2", obs_dim=3, horizon=4,
        ...                                   down_dims=[32, 64]))
        >>> student = FlowPolicy(ConsistencyModel.from_teacher(teacher), nfe=1)
        >>> loss = ConsistencyDistillationLoss(student, teacher=teacher)
        >>> out = loss(TensorDict({"observation": torch.randn(8, 2, 3),
        ...                        "action": torch.randn(8, 4, 2)}, [8]))
        >>> out["loss_consistency"].shape, any(p.requires_grad for p in loss.teacher.parameters())
        (torch.Size([]), False)
    """

    _loss_out_keys = ("loss_consistency",)

    def __init__(self, actor, loss_cfg=None, *, teacher: Any = None, camera_keys=None,
                 reduction: str = "mean") -> None:
        model = unwrap_policy_model(actor, "ConsistencyDistillationLoss")
        if not isinstance(model, ConsistencyModel):
            raise TypeError("ConsistencyDistillationLoss needs a ConsistencyModel student "
                            f"(algorithm='cp'), got algorithm {model.cfg.algorithm!r}")
        super().__init__(actor, loss_cfg, camera_keys=camera_keys, reduction=reduction)
        if teacher is not None and self.loss_cfg.teacher is not None:
            raise TypeError("ConsistencyDistillationLoss: give the teacher once, either "
                            f"teacher= or LossConfig.teacher (= {self.loss_cfg.teacher!r})")
        if teacher is None and self.loss_cfg.teacher is None:
            raise ValueError("ConsistencyDistillationLoss needs a teacher: teacher=<DiffusionModel "
                             "or ddim checkpoint path> or LossConfig(teacher=<ddim checkpoint>)")
        if teacher is None or isinstance(teacher, (str, os.PathLike)):
            path = Path(teacher if teacher is not None else self.loss_cfg.teacher)
            self.loss_cfg = replace(self.loss_cfg, teacher=str(path))
            teacher = load_teacher(path)
            where = f"teacher ({path})"
        else:
            teacher = copy.deepcopy(unwrap_policy_model(teacher, "ConsistencyDistillationLoss"))
            where = "teacher"
        check_teacher(model, teacher, where)
        teacher.requires_grad_(False)
        teacher.amp_dtype = model.amp_dtype
        self.teacher = teacher.to(model.alphas_cumprod.device).eval()

    def train(self, mode: bool = True) -> ConsistencyDistillationLoss:
        super().train(mode)
        self.teacher.eval()  # frozen: always in inference mode
        return self

    @torch.no_grad()
    def teacher_ddim_step(self, x: torch.Tensor, k: torch.Tensor, k_prev: torch.Tensor,
                     cond: torch.Tensor) -> torch.Tensor:
        """One teacher DDIM step (eta = 0) of the flat normalised chunks ``x (B, T_p * D)`` from
        diffusion steps ``k (B,)`` to ``k_prev (B,)`` (``-1``: to the clean estimate), as
        `DiffusionModel.sample` steps; ``cond`` is the teacher's global condition."""
        teacher = self.teacher
        ab = teacher.alphas_cumprod[k].unsqueeze(-1).to(x.dtype)
        ab_prev = self.model.alpha_bar(k_prev).to(x.dtype)
        eps = teacher.predict_noise(x, k.to(x.dtype), cond)
        x0 = (x - (1 - ab).sqrt() * eps) / ab.sqrt()
        if teacher.cfg.clip_sample:
            x0 = x0.clamp(-1.0, 1.0)
            eps = (x - ab.sqrt() * x0) / (1 - ab).sqrt()
        return ab_prev.sqrt() * x0 + (1 - ab_prev).sqrt() * eps

    def forward(self, tensordict: TensorDictBase) -> TensorDict:
        model, k_keys = self.model, self.tensor_keys
        cond, x1, valid = self._read(tensordict)
        with torch.no_grad():
            inputs = [self._require(tensordict, key) for key in self._condition_keys()]
            teacher_cond = self.teacher.encode_inputs(*inputs)
        batch, total = x1.shape[0], model.cfg.num_diffusion_steps
        eps = tensordict.get(k_keys.prior_noise, None)
        eps = torch.randn_like(x1) if eps is None else eps.reshape(x1.shape).to(x1.dtype)
        t = tensordict.get(k_keys.flow_time, None)
        if t is None:
            k = torch.randint(0, total, (batch,), device=x1.device)
        else:
            k = (t.reshape(batch) * total).floor().long().clamp(0, total - 1).to(x1.device)
        k_prev = (k - int(self.loss_cfg.teacher_step)).clamp_min(-1)
        x_k = model.add_noise(x1, eps, k)
        x_prev = self.teacher_ddim_step(x_k, k, k_prev, teacher_cond)
        with torch.no_grad():  # the target: the student itself, without gradient
            target = model.consistency(x_prev, k_prev, cond)
        pred = model.consistency(x_k, k, cond)
        per_step = ((pred - target) ** 2).unflatten(-1, (model.horizon, model.action_dim)).mean(-1)
        loss = self._reduce_steps(per_step, tensordict, valid)
        return TensorDict({"loss_consistency": loss}, batch_size=[])
