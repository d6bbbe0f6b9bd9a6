"""The paper's observation vector o = [o^{s-1}, o^c, s - c] (section "Riemannian Flow Matching
Policy").

RFMP conditions on a reference observation o^{s-1}, a context observation o^c with c drawn
uniformly from [s - T_o, s - 2], and the gap s - c. With T_o = 2 the context is always o^{s-2}, so
the gap carries no information and is dropped: o = [o^{s-1}, o^c]. Each step's observation is its
low-dimensional part followed by the features of every camera; both steps go through the same
per-camera vision encoder. The gap enters as ``(s - c) / T_o`` so it lies in (0, 1].
"""

from __future__ import annotations

from collections.abc import Mapping

import torch
from torch import Tensor, nn

from rfmp_rl.models.vision import MultiCameraEncoder

__all__ = ["ObservationEncoder"]


class ObservationEncoder(nn.Module):
    """Build the conditioning vector ``o = [o^{s-1}, o^c, (s - c) / T_o]``, shape ``(B, out_dim)``.

    Layout of the output: ``[low_dim(ref), cams(ref), low_dim(ctx), cams(ctx), gap]`` where
    ``cams`` are the camera features in the order of ``vision.cameras`` and ``gap`` is present
    only when ``obs_horizon > 2``.

    Args:
        obs_dim: Low-dimensional observation size per step (0 for images only).
        obs_horizon: The observation horizon T_o (>= 2).
        vision: Optional per-camera image encoder, shared by the two steps.

    Example:
        >>> enc = ObservationEncoder(obs_dim=20, obs_horizon=2)
        >>> enc(torch.randn(8, 20), torch.randn(8, 20)).shape
        torch.Size([8, 40])
        >>> enc4 = ObservationEncoder(obs_dim=20, obs_horizon=4)
        >>> enc4(torch.randn(8, 20), torch.randn(8, 20), gap=torch.full((8,), 3)).shape
        torch.Size([8, 41])
    """

    def __init__(
        self, obs_dim: int, obs_horizon: int = 2, vision: MultiCameraEncoder | None = None
    ) -> None:
        super().__init__()
        if obs_horizon < 2:
            raise ValueError(f"obs_horizon must be >= 2 (reference + context), got {obs_horizon}.")
        if obs_dim == 0 and vision is None:
            raise ValueError("ObservationEncoder needs low-dimensional observations or cameras.")
        self.obs_dim = obs_dim
        self.obs_horizon = obs_horizon
        self.vision = vision
        self.use_gap = obs_horizon > 2
        self.step_dim = obs_dim + (vision.out_dim if vision is not None else 0)
        self.out_dim = 2 * self.step_dim + int(self.use_gap)

    def forward(
        self,
        obs_ref: Tensor | None,
        obs_ctx: Tensor | None,
        gap: Tensor | None = None,
        images_ref: Mapping[str, Tensor] | None = None,
        images_ctx: Mapping[str, Tensor] | None = None,
    ) -> Tensor:
        """Encode one observation pair.

        Args:
            obs_ref: Low-dimensional reference observation o^{s-1}, ``(B, obs_dim)``; None when
                ``obs_dim == 0``.
            obs_ctx: Low-dimensional context observation o^c, ``(B, obs_dim)``; None when
                ``obs_dim == 0``.
            gap: The gap s - c in steps, ``(B,)`` or ``(B, 1)``; required when T_o > 2, ignored
                when T_o = 2.
            images_ref: ``{camera: (B, C, H, W)}`` at step s - 1 (required with ``vision``).
            images_ctx: ``{camera: (B, C, H, W)}`` at step c (required with ``vision``).

        Returns:
            The observation vector of shape ``(B, out_dim)``.
        """
        ref_parts: list[Tensor] = []
        ctx_parts: list[Tensor] = []
        if self.obs_dim > 0:
            if obs_ref is None or obs_ctx is None:
                raise ValueError("obs_ref and obs_ctx are required when obs_dim > 0.")
            ref_parts.append(obs_ref)
            ctx_parts.append(obs_ctx)
        if self.vision is not None:
            if images_ref is None or images_ctx is None:
                raise ValueError("images_ref and images_ctx are required with a vision encoder.")
            # One pass of each camera encoder over both steps: (2B, C, H, W) -> (2B, F).
            both = {
                name: torch.cat([images_ref[name], images_ctx[name]], dim=0)
                for name in self.vision.cameras
            }
            feats = self.vision(both)  # (2B, F)
            feat_ref, feat_ctx = feats.unflatten(0, (2, -1)).unbind(0)  # (B, F) each
            ref_parts.append(feat_ref)
            ctx_parts.append(feat_ctx)
        parts = ref_parts + ctx_parts
        if self.use_gap:
            if gap is None:
                raise ValueError(f"gap is required when obs_horizon = {self.obs_horizon} > 2.")
            batch = parts[0].shape[0]
            gap = gap.reshape(batch, 1).to(parts[0].dtype) / self.obs_horizon  # (B, 1)
            parts.append(gap)
        return torch.cat(parts, dim=-1)  # (B, out_dim)
