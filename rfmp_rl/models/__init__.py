"""Pure-PyTorch networks of RFMP/SRFMP: plain ``nn.Module``s on tensors (no TensorDict).

- :class:`SinusoidalPosEmb`: embedding of the flow time t / pseudo-time tau.
- :class:`ConditionalUnet1D`, :func:`make_unet`, :data:`UNET_PRESETS`: Diffusion Policy's
  FiLM-conditioned 1-D temporal UNet, optionally with SRFMP's :class:`TauHead`.
- :class:`ResNet18Encoder`, :class:`MultiCameraEncoder`, :class:`SpatialSoftmax`,
  :class:`CropRandomizer`: the vision backbone (ResNet-18 with GroupNorm and spatial softmax).
- :class:`ObservationEncoder`: the observation vector o = [o^{s-1}, o^c, s - c].
"""

from __future__ import annotations

from rfmp_rl.models.embeddings import DEFAULT_TIME_SCALE, SinusoidalPosEmb
from rfmp_rl.models.obs_encoder import ObservationEncoder
from rfmp_rl.models.tau_head import TauHead
from rfmp_rl.models.unet import (
    UNET_PRESETS,
    ConditionalResidualBlock1D,
    ConditionalUnet1D,
    Conv1dBlock,
    make_unet,
)
from rfmp_rl.models.vision import (
    PAPER_CROP_SHAPES,
    CropRandomizer,
    MultiCameraEncoder,
    ResNet18Encoder,
    SpatialSoftmax,
)

__all__ = [
    "DEFAULT_TIME_SCALE",
    "PAPER_CROP_SHAPES",
    "UNET_PRESETS",
    "ConditionalResidualBlock1D",
    "ConditionalUnet1D",
    "Conv1dBlock",
    "CropRandomizer",
    "MultiCameraEncoder",
    "ObservationEncoder",
    "ResNet18Encoder",
    "SinusoidalPosEmb",
    "SpatialSoftmax",
    "TauHead",
    "make_unet",
]
