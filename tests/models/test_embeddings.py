"""Tests for rfmp_rl.models.embeddings."""

from __future__ import annotations

import math

import pytest
import torch

from rfmp_rl.models import DEFAULT_TIME_SCALE, SinusoidalPosEmb


@pytest.mark.parametrize("shape", [(5,), (5, 1)])
def test_shapes_batch(shape: tuple[int, ...]) -> None:
    emb = SinusoidalPosEmb(256)
    out = emb(torch.rand(shape))
    assert out.shape == (5, 256)
    assert out.dtype == torch.float32


def test_scalar_gives_one_broadcastable_row() -> None:
    emb = SinusoidalPosEmb(64)
    t = torch.tensor(0.3)
    out = emb(t)
    assert out.shape == (1, 64)
    torch.testing.assert_close(out[0], emb(t.repeat(4))[2])


def test_known_values() -> None:
    dim, scale = 8, DEFAULT_TIME_SCALE
    emb = SinusoidalPosEmb(dim)
    t = torch.tensor([0.0, 0.25])
    out = emb(t)
    # t = 0: all sines 0, all cosines 1.
    torch.testing.assert_close(out[0], torch.cat([torch.zeros(4), torch.ones(4)]))
    # Frequencies 10000^(-k/3), k = 0..3, applied to scale * t.
    freqs = torch.tensor([10000.0 ** (-k / 3) for k in range(4)])
    arg = scale * 0.25 * freqs
    torch.testing.assert_close(out[1], torch.cat([arg.sin(), arg.cos()]))
    # Every row lies on a product of unit circles: sin^2 + cos^2 = 1 per frequency.
    torch.testing.assert_close(out[:, :4] ** 2 + out[:, 4:] ** 2, torch.ones(2, 4))


def test_nearby_flow_times_are_distinguishable() -> None:
    emb = SinusoidalPosEmb(256)
    out = emb(torch.tensor([0.0, 0.01, 0.02, 0.99, 1.0]))
    dists = torch.cdist(out, out)
    off_diag = dists[~torch.eye(5, dtype=torch.bool)]
    # With scale 100, a time step of 0.01 moves the embedding by more than 1 (unit-free norm).
    assert off_diag.min() > 1.0, off_diag.min()


def test_integer_steps_with_unit_scale() -> None:
    # DDIM baseline: integer diffusion steps, no rescaling.
    emb = SinusoidalPosEmb(16, scale=1.0)
    steps = torch.tensor([0, 10, 99])
    torch.testing.assert_close(emb(steps), emb(steps.float()))
    torch.testing.assert_close(emb(steps)[1, 0], torch.tensor(math.sin(10.0)))


def test_freqs_not_in_state_dict_and_follow_dtype() -> None:
    emb = SinusoidalPosEmb(32)
    assert len(emb.state_dict()) == 0
    emb = emb.double()
    assert emb(torch.rand(3)).dtype == torch.float64


@pytest.mark.parametrize("dim", [7, 2])
def test_bad_dim_raises(dim: int) -> None:
    with pytest.raises(ValueError, match="even dim"):
        SinusoidalPosEmb(dim)
