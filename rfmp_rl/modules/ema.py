"""Exponential moving average of a model's weights (decay 0.999 in the paper)."""

from __future__ import annotations

import copy

import torch
from torch import nn

__all__ = ["EMA"]


class EMA(nn.Module):
    """Keeps ``shadow = decay * shadow + (1 - decay) * weights`` after every `update`.

    Parameters are averaged; buffers (normaliser statistics, GroupNorm has none) are copied.
    Diffusion Policy's warm-up is used: the effective decay is
    ``min(decay, (1 + n) / (10 + n))`` after n updates, so early averages are not dominated by
    the random initialisation.

    Example:
        >>> net = nn.Linear(2, 2)
        >>> ema = EMA(net, decay=0.999)
        >>> ema.update(net)
        >>> ema.module(torch.zeros(1, 2)).shape
        torch.Size([1, 2])
    """

    def __init__(self, model: nn.Module, decay: float = 0.999, warmup: bool = True) -> None:
        super().__init__()
        if not 0.0 <= decay < 1.0:
            raise ValueError(f"EMA: decay must be in [0, 1), got {decay}")
        self.decay, self.warmup = float(decay), bool(warmup)
        self.module = copy.deepcopy(model).eval()
        self.module.requires_grad_(False)
        self.register_buffer("num_updates", torch.tensor(0, dtype=torch.long))
        self._count = 0  # a host copy of num_updates: no device sync per update on a GPU
        self.register_load_state_dict_post_hook(EMA._sync_count)

    @staticmethod
    def _sync_count(module: EMA, incompatible_keys) -> None:
        module._count = int(module.num_updates)

    def set_num_updates(self, n: int) -> None:
        """Restore the update count (e.g. when a run resumes)."""
        self.num_updates.fill_(int(n))
        self._count = int(n)

    def current_decay(self) -> float:
        n = self._count
        return min(self.decay, (1 + n) / (10 + n)) if self.warmup else self.decay

    @torch.no_grad()
    def update(self, model: nn.Module) -> None:
        decay = self.current_decay()
        shadow = dict(self.module.named_parameters())
        for name, p in model.named_parameters():
            shadow[name].lerp_(p.detach(), 1.0 - decay)
        shadow_buffers = dict(self.module.named_buffers())
        for name, b in model.named_buffers():
            shadow_buffers[name].copy_(b)
        self.num_updates += 1
        self._count += 1
