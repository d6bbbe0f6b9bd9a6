"""Shared plumbing of the imitation losses: reading batches by key."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import torch
from tensordict import TensorDictBase
from tensordict.utils import NestedKey
from torchrl.objectives import LossModule

from rfmp_rl import keys
from rfmp_rl.modules.policy_model import PolicyModel, unwrap_policy_model

__all__ = ["ImitationLoss"]


class ImitationLoss(LossModule):
    """Base of `RFMPLoss`, `SRFMPLoss` and `DiffusionPolicyLoss`.

    A batch holds (``B`` = batch size): the observation window ``(B, 2, D_obs)`` =
    ``[o^c, o^{s-1}]``, camera windows ``(B, 2, C, H, W)``, the gap ``(B, 1)`` when T_o > 2, the
    action chunk ``(B, T_p, D)`` and ``action_is_pad (B, T_p)`` (True on steps copied past the
    end of an episode, which do not contribute to the loss).
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
        """

        observation: NestedKey = keys.OBSERVATION
        action: NestedKey = keys.ACTION
        action_is_pad: NestedKey = keys.ACTION_IS_PAD
        obs_gap: NestedKey = keys.OBS_GAP
        prior_noise: NestedKey = keys.PRIOR_NOISE
        flow_time: NestedKey = keys.FLOW_TIME

    default_keys = _AcceptedKeys

    def __init__(
        self,
        model: PolicyModel,
        camera_keys: Mapping[str, NestedKey] | None = None,
        reduction: str = "mean",
    ) -> None:
        super().__init__()
        self.model = model = unwrap_policy_model(model, type(self).__name__)
        self.reduction = reduction
        self.camera_keys = dict(camera_keys or {name: name for name in model.cameras})
        model.condition_keys(camera_keys=self.camera_keys)  # every camera has a key

    def _forward_value_estimator_keys(self, **kwargs) -> None:
        pass  # no value estimator

    def _condition_keys(self) -> list[NestedKey]:
        k = self.tensor_keys
        return self.model.condition_keys(k.observation, self.camera_keys, k.obs_gap)

    @property
    def in_keys(self) -> list[NestedKey]:
        k = self.tensor_keys
        return [k.action, k.action_is_pad, *self._condition_keys()]

    @property
    def out_keys(self) -> list[str]:
        return [key for key in self._out_keys]

    _out_keys: tuple[str, ...] = ()

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

    def _flow_target(self, tensordict: TensorDictBase):
        """Condition, a path sample (x_t, u_t, t[, tau_t, u_tau]) and the valid-step mask.

        Draws ``a_0 ~ p_0`` (one base action repeated over the horizon) and the flow times, and
        builds the model's conditional path from ``a_0`` to the demonstrated chunk.
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
            t = model.sample_times(batch, device=x1.device, dtype=x1.dtype)
        else:
            t = t.reshape(batch, 1).to(x1.dtype)
        return cond, model.path.sample(x0, x1, t), valid

    def _per_step_sqnorm(self, x: torch.Tensor, err: torch.Tensor) -> torch.Tensor:
        """Riemannian squared norm of ``err`` at ``x`` per action step: ``(B, T_p)``."""
        chunk = self.model.chunk
        sq = chunk.step.inner(chunk.unflatten(x), chunk.unflatten(err), chunk.unflatten(err))
        return sq.squeeze(-1)
