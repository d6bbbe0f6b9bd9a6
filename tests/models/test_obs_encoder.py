"""Tests for rfmp_rl.models.obs_encoder (o = [o^{s-1}, o^c, s - c])."""

from __future__ import annotations

import pytest
import torch

from rfmp_rl.models import MultiCameraEncoder, ObservationEncoder


def test_two_steps_low_dim_is_concatenation_and_ignores_gap() -> None:
    enc = ObservationEncoder(obs_dim=20, obs_horizon=2)
    ref, ctx = torch.randn(4, 20), torch.randn(4, 20)
    out = enc(ref, ctx, gap=torch.full((4,), 2))
    assert enc.out_dim == 40
    torch.testing.assert_close(out, torch.cat([ref, ctx], dim=-1))
    torch.testing.assert_close(enc(ref, ctx), out)


@pytest.mark.parametrize("gap_shape", [(4,), (4, 1)])
def test_longer_horizon_appends_scaled_gap(gap_shape: tuple[int, ...]) -> None:
    enc = ObservationEncoder(obs_dim=3, obs_horizon=5)
    ref, ctx = torch.randn(4, 3), torch.randn(4, 3)
    gap = torch.tensor([2, 3, 4, 5]).reshape(gap_shape)
    out = enc(ref, ctx, gap=gap)
    assert enc.out_dim == 7
    assert out.shape == (4, 7)
    torch.testing.assert_close(out[:, :6], torch.cat([ref, ctx], dim=-1))
    torch.testing.assert_close(out[:, 6], torch.tensor([0.4, 0.6, 0.8, 1.0]))
    with pytest.raises(ValueError, match="gap is required"):
        enc(ref, ctx)


def test_images_use_the_shared_camera_encoders() -> None:
    torch.manual_seed(0)
    vision = MultiCameraEncoder.build(["front", "wrist"], crop_shape=(76, 76), out_dim=8).eval()
    enc = ObservationEncoder(obs_dim=2, obs_horizon=2, vision=vision).eval()
    assert enc.out_dim == 2 * (2 + 16)
    img = {n: torch.randint(0, 256, (2, 3, 84, 84), dtype=torch.uint8) for n in vision.cameras}
    img_ctx = {n: torch.randint(0, 256, (2, 3, 84, 84), dtype=torch.uint8) for n in vision.cameras}
    ref, ctx = torch.randn(2, 2), torch.randn(2, 2)
    out = enc(ref, ctx, images_ref=img, images_ctx=img_ctx)
    assert out.shape == (2, 36)
    # Layout: [low_dim(ref), cams(ref), low_dim(ctx), cams(ctx)].
    torch.testing.assert_close(out[:, :2], ref)
    torch.testing.assert_close(out[:, 2:18], vision(img))
    torch.testing.assert_close(out[:, 18:20], ctx)
    torch.testing.assert_close(out[:, 20:], vision(img_ctx))


def test_images_only() -> None:
    vision = MultiCameraEncoder.build(["cam"], crop_shape=None, out_dim=4).eval()
    enc = ObservationEncoder(obs_dim=0, obs_horizon=3, vision=vision).eval()
    img = {"cam": torch.rand(2, 3, 32, 32)}
    out = enc(None, None, gap=torch.tensor([[2], [3]]), images_ref=img, images_ctx=img)
    assert enc.out_dim == 9
    assert out.shape == (2, 9)
    torch.testing.assert_close(out[:, :4], out[:, 4:8])


def test_invalid_configurations() -> None:
    with pytest.raises(ValueError, match="obs_horizon"):
        ObservationEncoder(obs_dim=4, obs_horizon=1)
    with pytest.raises(ValueError, match="low-dimensional observations or cameras"):
        ObservationEncoder(obs_dim=0)
    with pytest.raises(ValueError, match="obs_ref and obs_ctx"):
        ObservationEncoder(obs_dim=4)(None, torch.zeros(1, 4))
