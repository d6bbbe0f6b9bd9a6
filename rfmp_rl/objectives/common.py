"""Shared plumbing of the imitation losses: the actor, the training options, reading batches
by key, and reducing every loss term the same way."""

from __future__ import annotations

import dataclasses
import re
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import torch
from tensordict import TensorDictBase
from tensordict.utils import NestedKey
from torchrl.objectives import LossModule

from rfmp_rl import keys
from rfmp_rl.flows import GeodesicPath, StablePath
from rfmp_rl.modules.policy_model import FlowModel, PolicyModel, unwrap_policy_model
from rfmp_rl.objectives.config import LossConfig

__all__ = ["ImitationLoss", "FlowLoss", "camera_field"]

REDUCTIONS = ("mean", "sum", "none")


def camera_field(camera: str) -> str:
    """The ``_AcceptedKeys`` field of a camera: its name, with characters that cannot appear in
    a Python name replaced by ``_`` (``"agentview_image"`` stays; ``"cam.top"`` -> ``"cam_top"``).

    Example:
        >>> camera_field("observation.images.top")
        'observation_images_top'
    """
    name = re.sub(r"\W", "_", str(camera))
    return f"_{name}" if name[:1].isdigit() else name


class ImitationLoss(LossModule):
    """Base of `RFMPLoss`, `SRFMPLoss` and `DiffusionPolicyLoss`.

    A batch holds (``B`` = batch size): the observation window ``(B, 2, D_obs)`` =
    ``[o^c, o^{s-1}]``, camera windows ``(B, 2, C, H, W)``, the gap ``(B, 1)`` when T_o > 2, the
    action chunk ``(B, T_p, D)`` and ``action_is_pad (B, T_p)`` (True on steps copied past the
    end of an episode, which do not contribute to the loss).

    Args:
        actor: the policy: a `FlowPolicy` (as TorchRL's ``DiffusionBCLoss`` takes its actor), a
            wrapper of one (``MultiStepActorWrapper``, ...) or the bare policy model; the loss
            trains the network inside it (`unwrap_policy_model`).
        loss_cfg: the training-time options (`LossConfig`, or its dict; default: the defaults
            with the model's ``lambda_x``). Checked for the algorithm (`LossConfig.check`).
        camera_keys: ``{camera: batch key}``; the same as ``set_keys(<camera>=key)``.
        reduction: ``"mean"`` (default), ``"sum"`` or ``"none"``, for every ``loss_*`` term.
            ``"none"`` gives one value per sample ``(B,)``: for the per-step terms, the mean
            over that sample's non-padded steps; ``"sum"`` sums those. ``"mean"`` weighs every
            non-padded action step of the batch equally (the mean of ``"none"`` when no step is
            padded). The detached diagnostics stay scalars.
    """

    @dataclass
    class _AcceptedKeys:
        """Configurable input keys (rename with ``loss.set_keys(...)``; nested keys work).

        Attributes:
            observation: low-dimensional observation window ``(B, 2, D_obs)``.
            action: demonstrated action chunk ``(B, T_p, D)``.
            action_is_pad: padding mask ``(B, T_p)``, True where the step is padding.
            obs_gap: gap ``s - c`` between reference and context observation (T_o > 2).
            prior_noise: optional standard-normal prior noise ``(B, noise_dim)``; when the batch
                holds it the flows start from it instead of a fresh prior draw.
            flow_time: optional training times ``(B, 1)`` (t; used instead of drawing them).
                With both, a loss is a deterministic function of its batch (distributed and
                reproducibility checks).

        A loss built for a policy with cameras adds one field per camera (`camera_field` of
        its name, default key: the camera's name) for its window ``(B, 2, C, H, W)``, e.g.
        ``loss.set_keys(agentview_image="agentview_image_window")``.
        """

        observation: NestedKey = keys.OBSERVATION
        action: NestedKey = keys.ACTION
        action_is_pad: NestedKey = keys.ACTION_IS_PAD
        obs_gap: NestedKey = keys.OBS_GAP
        prior_noise: NestedKey = keys.PRIOR_NOISE
        flow_time: NestedKey = keys.FLOW_TIME

    default_keys = _AcceptedKeys

    #: The entries `forward` writes (``loss_*`` terms first, then detached diagnostics).
    _loss_out_keys: tuple[str, ...] = ()

    def __init__(
        self,
        actor: Any,
        loss_cfg: LossConfig | Mapping[str, Any] | None = None,
        *,
        camera_keys: Mapping[str, NestedKey] | None = None,
        reduction: str = "mean",
    ) -> None:
        super().__init__()
        self.model = model = unwrap_policy_model(actor, type(self).__name__)
        if reduction not in REDUCTIONS:
            raise ValueError(f"{type(self).__name__}: reduction must be one of {REDUCTIONS}, "
                             f"got {reduction!r}")
        self.reduction = reduction
        if loss_cfg is None:
            loss_cfg = LossConfig(lambda_x=model.cfg.lambda_x)
        elif not isinstance(loss_cfg, LossConfig):
            loss_cfg = LossConfig.from_dict(loss_cfg)
        self.loss_cfg = loss_cfg.check(model.cfg.algorithm)
        self._add_camera_keys(model)
        if camera_keys:
            unknown = sorted(set(camera_keys) - set(model.cameras))
            if unknown:
                raise ValueError(f"{type(self).__name__}: camera_keys names cameras {unknown} "
                                 f"the policy does not have (it has {list(model.cameras)})")
            self.set_keys(**{self._camera_fields[c]: key for c, key in camera_keys.items()})
        self.out_keys = list(self._loss_out_keys)

    def _add_camera_keys(self, model: PolicyModel) -> None:
        """One ``_AcceptedKeys`` field per camera of the policy (`camera_field`)."""
        base = type(self)._AcceptedKeys
        taken = set(base.__dataclass_fields__)
        self._camera_fields: dict[str, str] = {}
        extra = []
        for camera in model.cameras:
            name = camera_field(camera)
            if name in taken:
                raise ValueError(f"{type(self).__name__}: camera {camera!r} would be the key "
                                 f"field {name!r}, which is taken: rename the camera")
            taken.add(name)
            self._camera_fields[camera] = name
            extra.append((name, NestedKey, dataclasses.field(default=camera)))
        if extra:
            accepted = dataclasses.make_dataclass(base.__name__, extra, bases=(base,))
            accepted.__doc__ = base.__doc__
            self._AcceptedKeys = self.default_keys = accepted
            self._tensor_keys = accepted()

    def _forward_value_estimator_keys(self, **kwargs) -> None:
        pass  # no value estimator

    @property
    def camera_keys(self) -> dict[str, NestedKey]:
        """``{camera: batch key}`` as currently set."""
        return {c: getattr(self.tensor_keys, f) for c, f in self._camera_fields.items()}

    def _condition_keys(self) -> list[NestedKey]:
        k = self.tensor_keys
        return self.model.condition_keys(k.observation, self.camera_keys, k.obs_gap)

    @property
    def in_keys(self) -> list[NestedKey]:
        """The entries every batch must hold: the action chunk and the conditioning inputs.
        ``action_is_pad``, ``prior_noise`` and ``flow_time`` are read when present."""
        return [self.tensor_keys.action, *self._condition_keys()]

    def _require(self, tensordict: TensorDictBase, key: NestedKey) -> torch.Tensor:
        value = tensordict.get(key, None)
        if value is None:
            raise KeyError(
                f"{type(self).__name__}: the batch has no entry {key!r} (present: "
                f"{sorted(map(str, tensordict.keys(True, True)))}); rename with loss.set_keys(...)"
            )
        return value

    def _read(self, tensordict: TensorDictBase) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Return ``(condition (B, C), normalised flat chunk (B, T_p * D), valid (B, T_p))``."""
        k, model = self.tensor_keys, self.model
        inputs = [self._require(tensordict, key) for key in self._condition_keys()]
        action = self._require(tensordict, k.action)
        expected = (model.horizon, model.action_dim)
        if action.shape[-2:] != expected:
            raise ValueError(
                f"{type(self).__name__}: {k.action!r} must have shape (B, {expected[0]}, "
                f"{expected[1]}) = (B, T_p, D), got {tuple(action.shape)}"
            )
        pad = tensordict.get(k.action_is_pad, None)
        if pad is None:
            pad = torch.zeros(action.shape[:-1], dtype=torch.bool, device=action.device)
        cond = model.encode_inputs(*inputs)
        return cond, model.normalize_action(action), ~pad.to(torch.bool)

    # ----- reduction ---------------------------------------------------------------------------
    def _reduce_steps(
        self, per_step: torch.Tensor, tensordict: TensorDictBase, valid: torch.Tensor
    ) -> torch.Tensor:
        """A per-step term ``(B, T_p)`` reduced as ``reduction`` says (padded steps excluded)."""
        if self.reduction == "mean":  # every valid step of the batch counts once
            return self._reduce_loss(per_step, tensordict, mask=valid)
        kept = torch.where(valid, per_step, torch.zeros_like(per_step))
        per_sample = kept.sum(-1) / valid.sum(-1).clamp_min(1)  # (B,)
        return self._reduce_loss(per_sample, tensordict)

    def _reduce_samples(self, per_sample: torch.Tensor, tensordict: TensorDictBase
                        ) -> torch.Tensor:
        """A per-sample term ``(B,)`` or ``(B, 1)`` reduced as ``reduction`` says."""
        return self._reduce_loss(per_sample.reshape(per_sample.shape[0]), tensordict)


class FlowLoss(ImitationLoss):
    """Base of the two flow-matching losses: the conditional path and the training times."""

    def __init__(self, actor: Any, loss_cfg=None, *, camera_keys=None,
                 reduction: str = "mean") -> None:
        super().__init__(actor, loss_cfg, camera_keys=camera_keys, reduction=reduction)
        model: FlowModel = self.model
        cfg = self.loss_cfg
        if model.stable:
            if cfg.lambda_x != model.cfg.lambda_x:
                raise ValueError(
                    f"{type(self).__name__}: LossConfig.lambda_x={cfg.lambda_x} differs from the "
                    f"policy's ModelConfig.lambda_x={model.cfg.lambda_x}; inference integrates "
                    "with the model's (SRFMP's first step is 1/lambda_x): set both alike"
                )
            self.path = StablePath(model.chunk, cfg.lambda_x, cfg.lambda_tau, model.cfg.tau0,
                                   model.cfg.tau1)
            trained = cfg.trained_tau_max(self.path)
            if model.cfg.tau_max is None:  # recorded in the model config (and its checkpoints)
                model.cfg.tau_max = trained
            elif abs(model.cfg.tau_max - trained) > 1e-6:
                raise ValueError(
                    f"{type(self).__name__}: the policy's ModelConfig.tau_max="
                    f"{model.cfg.tau_max:.6g} differs from the pseudo-time this loss trains up "
                    f"to ({trained:.6g}: tau at LossConfig.time_max={cfg.time_max}, lambda_tau="
                    f"{cfg.lambda_tau}); sampling clamps the network's tau there: set "
                    "ModelConfig.tau_max=None to record this loss's"
                )
        else:
            self.path = GeodesicPath(model.chunk)

    def sample_times(self, batch: int, device=None, dtype=None) -> torch.Tensor:
        """Training flow times ``(B, 1)`` (`LossConfig.sample_times`)."""
        return self.loss_cfg.sample_times(batch, self.path, device=device, dtype=dtype)

    def _flow_target(self, tensordict: TensorDictBase):
        """Condition, a path sample (x_t, u_t, t[, tau_t, u_tau]) and the valid-step mask.

        Draws ``a_0 ~ p_0`` (one base action repeated over the horizon) and the flow times, and
        builds the conditional path from ``a_0`` to the demonstrated chunk.
        """
        model = self.model
        cond, x1, valid = self._read(tensordict)
        batch = x1.shape[0]
        k = self.tensor_keys
        noise = tensordict.get(k.prior_noise, None)
        if noise is None:
            x0 = model.prior.sample(batch, dtype=x1.dtype, device=x1.device)
        else:
            x0 = model.prior.from_noise(noise.to(x1.dtype))
        t = tensordict.get(k.flow_time, None)
        if t is None:
            t = self.sample_times(batch, device=x1.device, dtype=x1.dtype)
        else:
            t = t.reshape(batch, 1).to(x1.dtype)
        return cond, self.path.sample(x0, x1, t), valid

    def _per_step_sqnorm(self, x: torch.Tensor, err: torch.Tensor) -> torch.Tensor:
        """Riemannian squared norm of ``err`` at ``x`` per action step: ``(B, T_p)``."""
        chunk = self.model.chunk
        sq = chunk.step.inner(chunk.unflatten(x), chunk.unflatten(err), chunk.unflatten(err))
        return sq.squeeze(-1)
