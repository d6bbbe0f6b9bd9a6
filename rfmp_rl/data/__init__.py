"""Demonstration data in TorchRL replay buffers."""

from rfmp_rl.data.slices import SlicesToChunks

__all__ = ["SlicesToChunks"]
