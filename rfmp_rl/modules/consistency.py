"""The Consistency Policy student (Prasad et al. 2024): a consistency model (Song et al. 2023)
distilled from a Diffusion Policy (DDIM) teacher, sampling in one network evaluation.

The student shares the teacher's noise schedule, forward process, UNet and normalisers; only what
its network's output means differs. Time is the teacher's diffusion step ``k`` (0 .. K - 1), with
``k = -1`` standing for the clean end of the teacher's DDIM trajectories (noise level 0). The
consistency function maps a noisy chunk ``x_k`` straight to that end, with Song et al.'s
parameterisation (their Eq. 6 form, ``sigma_data = 1``, ``sigma_min = 0``) written in the
teacher's variables::

    f(x_k, k) = c_skip(k) y_k + c_out(k) F(x_k, k),     y_k = x_k / sqrt(ab_k),
    c_skip = 1 / (1 + sigma_k^2) = ab_k,   c_out = sigma_k / sqrt(1 + sigma_k^2) = sqrt(1 - ab_k),
    so  f(x_k, k) = sqrt(ab_k) x_k + sqrt(1 - ab_k) F(x_k, k),

in the teacher's normalised action space (``ab_k`` the cumulative product of the schedule,
``sigma_k = sqrt(1 - ab_k) / sqrt(ab_k)`` the DDIM noise level, ``ab_{-1} = 1``). At ``k = -1``
``c_skip = 1`` and ``c_out = 0``, so ``f(x, -1) = x`` holds by construction (the boundary
condition). The network sees the teacher's input ``x_k = y_k / sqrt(1 + sigma_k^2)`` and step
``k``. This form is well conditioned at every step: at the largest ones (``ab_99 = 2.4e-7``) ``f``
is the network's output itself, where the teacher's clean estimate
``(x_k - sqrt(1 - ab_k) eps) / sqrt(ab_k)`` would amplify any error of ``eps`` 2000-fold.
`ConsistencyModel.from_teacher` initialises the student with the teacher's weights (as Consistency
Policy does): its features start as the teacher's, its output head learns the new meaning;
`rfmp_rl.objectives.ConsistencyDistillationLoss` makes it consistent along the teacher's
trajectories.
"""

from __future__ import annotations

from typing import Any

import torch

from rfmp_rl.modules.policy_model import DiffusionModel, ModelConfig, unwrap_policy_model

__all__ = ["ConsistencyModel"]


class ConsistencyModel(DiffusionModel):
    """Consistency Policy student (``ModelConfig.algorithm='cp'``).

    ``sample(cond, noise, nfe=1)`` evaluates the consistency function once at the largest
    diffusion step ``K - 1`` (one-step generation). With ``nfe > 1`` it runs multistep consistency
    sampling (Song et al. 2023, Algorithm 1) on the steps `consistency_timesteps`: denoise,
    re-noise the estimate to the next smaller step with a fresh standard-normal draw, denoise
    again. ``noise`` ``(B, n * noise_dim)`` holds the start draw followed by up to ``nfe - 1``
    re-noising draws; those not given are drawn with torch (zeros under ``deterministic``). The
    ONNX graph at NFE ``n`` takes all ``n`` draws (`prior_noise_dim`), so it computes exactly
    what the policy computes from the same draws. The estimate is clipped to ``[-1, 1]`` after
    every evaluation when ``clip_sample`` (as DDIM clips its clean-sample estimate), and the
    chunk is projected onto the action manifold at the end.

    Example:
        >>> teacher = DiffusionModel(ModelConfig(algorithm="ddim", action_manifold="R2",
        ...                                      obs_dim=3, horizon=4, down_dims=[32, 64]))
        >>> student = ConsistencyModel.from_teacher(teacher)
        >>> student.cfg.algorithm, student.consistency_timesteps(3)
        ('cp', [99, 66, 33])
        >>> student.sample(student.encode(torch.randn(5, 2, 3)), nfe=1).shape
        torch.Size([5, 4, 2])
    """

    def __init__(self, cfg: ModelConfig) -> None:
        if cfg.algorithm != "cp":
            raise ValueError(f"ConsistencyModel needs ModelConfig.algorithm='cp', got "
                             f"{cfg.algorithm!r}")
        super().__init__(cfg)

    @classmethod
    def from_teacher(cls, teacher: Any) -> ConsistencyModel:
        """A student with the teacher's architecture, weights and normalisers (its config with
        ``algorithm='cp'``), on the teacher's device (its output head then learns the
        consistency parameterisation of the module docstring). ``teacher``: a `DiffusionModel`
        (``algorithm='ddim'``), a `FlowPolicy` or a wrapper of one."""
        teacher = unwrap_policy_model(teacher, "ConsistencyModel.from_teacher")
        if teacher.cfg.algorithm != "ddim":
            raise TypeError(f"ConsistencyModel.from_teacher: the teacher must be a Diffusion "
                            f"Policy (algorithm 'ddim'), got algorithm {teacher.cfg.algorithm!r}")
        cfg = ModelConfig.from_dict({**teacher.cfg.to_dict(), "algorithm": "cp"})
        student = cls(cfg).to(teacher.alphas_cumprod.device)
        student.load_state_dict(teacher.state_dict())
        return student

    # ----- the consistency function ----------------------------------------------------------
    def alpha_bar(self, k: torch.Tensor) -> torch.Tensor:
        """``ab_k`` ``(B, 1)`` for integer steps ``k (B,)``; 1 at ``k = -1`` (the clean end)."""
        k = k.long()
        ab = self.alphas_cumprod[k.clamp_min(0)]
        return torch.where(k >= 0, ab, torch.ones_like(ab)).unsqueeze(-1)

    def consistency(self, x: torch.Tensor, k: torch.Tensor, cond: torch.Tensor) -> torch.Tensor:
        """``f(x_k, k)``: the clean end of the trajectory through the flat normalised chunk
        ``x (B, T_p * D)`` at diffusion steps ``k (B,)`` (``-1``: clean, where ``f(x) = x``)."""
        ab = self.alpha_bar(k).to(x.dtype)  # (B, 1)
        out = self.predict_noise(x, k.clamp_min(0).to(x.dtype), cond)  # (B, T_p * D)
        return ab.sqrt() * x + (1 - ab).sqrt() * out

    # ----- sampling --------------------------------------------------------------------------
    def consistency_timesteps(self, nfe: int) -> list[int]:
        """The diffusion steps multistep sampling evaluates at: ``K - 1`` first, then evenly
        spaced down (``nfe = 3``, ``K = 100``: 99, 66, 33)."""
        total = self.cfg.num_diffusion_steps
        if not 1 <= nfe <= total:
            raise ValueError(f"consistency sampling NFE must be in [1, {total}], got {nfe}")
        return [(total - 1) * (nfe - i) // nfe for i in range(nfe)]

    def prior_noise_dim(self, nfe: int) -> int:
        """One draw per evaluation: ``nfe * noise_dim``."""
        return int(nfe) * self.noise_dim

    def ddim_timesteps(self, nfe: int) -> list[int]:
        """The steps `sample` evaluates at (`consistency_timesteps`; `FlowPolicy` checks the
        budget through this name)."""
        return self.consistency_timesteps(nfe)

    def sample(
        self,
        cond: torch.Tensor,
        noise: torch.Tensor | None = None,
        *,
        nfe: int = 1,
        deterministic: bool = False,
        **unused: Any,
    ) -> torch.Tensor:
        batch, width = cond.shape[0], self.noise_dim
        steps = self.consistency_timesteps(nfe)
        like = {"dtype": cond.dtype, "device": cond.device}
        if deterministic:
            noise = torch.zeros(batch, nfe * width, **like)
        elif noise is None:
            noise = torch.randn(batch, nfe * width, **like)
        else:
            given = noise.shape[-1]
            if given % width or not 1 <= given // width <= nfe:
                raise ValueError(f"consistency sampling at NFE {nfe} takes 1 to {nfe} prior draws "
                                 f"of {width} (last dimension {width}, ..., {nfe * width}), got "
                                 f"{tuple(noise.shape)}")
            if given < nfe * width:  # the re-noising draws not given
                noise = torch.cat([noise, torch.randn(batch, nfe * width - given, **like)], -1)
        draws = noise.unflatten(-1, (nfe, width))  # (B, nfe, noise_dim)
        x = estimate = draws[:, 0]
        for i, k in enumerate(steps):
            if i:  # re-noise the estimate to step k with a fresh draw
                ab = self.alphas_cumprod[k]
                x = ab.sqrt() * estimate + (1 - ab).sqrt() * draws[:, i]
            k_in = torch.full((batch,), k, dtype=torch.long, device=cond.device)
            estimate = self.consistency(x, k_in, cond)
            if self.cfg.clip_sample:
                estimate = estimate.clamp(-1.0, 1.0)
        return self.unnormalize_action(self.chunk.projx(estimate))
