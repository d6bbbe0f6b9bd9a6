"""Tests for rfmp_rl.models.tau_head."""

from __future__ import annotations

import pytest
import torch

from rfmp_rl.models import TauHead


def test_shapes_and_broadcast_of_scalar_tau() -> None:
    torch.manual_seed(0)
    head = TauHead(global_cond_dim=6, time_embed_dim=16, hidden_dim=32)
    cond = torch.randn(4, 6)
    out = head(torch.rand(4), cond)
    assert out.shape == (4, 1)
    tau = torch.tensor(0.4)
    torch.testing.assert_close(head(tau, cond), head(tau.repeat(4), cond))
    torch.testing.assert_close(head(tau.repeat(4, 1), cond), head(tau.repeat(4), cond))


def test_depends_on_tau_and_observation() -> None:
    torch.manual_seed(0)
    head = TauHead(global_cond_dim=6, time_embed_dim=16, hidden_dim=32)
    cond = torch.randn(4, 6)
    base = head(torch.full((4,), 0.1), cond)
    assert (head(torch.full((4,), 0.9), cond) - base).abs().max() > 1e-4
    assert (head(torch.full((4,), 0.1), cond + 1.0) - base).abs().max() > 1e-4


def test_unconditional() -> None:
    head = TauHead(global_cond_dim=0, time_embed_dim=16, hidden_dim=32, num_hidden_layers=1)
    assert head(torch.rand(3)).shape == (3, 1)
    n_params = sum(p.numel() for p in head.parameters())
    # Time MLP (16 -> 64 -> 16) + Linear(16, 32) + Linear(32, 1).
    assert n_params == (16 * 64 + 64) + (64 * 16 + 16) + (16 * 32 + 32) + (32 + 1)


def test_needs_a_hidden_layer() -> None:
    with pytest.raises(ValueError, match="num_hidden_layers"):
        TauHead(4, num_hidden_layers=0)
