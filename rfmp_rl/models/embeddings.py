"""Sinusoidal embeddings of a scalar per sample: flow time t (RFMP) or pseudo-time tau (SRFMP).

Diffusion Policy feeds integer diffusion steps (0..99) to its sinusoidal embedding. Flow times live
in [0, 1] (or slightly beyond, when integrating to a horizon T > 1), so we multiply them by
``scale`` before the sinusoid. The default ``scale=100`` maps t in [0, 1] onto the same argument
range as Diffusion Policy's 100 DDIM training steps: the highest frequency then completes ~16
periods over [0, 1], so nearby times (t = 0.01 vs 0.02) get clearly different embeddings, while
the lowest frequencies stay monotone over the whole range. Use ``scale=1`` for the DDIM baseline,
whose timesteps already are integers.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor, nn

__all__ = ["DEFAULT_TIME_SCALE", "SinusoidalPosEmb"]

DEFAULT_TIME_SCALE = 100.0


class SinusoidalPosEmb(nn.Module):
    """Transformer-style sinusoidal embedding of one scalar per sample.

    ``emb(t) = [sin(s t w_0), ..., sin(s t w_{h-1}), cos(s t w_0), ..., cos(s t w_{h-1})]`` with
    ``h = dim // 2``, ``s = scale`` and frequencies ``w_k = 10000^(-k / (h - 1))`` (from 1 down to
    1e-4), as in Diffusion Policy. The forward pass is branch-free tensor code, so it exports to
    ONNX unchanged.

    Args:
        dim: Embedding size; must be even and at least 4.
        scale: Factor applied to the input before the sinusoid (see the module docstring).
        max_period: Inverse of the lowest frequency.

    Example:
        >>> emb = SinusoidalPosEmb(256)
        >>> emb(torch.rand(8)).shape
        torch.Size([8, 256])
        >>> emb(torch.tensor(0.5)).shape  # a scalar gives one row, which broadcasts over a batch
        torch.Size([1, 256])
    """

    freqs: Tensor

    def __init__(
        self, dim: int, scale: float = DEFAULT_TIME_SCALE, max_period: float = 10000.0
    ) -> None:
        super().__init__()
        if dim % 2 != 0 or dim < 4:
            raise ValueError(f"SinusoidalPosEmb needs an even dim >= 4, got {dim}.")
        self.dim = dim
        self.scale = float(scale)
        half = dim // 2
        freqs = torch.exp(-math.log(max_period) * torch.arange(half) / (half - 1))  # (h,)
        # Not persistent: derived from the constructor arguments, so not in the state dict.
        self.register_buffer("freqs", freqs * self.scale, persistent=False)

    def forward(self, t: Tensor) -> Tensor:
        """Embed ``t``.

        Args:
            t: Times of shape ``()``, ``(B,)`` or ``(B, 1)``; any real or integer dtype.

        Returns:
            Embedding of shape ``(B, dim)`` (``(1, dim)`` for a scalar ``t``).
        """
        t = t.reshape(-1, 1).to(self.freqs.dtype)  # (B, 1)
        arg = t * self.freqs  # (B, h)
        return torch.cat([arg.sin(), arg.cos()], dim=-1)  # (B, dim)

    def extra_repr(self) -> str:
        return f"dim={self.dim}, scale={self.scale:g}"
