"""Demonstration data in TorchRL replay buffers: readers, the store and the paper's sampler."""

from rfmp_rl.data.dp_zarr import read_dp_zarr, write_dp_zarr
from rfmp_rl.data.episodes import DataError, Manifest, make_episode, step_timestamps
from rfmp_rl.data.lasa import (
    LASA_MULTI_MODELS,
    LASA_SHAPES,
    lasa_episodes,
    load_lasa,
    load_lasa_sphere,
    read_lasa,
)
from rfmp_rl.data.lerobot import read_lerobot
from rfmp_rl.data.minari import read_minari
from rfmp_rl.data.quaternions import (
    QuaternionField,
    canonicalize_episode_quaternions,
    parse_quaternion_fields,
)
from rfmp_rl.data.robomimic import read_robomimic, write_robomimic
from rfmp_rl.data.ros import RosbagConfig, TopicConfig, load_rosbag_config, read_rosbags
from rfmp_rl.data.slices import SlicesToChunks
from rfmp_rl.data.store import (
    ContextChunk,
    DemonstrationStore,
    HorizonContextSampler,
    sample_indices,
)

__all__ = [
    "DataError",
    "Manifest",
    "make_episode",
    "step_timestamps",
    "QuaternionField",
    "parse_quaternion_fields",
    "canonicalize_episode_quaternions",
    "DemonstrationStore",
    "HorizonContextSampler",
    "ContextChunk",
    "sample_indices",
    "SlicesToChunks",
    "read_dp_zarr",
    "write_dp_zarr",
    "read_lerobot",
    "read_minari",
    "read_robomimic",
    "write_robomimic",
    "read_rosbags",
    "RosbagConfig",
    "TopicConfig",
    "load_rosbag_config",
    "read_lasa",
    "LASA_SHAPES",
    "LASA_MULTI_MODELS",
    "load_lasa",
    "load_lasa_sphere",
    "lasa_episodes",
]
