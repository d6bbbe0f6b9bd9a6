"""Tests for rfmp_rl.models.vision (ResNet-18 with GroupNorm and spatial softmax)."""

from __future__ import annotations

import pytest
import torch
from torch import nn

from rfmp_rl.models import (
    PAPER_CROP_SHAPES,
    CropRandomizer,
    MultiCameraEncoder,
    ResNet18Encoder,
    SpatialSoftmax,
)


@pytest.fixture(scope="module")
def pusht_encoder() -> ResNet18Encoder:
    torch.manual_seed(0)
    return ResNet18Encoder(PAPER_CROP_SHAPES["pusht"], out_dim=64).eval()


def test_group_norm_replaces_batch_norm(pusht_encoder: ResNet18Encoder) -> None:
    modules = list(pusht_encoder.modules())
    assert not any(isinstance(m, nn.modules.batchnorm._BatchNorm) for m in modules)
    norms = [m for m in modules if isinstance(m, nn.GroupNorm)]
    assert len(norms) == 20  # ResNet-18 has 20 BatchNorm2d layers (incl. 3 in downsampling)
    assert all(m.num_groups == m.num_channels // 16 for m in norms)
    assert {m.num_groups for m in norms} == {4, 8, 16, 32}


def test_trunk_parameter_count_matches_paper(pusht_encoder: ResNet18Encoder) -> None:
    n_trunk = sum(p.numel() for p in pusht_encoder.trunk.parameters())
    n_total = sum(p.numel() for p in pusht_encoder.parameters())
    print(f"ResNet-18 trunk {n_trunk:,} params, encoder with spatial softmax + head {n_total:,}")
    assert n_trunk == 11_176_512  # ResNet-18 without its classifier; paper table: 1.12e7
    assert n_total == n_trunk + (512 * 32 + 32) + (64 * 64 + 64)


def test_output_shape_and_uint8_equals_float(pusht_encoder: ResNet18Encoder) -> None:
    torch.manual_seed(1)
    images = torch.randint(0, 256, (2, 3, 96, 96), dtype=torch.uint8)
    out = pusht_encoder(images)
    assert out.shape == (2, 64)
    torch.testing.assert_close(pusht_encoder(images.float() / 255.0), out)
    # Leading dimensions, e.g. (B, T_o, C, H, W), are kept.
    out_seq = pusht_encoder(images.unsqueeze(0))
    assert out_seq.shape == (1, 2, 64)
    torch.testing.assert_close(out_seq[0], out)


def test_avg_pool_and_no_head() -> None:
    enc = ResNet18Encoder((76, 76), pool="avg", out_dim=None).eval()
    assert enc.out_dim == 512
    assert enc(torch.rand(1, 3, 84, 84)).shape == (1, 512)
    enc_kp = ResNet18Encoder((76, 76), num_keypoints=16, out_dim=None, in_channels=1).eval()
    assert enc_kp.out_dim == 32
    assert enc_kp(torch.rand(1, 1, 84, 84)).shape == (1, 32)
    with pytest.raises(ValueError, match="pool"):
        ResNet18Encoder((76, 76), pool="max")


def test_spatial_softmax_keypoints_in_unit_box() -> None:
    torch.manual_seed(0)
    pool = SpatialSoftmax(8, num_keypoints=5)
    keypoints = pool(30.0 * torch.randn(4, 8, 6, 9))
    assert keypoints.shape == (4, 10)
    assert keypoints.abs().max() <= 1.0 + 1e-6


def test_spatial_softmax_known_peak() -> None:
    pool = SpatialSoftmax(1, num_keypoints=1)
    with torch.no_grad():
        pool.proj.weight.fill_(1.0)
        pool.proj.bias.zero_()
    features = torch.zeros(1, 1, 5, 7)
    features[0, 0, 1, 4] = 50.0  # row 1 of 5 -> y = -0.5, column 4 of 7 -> x = 1/3
    torch.testing.assert_close(pool(features), torch.tensor([[1.0 / 3.0, -0.5]]))
    # Uniform map: the expected position is the centre.
    torch.testing.assert_close(pool(torch.zeros(1, 1, 4, 4)), torch.zeros(1, 2))


def test_eval_crop_is_the_deterministic_centre() -> None:
    crop = CropRandomizer((3, 4)).eval()
    images = torch.arange(2 * 1 * 7 * 8).reshape(2, 1, 7, 8)
    out = crop(images)
    torch.testing.assert_close(out, images[:, :, 2:5, 2:6])
    torch.testing.assert_close(crop(images), out)


def test_train_crop_is_random_per_sample_window() -> None:
    torch.manual_seed(0)
    crop = CropRandomizer((3, 4)).train()
    images = torch.arange(16 * 2 * 7 * 8).reshape(16, 2, 7, 8)
    first, second = crop(images), crop(images)
    assert first.shape == (16, 2, 3, 4)
    assert not torch.equal(first, second)
    offsets = set()
    for b in range(16):
        # Each crop is a contiguous window of its own image, the same for all channels.
        top, left = divmod(int(first[b, 0, 0, 0] - images[b, 0, 0, 0]), 8)
        offsets.add((top, left))
        torch.testing.assert_close(first[b], images[b, :, top : top + 3, left : left + 4])
    assert len(offsets) > 1  # different offsets within one batch


def test_crop_larger_than_image_raises() -> None:
    with pytest.raises(ValueError, match="smaller than the crop"):
        CropRandomizer((84, 84))(torch.zeros(1, 3, 76, 76))


def test_multi_camera_concatenates_in_camera_order() -> None:
    torch.manual_seed(0)
    cams = MultiCameraEncoder.build(["agentview", "wrist"], crop_shape=(76, 76), out_dim=8).eval()
    assert cams.cameras == ("agentview", "wrist")
    assert cams.out_dim == 16
    images = {
        "wrist": torch.randint(0, 256, (2, 3, 84, 84), dtype=torch.uint8),
        "agentview": torch.randint(0, 256, (2, 3, 84, 84), dtype=torch.uint8),
    }
    out = cams(images)
    assert out.shape == (2, 16)
    torch.testing.assert_close(out[:, :8], cams.encoders["agentview"](images["agentview"]))
    torch.testing.assert_close(out[:, 8:], cams.encoders["wrist"](images["wrist"]))
    with pytest.raises(KeyError, match="wrist"):
        cams({"agentview": images["agentview"]})
