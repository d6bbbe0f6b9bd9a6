"""Evaluation: trajectory metrics (DTW, goal error, on-manifold error, jerk)."""

from rfmp_rl.eval.metrics import (
    dtw_distance,
    final_goal_distance,
    jerk,
    nearest_demo_dtw,
    on_manifold_error,
)

__all__ = [
    "dtw_distance",
    "nearest_demo_dtw",
    "final_goal_distance",
    "on_manifold_error",
    "jerk",
]
