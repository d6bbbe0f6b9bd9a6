"""The policy networks as plain tensor modules: RFMP/SRFMP flow models and the DDIM baseline
(the Consistency Policy student, `rfmp_rl.modules.consistency.ConsistencyModel`, builds on it).

`FlowModel` and `DiffusionModel` hold everything inference needs — normalisers (buffers), the
observation encoder, the UNet, the manifold, the prior and the solver maths — and take and
return tensors only. The TensorDict-facing wrappers (`VectorField`, `FlowPolicy`) and the losses
call into them, and the ONNX exporter traces them.

Shapes: ``observation (B, 2, D_obs)`` = ``[o^c, o^{s-1}]``; camera images ``(B, 2, C, H, W)``;
actions ``(B, T_p, D)`` on the per-step action manifold; flow states are flat ``(B, T_p * D)``
(``(B, T_p * D + 1)`` for SRFMP, whose last coordinate is the pseudo-time tau).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field
from typing import Any

import torch
from tensordict.utils import NestedKey
from torch import nn

from rfmp_rl import keys
from rfmp_rl.flows import HorizonPrior, make_prior
from rfmp_rl.manifolds import Euclidean, Horizon, Manifold, Product, from_spec
from rfmp_rl.models import (
    UNET_PRESETS,
    ConditionalUnet1D,
    MultiCameraEncoder,
    ObservationEncoder,
)
from rfmp_rl.modules.normalizer import Normalizer, euclidean_mask
from rfmp_rl.solvers import DEFAULT_SCHEDULES, integrate

__all__ = ["ModelConfig", "PolicyModel", "FlowModel", "DiffusionModel", "build_model",
           "unwrap_policy_model", "MOVED_FIELDS"]

ALGORITHMS = ("rfmp", "srfmp", "ddim", "cp")

#: Precision name -> autocast dtype of the networks (None: fp32, no autocast).
PRECISIONS = {"fp32": None, "bf16": torch.bfloat16, "fp16": torch.float16}


@dataclass
class ModelConfig:
    """A policy network's architecture and what inference needs (stored in every checkpoint).

    The training-time options (how flow times are drawn, SRFMP's ``lambda_tau``) belong to the
    loss (`rfmp_rl.objectives.LossConfig`); the rate actions are executed at is given at export
    (``export_onnx(control_rate_hz=...)``). ``lambda_x`` stays here because inference needs it:
    SRFMP's schedule takes its first step at ``1 / lambda_x`` and caps the later ones there.
    ``time_embed_dim`` / ``tau_hidden_dim`` default to the first UNet width / twice it
    (256 / 512 for the paper preset, 64 / 128 for the small one).

    Example:
        >>> cfg = ModelConfig(algorithm="srfmp", action_manifold="S2", obs_dim=3, horizon=4,
        ...                   down_dims=[32, 64])
        >>> model = build_model(cfg)
        >>> model.chunk.dim
        12
    """

    algorithm: str = "srfmp"  # rfmp | srfmp | ddim | cp (Consistency Policy student)
    action_manifold: str | dict = "R2"  # per-step action space, e.g. "R3 x S3 x R1"
    horizon: int = 16  # T_p: actions predicted per chunk
    action_steps: int | None = None  # T_a: actions executed per chunk (default T_p / 2)
    obs_horizon: int = 2  # T_o: context observation drawn from [s - T_o, s - 2]
    obs_dim: int = 0  # low-dimensional observation size per step (0: images only)
    obs_manifold: str | dict | None = None  # e.g. "S2 x S2" keeps sphere parts unnormalised
    obs_keys: list[list] | None = None  # [[name, dim], ...] concatenated into the obs vector
    # observed quaternions whose signs the data, the env and the controller make canonical:
    # [{"columns": [a, a + 4], "reference": [4]}, ...] (rfmp_rl.data.quaternions); None: raw
    obs_quaternions: list[dict] | None = None
    cameras: dict[str, list[int]] = field(default_factory=dict)  # name -> [C, H, W]
    crop_shape: list[int] | None = None  # (H, W) crop of every camera
    vision_pool: str = "spatial_softmax"  # or "avg"
    vision_out_dim: int = 512  # per-camera feature size
    unet_preset: str = "small"  # small | paper | paper_real
    down_dims: list[int] | None = None  # overrides the preset
    time_embed_dim: int | None = None  # None: down_dims[0] (256 for the paper preset)
    kernel_size: int = 5
    tau_hidden_dim: int | None = None  # SRFMP's tau-head MLP width; None: 2 * down_dims[0]
    prior_sphere: str = "uniform"  # uniform | wrapped (sphere components)
    prior_scale: float = 1.0  # tangent std of wrapped Gaussians
    prior_std: float = 1.0  # std of Euclidean Gaussians
    prior_repeat: bool = True  # one base action repeated over the chunk (paper) or one per step
    lambda_x: float = 2.5  # SRFMP: rate of the learned field; its schedule's first step 1/lambda_x
    tau0: float = 0.0  # SRFMP: pseudo-time at the prior
    tau1: float = 1.0  # SRFMP: pseudo-time at the data
    # SRFMP: the pseudo-time the network was trained up to (tau at LossConfig.time_max; the
    # loss records it). Sampling feeds the network tau clamped to [tau0, tau_max]: after the
    # first step (1 / lambda_x) the learned tau velocity carries tau to about tau1 and then
    # past it, where the network was never trained. None: no clamp (checkpoints written
    # before the field existed, which sample as they did then).
    tau_max: float | None = None
    num_diffusion_steps: int = 100  # DDIM (and CP) training steps
    clip_sample: bool = True  # DDIM / CP clip the predicted clean sample to [-1, 1]

    def __post_init__(self) -> None:
        if self.action_steps is None:
            self.action_steps = max(1, self.horizon // 2)
        if self.algorithm not in ALGORITHMS:
            raise ValueError(
                f"ModelConfig.algorithm must be one of {ALGORITHMS}, got {self.algorithm!r}"
            )
        if self.horizon < 1 or not 1 <= self.action_steps <= self.horizon:
            raise ValueError(
                f"ModelConfig: need 1 <= action_steps (T_a={self.action_steps}) <= horizon "
                f"(T_p={self.horizon})"
            )
        if self.obs_keys is None:
            self.obs_keys = [["observation", self.obs_dim]] if self.obs_dim else []
        if sum(int(d) for _, d in self.obs_keys) != self.obs_dim:
            raise ValueError(
                f"ModelConfig.obs_keys {self.obs_keys} add up to "
                f"{sum(int(d) for _, d in self.obs_keys)} dims, but obs_dim is {self.obs_dim}"
            )
        if self.obs_horizon < 2:
            raise ValueError(f"ModelConfig.obs_horizon (T_o) must be >= 2, got {self.obs_horizon}")
        if self.obs_quaternions is not None:
            from rfmp_rl.data.quaternions import parse_observation_quaternions

            self.obs_quaternions = [q.to_dict() for q in parse_observation_quaternions(
                self.obs_quaternions, self.obs_dim)]
        if self.down_dims is None and self.unet_preset not in UNET_PRESETS:
            raise ValueError(
                f"ModelConfig.unet_preset must be one of {sorted(UNET_PRESETS)}, "
                f"got {self.unet_preset!r}"
            )
        if not self.lambda_x > 0:
            raise ValueError(f"ModelConfig.lambda_x must be > 0, got {self.lambda_x}")
        if self.tau_max is not None:
            lo, hi = sorted((self.tau0, self.tau1))
            if not lo < self.tau_max <= hi:
                raise ValueError(f"ModelConfig.tau_max must lie between tau0 ({self.tau0}) and "
                                 f"tau1 ({self.tau1}), excluding tau0; got {self.tau_max}")
        first = int(self.unet_down_dims()[0])
        if self.time_embed_dim is None:
            self.time_embed_dim = first
        if self.tau_hidden_dim is None:
            self.tau_hidden_dim = 2 * first

    def unet_down_dims(self) -> list[int]:
        """The UNet's down-sampling widths: ``down_dims``, else the preset's."""
        dims = self.down_dims if self.down_dims is not None else UNET_PRESETS[self.unet_preset]
        return [int(d) for d in dims]

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> ModelConfig:
        """From `to_dict`'s output. An unknown field raises, naming it; the training options
        and the control rate that configs written before `LossConfig` held raise with how to
        convert them (`rfmp_rl.checkpoint.read_checkpoint` does it for a checkpoint)."""
        known = set(cls.__dataclass_fields__)
        moved = sorted(set(data) & set(MOVED_FIELDS))
        if moved:
            raise ValueError(
                f"ModelConfig: fields {moved} no longer belong to the model config ("
                + "; ".join(f"{k} -> {MOVED_FIELDS[k]}" for k in moved)
                + "): load the checkpoint with rfmp_rl.checkpoint.read_checkpoint / "
                "load_checkpoint, which convert it, or split the dict with "
                "rfmp_rl.checkpoint.split_legacy_model_config"
            )
        unknown = sorted(set(data) - known)
        if unknown:
            raise ValueError(f"ModelConfig: unknown fields {unknown}")
        return cls(**dict(data))


#: Fields that configs written before `rfmp_rl.objectives.LossConfig` existed hold, and where
#: each went: the training-time options to the loss config, the deployment rate to the
#: checkpoint and the exporter.
MOVED_FIELDS = {
    "time_sampling": "LossConfig.time_sampling",
    "time_max": "LossConfig.time_max",
    "t0_fraction": "LossConfig.t0_fraction",
    "lambda_tau": "LossConfig.lambda_tau",
    "control_rate_hz": "save_checkpoint(control_rate_hz=...) / export_onnx(control_rate_hz=...)",
}


class PolicyModel(nn.Module):
    """Shared observation path: normalise, encode both steps, build the global condition."""

    def __init__(self, cfg: ModelConfig) -> None:
        super().__init__()
        self.cfg = cfg
        self.step_manifold: Manifold = from_spec(cfg.action_manifold)
        self.action_dim = self.step_manifold.dim
        self.horizon = cfg.horizon
        self.chunk = Horizon(self.step_manifold, cfg.horizon)
        self.cameras = tuple(cfg.cameras)

        self.action_normalizer = Normalizer(self.action_dim, euclidean_mask(self.step_manifold))
        obs_mask = (
            euclidean_mask(from_spec(cfg.obs_manifold)) if cfg.obs_manifold is not None else None
        )
        if obs_mask is not None and obs_mask.numel() != cfg.obs_dim:
            raise ValueError(
                f"ModelConfig.obs_manifold has {obs_mask.numel()} coordinates but obs_dim is "
                f"{cfg.obs_dim}"
            )
        self.obs_normalizer = Normalizer(max(cfg.obs_dim, 1), obs_mask)
        vision = None
        if cfg.cameras:
            vision = MultiCameraEncoder.build(
                list(cfg.cameras),
                tuple(cfg.crop_shape) if cfg.crop_shape else None,
                in_channels=int(next(iter(cfg.cameras.values()))[0]),
                pool=cfg.vision_pool,
                out_dim=cfg.vision_out_dim,
            )
        self.obs_encoder = ObservationEncoder(cfg.obs_dim, cfg.obs_horizon, vision)
        self.network = ConditionalUnet1D(
            input_dim=self.action_dim,
            global_cond_dim=self.obs_encoder.out_dim,
            time_embed_dim=cfg.time_embed_dim,
            down_dims=cfg.unet_down_dims(),
            kernel_size=cfg.kernel_size,
            predict_tau=cfg.algorithm == "srfmp",
            tau_hidden_dim=cfg.tau_hidden_dim,
            time_scale=1.0 if cfg.algorithm in ("ddim", "cp") else 100.0,
        )
        self.amp_dtype: torch.dtype | None = None  # set_precision; not part of the state
        self.network_dtype: torch.dtype | None = None  # store_networks_in; export only

    # ----- precision ---------------------------------------------------------------------------
    def set_precision(self, precision: str) -> PolicyModel:
        """Run the networks (observation encoder, UNet) under autocast: ``fp32`` (off), ``bf16``
        or ``fp16``. Their outputs come back in the caller's dtype, so the normalisers, the
        manifold maps and the solver's projections always compute in float32."""
        if precision not in PRECISIONS:
            raise ValueError(f"precision must be one of {sorted(PRECISIONS)}, got {precision!r}")
        self.amp_dtype = PRECISIONS[precision]
        return self

    def store_networks_in(self, dtype: torch.dtype) -> PolicyModel:
        """Keep the networks' weights in ``dtype`` (``torch.float16`` for a half-precision ONNX
        export): their floating inputs are cast to it and their outputs back, so the normalisers,
        the manifold maps and the solver steps stay float32. For inference; train with
        `set_precision` instead."""
        self.obs_encoder.to(dtype)
        self.network.to(dtype)
        self.network_dtype = dtype
        return self

    def _run_network(self, module: nn.Module, like: torch.Tensor, *args):
        """``module(*args)`` under the model's autocast, or in the dtype the networks are stored
        in (`store_networks_in`); outputs cast to ``like``'s dtype."""
        if self.network_dtype is not None:
            dtype = self.network_dtype
            out = module(*(a.to(dtype) if torch.is_tensor(a) and a.is_floating_point() else a
                           for a in args))
        elif self.amp_dtype is None:
            return module(*args)
        else:
            with torch.autocast(like.device.type, dtype=self.amp_dtype):
                out = module(*args)
        if isinstance(out, tuple):
            return tuple(o.to(like.dtype) for o in out)
        return out.to(like.dtype)

    # ----- observations ------------------------------------------------------------------------
    def condition_keys(
        self,
        observation_key: NestedKey = keys.OBSERVATION,
        camera_keys: Mapping[str, NestedKey] | None = None,
        gap_key: NestedKey = keys.OBS_GAP,
    ) -> list[NestedKey]:
        """The TensorDict keys this policy is conditioned on, in the order `encode_inputs`
        takes them: the observation window (``obs_dim > 0``), each camera's window, the gap
        (T_o > 2). The losses, `FlowPolicy`, `VectorField` and the ONNX graph all read their
        inputs through this and `encode_inputs`.

        Example:
            >>> model = build_model(ModelConfig("srfmp", "S2", obs_dim=3, horizon=4,
            ...                                 obs_horizon=4, down_dims=[32, 64]))
            >>> model.condition_keys()
            ['observation', 'obs_gap']
        """
        cameras = dict(camera_keys or {name: name for name in self.cameras})
        missing = [c for c in self.cameras if c not in cameras]
        if missing:
            raise ValueError(f"camera_keys lacks an entry for cameras {missing} (given: "
                             f"{sorted(cameras)})")
        out = [observation_key] if self.cfg.obs_dim > 0 else []
        out += [cameras[name] for name in self.cameras]
        if self.cfg.obs_horizon > 2:
            out.append(gap_key)
        return out

    def encode_inputs(self, *inputs: torch.Tensor) -> torch.Tensor:
        """Global condition ``(B, C)`` from the inputs named by `condition_keys`, in its order."""
        expected = (int(self.cfg.obs_dim > 0) + len(self.cameras)
                    + int(self.cfg.obs_horizon > 2))
        if len(inputs) != expected:
            raise ValueError(f"expected {expected} conditioning inputs ({self.condition_keys()}), "
                             f"got {len(inputs)}")
        rest = list(inputs)
        obs = rest.pop(0) if self.cfg.obs_dim > 0 else None
        images = {name: rest.pop(0) for name in self.cameras}
        gap = rest.pop(0) if self.cfg.obs_horizon > 2 else None
        return self.encode(obs, images or None, gap)

    def encode(
        self,
        observation: torch.Tensor | None,
        images: Mapping[str, torch.Tensor] | None = None,
        gap: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """Global condition ``(B, C)`` from the window ``[o^c, o^{s-1}]`` (raw, unnormalised)."""
        obs_ref = obs_ctx = None
        if self.cfg.obs_dim > 0:
            if observation is None:
                raise ValueError("this policy needs a low-dimensional observation window")
            if observation.shape[-2:] != (2, self.cfg.obs_dim):
                raise ValueError(
                    f"observation must have shape (B, 2, {self.cfg.obs_dim}) = [o^c, o^(s-1)], "
                    f"got {tuple(observation.shape)}"
                )
            obs = self.obs_normalizer(observation)
            obs_ctx, obs_ref = obs[..., 0, :], obs[..., 1, :]
        images_ref = images_ctx = None
        if self.cameras:
            if images is None:
                raise ValueError(f"this policy needs images for cameras {list(self.cameras)}")
            images_ref = {name: images[name][:, 1] for name in self.cameras}
            images_ctx = {name: images[name][:, 0] for name in self.cameras}
        like = obs_ref if obs_ref is not None else self.obs_normalizer.offset
        return self._run_network(self.obs_encoder, like, obs_ref, obs_ctx, gap, images_ref,
                                 images_ctx)

    # ----- actions -----------------------------------------------------------------------------
    def normalize_action(self, action: torch.Tensor) -> torch.Tensor:
        """``(B, T_p, D)`` raw actions -> flat normalised chunk ``(B, T_p * D)``."""
        return self.chunk.flatten(self.action_normalizer(action))

    def unnormalize_action(self, x: torch.Tensor) -> torch.Tensor:
        """Flat normalised chunk -> ``(B, T_p, D)`` raw actions, projected onto the manifold."""
        return self.step_manifold.projx(self.action_normalizer.unnormalize(self.chunk.unflatten(x)))

    @property
    def noise_dim(self) -> int:
        """Size of the standard-normal prior noise per sample."""
        raise NotImplementedError

    def prior_noise_dim(self, nfe: int) -> int:
        """Width of the standard-normal prior noise a sample with ``nfe`` evaluations takes (the
        ONNX graph's ``prior_noise`` input): `noise_dim` (CP's multistep sampling, one draw per
        evaluation)."""
        return self.noise_dim


class FlowModel(PolicyModel):
    """RFMP (geodesic path, Eq. 6) or SRFMP (stable path with pseudo-time, Eqs. 17-18).

    Example:
        >>> model = build_model(ModelConfig(algorithm="rfmp", action_manifold="S2", obs_dim=3,
        ...                                 horizon=4, down_dims=[32, 64]))
        >>> obs = torch.randn(5, 2, 3)
        >>> model.sample(model.encode(obs), nfe=2).shape
        torch.Size([5, 4, 3])
    """

    def __init__(self, cfg: ModelConfig) -> None:
        super().__init__(cfg)
        self.stable = cfg.algorithm == "srfmp"
        step_prior = make_prior(
            self.step_manifold, sphere=cfg.prior_sphere, scale=cfg.prior_scale, std=cfg.prior_std
        )
        self.prior = HorizonPrior(step_prior, cfg.horizon, repeat=cfg.prior_repeat)
        if self.stable:
            self.state_manifold: Manifold = Product([self.chunk, Euclidean(1)])
        else:
            self.state_manifold = self.chunk

    @property
    def noise_dim(self) -> int:
        return self.prior.noise_dim

    def velocity(
        self, x: torch.Tensor, time: torch.Tensor, cond: torch.Tensor
    ) -> torch.Tensor | tuple[torch.Tensor, torch.Tensor]:
        """Network velocity on a flat chunk ``x (B, T_p * D)`` at ``time (B, 1)``.

        ``time`` is the flow time t for RFMP and the pseudo-time tau for SRFMP; SRFMP returns
        ``(v_x, v_tau)`` and gives the network tau clamped to the trained range
        (`ModelConfig.tau_max`). Velocities are projected onto the tangent space at x.
        """
        if self.stable and self.cfg.tau_max is not None:
            lo, hi = sorted((self.cfg.tau0, self.cfg.tau_max))
            time = time.clamp(lo, hi)
        out = self._run_network(self.network, x, self.chunk.unflatten(x), time.reshape(-1), cond)
        if self.stable:
            v_x, v_tau = out
            return self.chunk.proju(x, self.chunk.flatten(v_x)), v_tau
        return self.chunk.proju(x, self.chunk.flatten(out))

    def initial_state(
        self,
        noise: torch.Tensor | None,
        batch: int,
        deterministic: bool = False,
        like: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """Flow state at t = 0 from prior noise ``(B, noise_dim)`` (or the prior's mode)."""
        dtype = like.dtype if like is not None else None
        device = like.device if like is not None else None
        if deterministic:
            x0 = self.prior.mode(batch, dtype=dtype, device=device)
        elif noise is None:
            x0 = self.prior.sample(batch, dtype=dtype, device=device)
        else:
            if noise.shape[-1] != self.noise_dim:
                raise ValueError(
                    f"prior noise must have last dimension {self.noise_dim}, got "
                    f"{tuple(noise.shape)}"
                )
            x0 = self.prior.from_noise(noise)
        if self.stable:
            x0 = torch.cat([x0, torch.full_like(x0[..., :1], self.cfg.tau0)], dim=-1)
        return x0

    def sample(
        self,
        cond: torch.Tensor,
        noise: torch.Tensor | None = None,
        *,
        nfe: int = 1,
        method: str = "euler",
        t_end: float = 1.0,
        schedule: str | None = None,
        refine_dt: float | None = None,
        deterministic: bool = False,
        return_intermediates: bool = False,
    ) -> torch.Tensor | tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Integrate the learned field from the prior; returns raw actions ``(B, T_p, D)``.

        ``schedule`` defaults to ``"srfmp"`` for SRFMP and ``"uniform"`` for RFMP. With
        ``return_intermediates`` also returns the times and the raw action chunks visited
        ``(n + 1, B, T_p, D)``.
        """
        schedule = schedule or DEFAULT_SCHEDULES[self.cfg.algorithm]
        x0 = self.initial_state(noise, cond.shape[0], deterministic, like=cond)
        if self.stable:
            dim = self.chunk.dim

            def field(t: torch.Tensor, state: torch.Tensor) -> torch.Tensor:
                v_x, v_tau = self.velocity(state[..., :dim], state[..., dim:], cond)
                return torch.cat([v_x, v_tau], dim=-1)
        else:

            def field(t: torch.Tensor, state: torch.Tensor) -> torch.Tensor:
                return self.velocity(state, t, cond)

        result = integrate(
            field,
            x0,
            self.state_manifold,
            nfe,
            method,
            t_end,
            schedule,
            lambda_x=self.cfg.lambda_x,
            refine_dt=refine_dt,
            return_intermediates=return_intermediates,
        )
        if not return_intermediates:
            return self.unnormalize_action(result[..., : self.chunk.dim])
        final, times, states = result
        actions = self.unnormalize_action(states[..., : self.chunk.dim])
        return self.unnormalize_action(final[..., : self.chunk.dim]), times, actions


def squaredcos_cap_v2_betas(num_steps: int, max_beta: float = 0.999) -> torch.Tensor:
    """The cosine noise schedule of Nichol & Dhariwal (2021), as used by Diffusion Policy."""

    def alpha_bar(t: float) -> float:
        return math.cos((t + 0.008) / 1.008 * math.pi / 2) ** 2

    betas = [
        min(1 - alpha_bar((i + 1) / num_steps) / alpha_bar(i / num_steps), max_beta)
        for i in range(num_steps)
    ]
    return torch.tensor(betas, dtype=torch.float64)


class DiffusionModel(PolicyModel):
    """Diffusion Policy baseline: epsilon prediction, 100 training steps, DDIM sampling.

    Sampling runs DDIM (eta = 0) with ``nfe`` evenly spaced steps, then projects the chunk onto
    the action manifold (the paper's post-processing for sphere components).

    Example:
        >>> model = build_model(ModelConfig(algorithm="ddim", action_manifold="S2", obs_dim=3,
        ...                                 horizon=4, down_dims=[32, 64]))
        >>> norms = model.sample(model.encode(torch.randn(5, 2, 3)), nfe=10).norm(dim=-1)
        >>> round(norms.mean().item(), 5)  # on S^2 to float32 rounding
        1.0
    """

    def __init__(self, cfg: ModelConfig) -> None:
        super().__init__(cfg)
        betas = squaredcos_cap_v2_betas(cfg.num_diffusion_steps)
        self.register_buffer("alphas_cumprod", torch.cumprod(1 - betas, 0).to(torch.float32))

    @property
    def noise_dim(self) -> int:
        return self.chunk.dim

    def add_noise(self, x: torch.Tensor, eps: torch.Tensor, k: torch.Tensor) -> torch.Tensor:
        """Forward process ``sqrt(ab_k) x + sqrt(1 - ab_k) eps`` for integer steps ``k (B,)``."""
        ab = self.alphas_cumprod[k].unsqueeze(-1)  # (B, 1)
        return ab.sqrt() * x + (1 - ab).sqrt() * eps

    def predict_noise(self, x: torch.Tensor, k: torch.Tensor, cond: torch.Tensor) -> torch.Tensor:
        out = self._run_network(self.network, x, self.chunk.unflatten(x), k.to(x.dtype), cond)
        return self.chunk.flatten(out)

    def ddim_timesteps(self, nfe: int) -> list[int]:
        total = self.cfg.num_diffusion_steps
        if not 1 <= nfe <= total:
            raise ValueError(f"DDIM NFE must be in [1, {total}], got {nfe}")
        ratio = total // nfe
        return [i * ratio for i in range(nfe)][::-1]

    def sample(
        self,
        cond: torch.Tensor,
        noise: torch.Tensor | None = None,
        *,
        nfe: int = 10,
        deterministic: bool = False,
        **unused: Any,
    ) -> torch.Tensor:
        batch = cond.shape[0]
        if deterministic:
            x = torch.zeros(batch, self.noise_dim, dtype=cond.dtype, device=cond.device)
        elif noise is None:
            x = torch.randn(batch, self.noise_dim, dtype=cond.dtype, device=cond.device)
        else:
            if noise.shape[-1] != self.noise_dim:
                raise ValueError(
                    f"DDIM noise must have last dimension {self.noise_dim}, "
                    f"got {tuple(noise.shape)}"
                )
            x = noise
        steps = self.ddim_timesteps(nfe)
        ratio = self.cfg.num_diffusion_steps // nfe
        for k in steps:
            ab = self.alphas_cumprod[k]
            ab_prev = self.alphas_cumprod[k - ratio] if k - ratio >= 0 else ab.new_tensor(1.0)
            k_in = torch.full((batch,), float(k), dtype=cond.dtype, device=cond.device)
            eps = self.predict_noise(x, k_in, cond)
            x0 = (x - (1 - ab).sqrt() * eps) / ab.sqrt()
            if self.cfg.clip_sample:
                x0 = x0.clamp(-1.0, 1.0)
                eps = (x - ab.sqrt() * x0) / (1 - ab).sqrt()
            x = ab_prev.sqrt() * x0 + (1 - ab_prev).sqrt() * eps
        return self.unnormalize_action(self.chunk.projx(x))


def build_model(cfg: ModelConfig | Mapping[str, Any]) -> FlowModel | DiffusionModel:
    """Build the network for a config (a `ModelConfig` or its dict)."""
    if not isinstance(cfg, ModelConfig):
        cfg = ModelConfig.from_dict(cfg)
    if cfg.algorithm == "cp":
        from rfmp_rl.modules.consistency import ConsistencyModel

        return ConsistencyModel(cfg)
    return DiffusionModel(cfg) if cfg.algorithm == "ddim" else FlowModel(cfg)


def unwrap_policy_model(obj: Any, what: str) -> PolicyModel:
    """The `PolicyModel` inside ``obj``: the model itself, a `FlowPolicy`, TorchRL's
    ``MultiStepActorWrapper`` around one, a ``TensorDictModule``, an `EMA` (its averaged copy) or
    a ``DistributedDataParallel`` wrapper. ``what`` names the caller in the error.

    Raises:
        TypeError: naming what was given and what is expected.

    Example:
        >>> model = build_model(ModelConfig("rfmp", "S2", obs_dim=3, horizon=4,
        ...                                 down_dims=[32, 64]))
        >>> from rfmp_rl.modules import FlowPolicy
        >>> unwrap_policy_model(FlowPolicy(model), "make_loss") is model
        True
    """
    given = obj
    for _ in range(8):
        if isinstance(obj, PolicyModel):
            return obj
        inner = next((getattr(obj, name) for name in ("model", "actor", "module")
                      if isinstance(getattr(obj, name, None), nn.Module)), None)
        if inner is None:
            break
        obj = inner
    raise TypeError(f"{what} takes a policy model (FlowModel or DiffusionModel), a FlowPolicy, "
                    f"or a wrapper of one (MultiStepActorWrapper, EMA, DistributedDataParallel); "
                    f"got {type(given).__name__}")
