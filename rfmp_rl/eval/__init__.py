"""Evaluation: closed-loop rollouts over seeds, the NFE x end-time sweep, result tables and plots
(`rollout`, `tables`), trajectory metrics (DTW, goal error, on-manifold error, jerk: `metrics`)
and seed-independent batched evaluation envs (`parallel`)."""

from rfmp_rl.eval.metrics import (
    dtw_distance,
    final_goal_distance,
    jerk,
    nearest_demo_dtw,
    on_manifold_error,
)
from rfmp_rl.eval.rollout import (
    EvalConfig,
    SeedResults,
    evaluate,
    reached_time,
    seed_max,
    seed_mean,
    seed_std,
    sweep,
    sweep_settings,
)
from rfmp_rl.eval.tables import Column, plot_sweep, read_table, setting_label, write_tables

__all__ = [
    "dtw_distance",
    "nearest_demo_dtw",
    "final_goal_distance",
    "on_manifold_error",
    "jerk",
    "EvalConfig",
    "SeedResults",
    "evaluate",
    "sweep",
    "sweep_settings",
    "reached_time",
    "seed_mean",
    "seed_std",
    "seed_max",
    "Column",
    "write_tables",
    "read_table",
    "plot_sweep",
    "setting_label",
]
