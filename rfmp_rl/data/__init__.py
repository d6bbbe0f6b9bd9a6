"""Demonstration data in TorchRL replay buffers."""

from rfmp_rl.data.lasa import (
    LASA_MULTI_MODELS,
    LASA_SHAPES,
    lasa_episodes,
    load_lasa,
    load_lasa_sphere,
)
from rfmp_rl.data.slices import SlicesToChunks
from rfmp_rl.data.windows import episode_windows

__all__ = [
    "SlicesToChunks",
    "episode_windows",
    "LASA_SHAPES",
    "LASA_MULTI_MODELS",
    "load_lasa",
    "load_lasa_sphere",
    "lasa_episodes",
]
