"""Tests for rfmp_rl.models.unet (Diffusion Policy's FiLM-conditioned 1-D UNet)."""

from __future__ import annotations

from collections.abc import Sequence

import pytest
import torch
from torch import nn

from rfmp_rl.models import (
    UNET_PRESETS,
    ConditionalResidualBlock1D,
    ConditionalUnet1D,
    make_unet,
)

# A tiny configuration with the paper's structure (3 levels, kernel 5, 8 groups) for fast tests.
TINY = {"time_embed_dim": 32, "down_dims": (16, 32, 64), "kernel_size": 5, "n_groups": 8}


def n_params(module: nn.Module) -> int:
    return sum(p.numel() for p in module.parameters())


def tiny_unet(input_dim: int = 2, global_cond_dim: int = 6, **kw: object) -> ConditionalUnet1D:
    torch.manual_seed(0)
    return ConditionalUnet1D(input_dim, global_cond_dim, **{**TINY, **kw})  # type: ignore[arg-type]


@pytest.mark.parametrize("horizon", [4, 8, 16, 1, 5, 7])
def test_output_shape_for_prediction_horizons(horizon: int) -> None:
    net = tiny_unet(input_dim=3)
    out = net(torch.randn(4, horizon, 3), torch.rand(4), torch.randn(4, 6))
    assert out.shape == (4, horizon, 3)
    assert torch.isfinite(out).all()


def test_time_shapes_are_equivalent() -> None:
    net = tiny_unet().eval()
    x, c = torch.randn(3, 8, 2), torch.randn(3, 6)
    t = torch.tensor(0.7)
    ref = net(x, t.repeat(3), c)
    torch.testing.assert_close(net(x, t.repeat(3, 1), c), ref)
    torch.testing.assert_close(net(x, t, c), ref)


def test_film_and_time_change_the_output() -> None:
    net = tiny_unet()
    x, t, c = torch.randn(4, 16, 2), torch.rand(4), torch.randn(4, 6)
    base = net(x, t, c)
    assert (net(x, t, c + 0.5) - base).abs().max() > 1e-3
    assert (net(x, (t + 0.3) % 1.0, c) - base).abs().max() > 1e-3
    assert (net(x + 0.5, t, c) - base).abs().max() > 1e-3


@pytest.mark.parametrize("predict_scale", [True, False])
def test_film_known_answer(predict_scale: bool) -> None:
    torch.manual_seed(0)
    block = ConditionalResidualBlock1D(4, 8, cond_dim=3, cond_predict_scale=predict_scale)
    linear = block.film[1]
    assert isinstance(linear, nn.Linear)
    scale = torch.linspace(0.5, 2.0, 8)
    bias = torch.linspace(-1.0, 1.0, 8)
    with torch.no_grad():
        linear.weight.zero_()  # the FiLM output is then its bias, whatever the condition
        linear.bias.copy_(torch.cat([scale, bias]) if predict_scale else bias)
    x = torch.randn(2, 4, 10)
    h = block.conv1(x)
    h = scale.view(1, 8, 1) * h + bias.view(1, 8, 1) if predict_scale else h + bias.view(1, 8, 1)
    expected = block.conv2(h) + block.residual(x)
    torch.testing.assert_close(block(x, torch.randn(2, 3)), expected)


def test_predict_tau_returns_pair() -> None:
    net = tiny_unet(predict_tau=True, tau_hidden_dim=16)
    x, c = torch.randn(4, 16, 2), torch.randn(4, 6)
    v_x, v_tau = net(x, torch.rand(4), c)
    assert v_x.shape == (4, 16, 2)
    assert v_tau.shape == (4, 1)
    # v_tau depends on tau, and the RFMP-mode model returns a single tensor.
    _, v_tau2 = net(x, torch.rand(4) + 1.0, c)
    assert (v_tau2 - v_tau).abs().max() > 1e-4
    assert isinstance(tiny_unet()(x, torch.rand(4), c), torch.Tensor)


def test_unconditional_and_missing_condition() -> None:
    net = tiny_unet(global_cond_dim=0)
    assert net(torch.randn(2, 8, 2), torch.rand(2)).shape == (2, 8, 2)
    with pytest.raises(ValueError, match="global_cond must be given"):
        net(torch.randn(2, 8, 2), torch.rand(2), torch.randn(2, 6))
    with pytest.raises(ValueError, match="global_cond must be given"):
        tiny_unet()(torch.randn(2, 8, 2), torch.rand(2))


def test_group_norm_only_and_samples_are_independent() -> None:
    net = tiny_unet()
    assert not any(isinstance(m, nn.modules.batchnorm._BatchNorm) for m in net.modules())
    norms = [m for m in net.modules() if isinstance(m, nn.GroupNorm)]
    # 2 GroupNorms per residual block (2 x 3 down + 2 mid + 2 x 2 up = 12 blocks) + final conv.
    assert len(norms) == 2 * 12 + 1
    assert all(m.num_groups == 8 for m in norms)
    # Per-sample normalisation: a sample's output does not depend on the rest of the batch.
    x, t, c = torch.randn(6, 8, 2), torch.rand(6), torch.randn(6, 6)
    torch.testing.assert_close(net(x, t, c)[:2], net(x[:2], t[:2], c[:2]))


def test_every_parameter_gets_a_gradient() -> None:
    net = tiny_unet(predict_tau=True, tau_hidden_dim=16)
    v_x, v_tau = net(torch.randn(3, 8, 2), torch.rand(3), torch.randn(3, 6))
    (v_x.square().mean() + v_tau.square().mean()).backward()
    missing = [n for n, p in net.named_parameters() if p.grad is None or not p.grad.abs().sum()]
    assert missing == []


def _block_params(c_in: int, c_out: int, cond: int, k: int) -> int:
    convs = (c_in * k + 1) * c_out + (c_out * k + 1) * c_out
    norms = 2 * 2 * c_out
    film = (cond + 1) * 2 * c_out
    residual = (c_in + 1) * c_out if c_in != c_out else 0
    return convs + norms + film + residual


def _expected_params(d_in: int, cond: int, emb: int, dims: Sequence[int], k: int) -> int:
    total = (emb + 1) * 4 * emb + (4 * emb + 1) * emb  # time MLP
    cond_dim = emb + cond
    widths = [d_in, *dims]
    for level in range(len(dims)):
        c_in, c_out = widths[level], widths[level + 1]
        total += _block_params(c_in, c_out, cond_dim, k) + _block_params(c_out, c_out, cond_dim, k)
        if level < len(dims) - 1:
            total += (c_out * 3 + 1) * c_out  # stride-2 Conv1d
    total += 2 * _block_params(dims[-1], dims[-1], cond_dim, k)  # mid
    for level in range(len(dims) - 1, 0, -1):  # up: skip of level `level` is concatenated
        c_below = dims[level - 1]
        total += _block_params(2 * dims[level], c_below, cond_dim, k)
        total += _block_params(c_below, c_below, cond_dim, k)
        total += (c_below * 4 + 1) * c_below  # ConvTranspose1d
    total += (dims[0] * k + 1) * dims[0] + 2 * dims[0] + (dims[0] + 1) * d_in  # final
    return total


def test_parameter_count_matches_diffusion_policy_layout() -> None:
    net = tiny_unet(input_dim=3, global_cond_dim=6)
    assert n_params(net) == _expected_params(3, 6, 32, (16, 32, 64), 5)


def test_bias_only_film_is_smaller() -> None:
    with_scale = n_params(tiny_unet())
    bias_only = n_params(tiny_unet(cond_predict_scale=False))
    # Each of the 12 blocks loses (cond_dim + 1) * C_out weights of its FiLM Linear.
    blocks_c_out = 2 * (16 + 32 + 64) + 2 * 64 + 2 * (32 + 16)
    assert with_scale - bias_only == (32 + 6 + 1) * blocks_c_out


def test_presets_parameter_counts() -> None:
    """Push-T states (action 2, obs 2 x 20), and the paper's table for images/robomimic."""
    with torch.device("meta"):  # no memory, no init cost
        counts = {
            preset: (
                n_params(make_unet(preset, 2, 40)),
                n_params(make_unet(preset, 2, 40, predict_tau=True)),
            )
            for preset in UNET_PRESETS
        }
        # Paper table: Push-T images (2 steps x (512 image features + 2 agent xy)).
        pusht_img = n_params(make_unet("paper", 2, 2 * (512 + 2)))
        pusht_img_tau = n_params(make_unet("paper", 2, 2 * (512 + 2), predict_tau=True))
    for preset, (rfmp, srfmp) in counts.items():
        print(f"UNet preset {preset!r}, Push-T state: RFMP {rfmp:,} / SRFMP {srfmp:,} params")
    print(f"UNet preset 'paper', Push-T image: RFMP {pusht_img:,} / SRFMP {pusht_img_tau:,}")
    assert counts["paper"] == (65_783_298, 66_724_099)  # Diffusion Policy: ~65M
    assert counts["paper"][0] == _expected_params(2, 40, 256, (256, 512, 1024), 5)
    assert 4e6 < counts["small"][0] < 7e6
    # the small preset's time embedding scales with it: down_dims[0] = 64 (the paper's: 256)
    assert counts["small"][0] == _expected_params(2, 40, 64, (64, 128, 256), 5)
    assert pusht_img == pytest.approx(8.0e7, rel=0.01)
    assert pusht_img_tau == pytest.approx(8.14e7, rel=0.01)


def test_make_unet_overrides_and_errors() -> None:
    with torch.device("meta"):
        net = make_unet("small", 7, 10, predict_tau=True, kernel_size=3)
    assert net.down_dims == UNET_PRESETS["small"]
    assert net.predict_tau
    with pytest.raises(KeyError, match="Unknown UNet preset"):
        make_unet("huge", 2, 40)
    with pytest.raises(ValueError, match="odd"):
        ConditionalUnet1D(2, 4, kernel_size=4)
