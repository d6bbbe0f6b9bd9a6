"""The ROS bag reader under its first name: re-exports `rfmp_rl.data.ros` (configuration,
resampling and reading; its docstring describes the topic config, timing, gaps and keys)."""

from rfmp_rl.data.ros import (
    CONFIG_FIELDS,
    ON_GAP,
    TIMESTAMP,
    RosbagConfig,
    TopicConfig,
    VectorPart,
    load_rosbag_config,
    nearest_indices,
    read_rosbags,
    resample_linear,
    resample_slerp,
    slerp,
)

__all__ = [
    "RosbagConfig",
    "TopicConfig",
    "VectorPart",
    "CONFIG_FIELDS",
    "ON_GAP",
    "TIMESTAMP",
    "load_rosbag_config",
    "read_rosbags",
    "slerp",
    "resample_linear",
    "resample_slerp",
    "nearest_indices",
]
