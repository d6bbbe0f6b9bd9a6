"""Vision backbone of Diffusion Policy, as used by RFMP/SRFMP for image observations.

A standard ResNet-18 (torchvision, randomly initialised) in which, following the paper (section
"RFMP and SRFMP Implementation"):

1. every BatchNorm2d is replaced by GroupNorm with ``channels // 16`` groups (BatchNorm's running
   statistics interact badly with the EMA of the weights), and
2. the global average pooling is replaced by a spatial-softmax keypoint layer.

Images are cropped first: a random crop per sample in training mode, the centre crop in eval
mode. :data:`PAPER_CROP_SHAPES` lists the crops of the paper's hyperparameter table.

Input images are ``uint8`` in [0, 255] (scaled to [0, 1] inside) or floating point already in
[0, 1], laid out ``(..., C, H, W)``. No ImageNet mean/std normalisation is applied, since the
backbone is trained from scratch.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping

import torch
import torchvision
from torch import Tensor, nn

__all__ = [
    "PAPER_CROP_SHAPES",
    "CropRandomizer",
    "MultiCameraEncoder",
    "ResNet18Encoder",
    "SpatialSoftmax",
]

# (H, W) crops from the paper's hyperparameter table (the table writes real-robot sizes as W x H).
PAPER_CROP_SHAPES: dict[str, tuple[int, int]] = {
    "pusht": (84, 84),  # 96 x 96 images
    "sphere_pusht": (84, 84),  # 100 x 100 images
    "robomimic": (76, 76),  # 84 x 84 images
    "pick_place": (216, 288),  # 240 x 320 images
    "mug_flipping": (192, 256),  # 240 x 320 images
}


class CropRandomizer(nn.Module):
    """Crop images to ``crop_shape``: random per sample when training, centred in eval mode.

    The only Python branch is on ``self.training`` (fixed when a graph is exported), so the eval
    path exports to ONNX as a constant slice.

    Args:
        crop_shape: Output ``(height, width)``.

    Example:
        >>> crop = CropRandomizer((84, 84))
        >>> crop(torch.zeros(8, 3, 96, 96, dtype=torch.uint8)).shape
        torch.Size([8, 3, 84, 84])
    """

    def __init__(self, crop_shape: tuple[int, int]) -> None:
        super().__init__()
        self.crop_shape = (int(crop_shape[0]), int(crop_shape[1]))

    def forward(self, images: Tensor) -> Tensor:
        """Crop ``images`` of shape ``(B, C, H, W)`` to ``(B, C, crop_h, crop_w)``."""
        height, width = images.shape[-2:]
        crop_h, crop_w = self.crop_shape
        if height < crop_h or width < crop_w:
            raise ValueError(
                f"Images of size {height}x{width} are smaller than the crop {crop_h}x{crop_w}."
            )
        if not self.training:
            top, left = (height - crop_h) // 2, (width - crop_w) // 2
            return images[..., top : top + crop_h, left : left + crop_w]
        batch, device = images.shape[0], images.device
        top = torch.randint(0, height - crop_h + 1, (batch, 1, 1), device=device)
        left = torch.randint(0, width - crop_w + 1, (batch, 1, 1), device=device)
        rows = top + torch.arange(crop_h, device=device).view(1, crop_h, 1)  # (B, crop_h, 1)
        cols = left + torch.arange(crop_w, device=device).view(1, 1, crop_w)  # (B, 1, crop_w)
        index = torch.arange(batch, device=device).view(batch, 1, 1)
        crops = images.permute(0, 2, 3, 1)[index, rows, cols]  # (B, crop_h, crop_w, C)
        return crops.permute(0, 3, 1, 2)  # (B, C, crop_h, crop_w)

    def extra_repr(self) -> str:
        return f"crop_shape={self.crop_shape}"


class SpatialSoftmax(nn.Module):
    """Spatial-softmax keypoints (Levine et al.; robomimic's pooling used by Diffusion Policy).

    A 1x1 convolution maps the feature map to ``num_keypoints`` channels; each channel is turned
    into a distribution over the H x W positions by a softmax, and its expected (x, y) position on
    a [-1, 1] grid is returned. Keypoints are therefore always in [-1, 1].

    Args:
        in_channels: Channels of the input feature map.
        num_keypoints: Number of keypoints K.
        temperature: Softmax temperature.

    Example:
        >>> pool = SpatialSoftmax(512, num_keypoints=32)
        >>> pool(torch.randn(4, 512, 3, 3)).shape  # [x_0, y_0, x_1, y_1, ...]
        torch.Size([4, 64])
    """

    def __init__(self, in_channels: int, num_keypoints: int = 32, temperature: float = 1.0):
        super().__init__()
        self.num_keypoints = num_keypoints
        self.temperature = float(temperature)
        self.proj = nn.Conv2d(in_channels, num_keypoints, kernel_size=1)
        self.out_dim = 2 * num_keypoints

    def forward(self, features: Tensor) -> Tensor:
        """Map ``(B, C, H, W)`` features to keypoints ``(B, 2K)`` ordered ``[x_0, y_0, ...]``."""
        logits = self.proj(features)  # (B, K, H, W)
        batch, k, height, width = logits.shape
        prob = torch.softmax(logits.reshape(batch, k, height * width) / self.temperature, dim=-1)
        ys = torch.linspace(-1.0, 1.0, height, device=logits.device, dtype=logits.dtype)
        xs = torch.linspace(-1.0, 1.0, width, device=logits.device, dtype=logits.dtype)
        grid_y, grid_x = torch.meshgrid(ys, xs, indexing="ij")  # (H, W) each
        grid = torch.stack([grid_x.reshape(-1), grid_y.reshape(-1)], dim=-1)  # (H W, 2)
        keypoints = prob @ grid  # (B, K, 2)
        return keypoints.reshape(batch, 2 * k)  # (B, 2K)


def _batchnorm_to_groupnorm(module: nn.Module, group_size: int) -> None:
    """Replace, in place, every BatchNorm2d in ``module`` by GroupNorm(channels // group_size)."""
    for name, child in module.named_children():
        if isinstance(child, nn.BatchNorm2d):
            channels = child.num_features
            setattr(module, name, nn.GroupNorm(channels // group_size, channels))
        else:
            _batchnorm_to_groupnorm(child, group_size)


class ResNet18Encoder(nn.Module):
    """Crop -> ResNet-18 trunk (GroupNorm) -> spatial softmax (or average pool) -> Linear.

    Args:
        crop_shape: ``(height, width)`` of the crop, or None to use the images as they are.
        in_channels: Image channels (3 for RGB; the first convolution is rebuilt otherwise).
        pool: ``"spatial_softmax"`` (paper, Diffusion Policy) or ``"avg"`` (ResNet's global
            average pooling, 512 features).
        num_keypoints: Keypoints of the spatial softmax (gives ``2 * num_keypoints`` features).
        out_dim: Size of the final Linear layer; None to return the pooled features directly.
            The default 512 matches the paper's parameter counts (Diffusion Policy uses 64).
        group_size: Channels per GroupNorm group (16 gives ``channels // 16`` groups).

    Example:
        >>> enc = ResNet18Encoder(crop_shape=(84, 84), out_dim=64).eval()
        >>> enc(torch.zeros(2, 3, 96, 96, dtype=torch.uint8)).shape
        torch.Size([2, 64])
    """

    def __init__(
        self,
        crop_shape: tuple[int, int] | None,
        in_channels: int = 3,
        pool: str = "spatial_softmax",
        num_keypoints: int = 32,
        out_dim: int | None = 512,
        group_size: int = 16,
    ) -> None:
        super().__init__()
        self.crop = CropRandomizer(crop_shape) if crop_shape is not None else nn.Identity()
        resnet = torchvision.models.resnet18(weights=None)
        if in_channels != 3:
            resnet.conv1 = nn.Conv2d(
                in_channels, 64, kernel_size=7, stride=2, padding=3, bias=False
            )
        _batchnorm_to_groupnorm(resnet, group_size)
        # The convolutional trunk: everything but the global average pool and the classifier.
        self.trunk = nn.Sequential(
            resnet.conv1,
            resnet.bn1,
            resnet.relu,
            resnet.maxpool,
            resnet.layer1,
            resnet.layer2,
            resnet.layer3,
            resnet.layer4,
        )
        trunk_channels = 512
        if pool == "spatial_softmax":
            self.pool: nn.Module = SpatialSoftmax(trunk_channels, num_keypoints)
            pooled_dim = 2 * num_keypoints
        elif pool == "avg":
            self.pool = nn.Sequential(nn.AdaptiveAvgPool2d(1), nn.Flatten())
            pooled_dim = trunk_channels
        else:
            raise ValueError(f"pool must be 'spatial_softmax' or 'avg', got {pool!r}.")
        self.head = nn.Linear(pooled_dim, out_dim) if out_dim is not None else nn.Identity()
        self.in_channels = in_channels
        self.out_dim = out_dim if out_dim is not None else pooled_dim

    def forward(self, images: Tensor) -> Tensor:
        """Encode images.

        Args:
            images: ``(..., C, H, W)``, ``uint8`` in [0, 255] or float in [0, 1].

        Returns:
            Features of shape ``(..., out_dim)``.
        """
        lead = images.shape[:-3]
        x = images.reshape(-1, *images.shape[-3:])  # (N, C, H, W)
        x = self.crop(x)  # (N, C, h, w)
        if x.dtype == torch.uint8:  # to the trunk's dtype (float16 in a half-precision export)
            x = x.to(next(self.trunk.parameters()).dtype) / 255.0
        x = self.trunk(x)  # (N, 512, h / 32, w / 32)
        x = self.head(self.pool(x))  # (N, out_dim)
        return x.reshape(*lead, self.out_dim)


class MultiCameraEncoder(nn.Module):
    """One encoder per camera; features are concatenated in the order the cameras were given.

    Args:
        encoders: ``{camera_name: encoder}``; each encoder maps ``(..., C, H, W)`` images to
            ``(..., out_dim)`` and exposes ``out_dim``.

    Example:
        >>> cams = MultiCameraEncoder.build(["agentview", "wrist"], crop_shape=(76, 76), out_dim=64)
        >>> images = {name: torch.zeros(2, 3, 84, 84, dtype=torch.uint8) for name in cams.cameras}
        >>> cams(images).shape
        torch.Size([2, 128])
    """

    def __init__(self, encoders: Mapping[str, nn.Module]) -> None:
        super().__init__()
        if len(encoders) == 0:
            raise ValueError("MultiCameraEncoder needs at least one camera.")
        self.encoders = nn.ModuleDict(dict(encoders))
        self.cameras: tuple[str, ...] = tuple(encoders)
        self.out_dim = sum(int(enc.out_dim) for enc in self.encoders.values())

    @classmethod
    def build(
        cls, cameras: Iterable[str], crop_shape: tuple[int, int] | None, **encoder_kwargs: object
    ) -> MultiCameraEncoder:
        """Make one :class:`ResNet18Encoder` per camera, all with the same settings."""
        return cls({name: ResNet18Encoder(crop_shape, **encoder_kwargs) for name in cameras})  # type: ignore[arg-type]

    def forward(self, images: Mapping[str, Tensor]) -> Tensor:
        """Encode ``{camera: (..., C, H, W)}`` into ``(..., out_dim)``."""
        missing = [name for name in self.cameras if name not in images]
        if missing:
            raise KeyError(f"Missing images for cameras {missing}; expected {list(self.cameras)}.")
        return torch.cat([self.encoders[name](images[name]) for name in self.cameras], dim=-1)
