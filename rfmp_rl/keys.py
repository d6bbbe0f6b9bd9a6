"""Every TensorDict key the library reads or writes by default, in one place.

Losses expose them through ``loss.tensor_keys`` and accept renames with ``loss.set_keys(...)``;
policies take them as constructor arguments. Nested keys (tuples) work everywhere.

Observation layout: ``observation`` holds the observation window ``(..., 2, D_obs)`` ordered in
time, ``[o^c, o^{s-1}]`` (context first, reference last) — what TorchRL's
``CatFrames(N=2, dim=-2)`` produces. Camera entries hold ``(..., 2, C, H, W)`` the same way.
``obs_gap`` holds ``s - c`` when T_o > 2.

Stored episodes may carry ``timestamp``: float64 ``(T,)``, seconds since the episode's first step
(the first value is 0.0). It is step metadata, never an observation or an action.

The library's envs emit one step's observation under ``obs_step`` / ``pixels_step`` and the
window a policy acts on under ``obs_window`` / ``pixels_window`` (TorchRL ``CatFrames``).
"""

from __future__ import annotations

OBSERVATION = "observation"
PIXELS = "pixels"
OBS_GAP = "obs_gap"
ACTION = "action"
ACTION_IS_PAD = "action_is_pad"
PRIOR_NOISE = "prior_noise"
FLOW_TIME = "flow_time"
TIMESTAMP = "timestamp"
OBS_STEP = "obs_step"
OBS_WINDOW = "obs_window"
PIXELS_STEP = "pixels_step"
PIXELS_WINDOW = "pixels_window"

__all__ = [
    "OBSERVATION", "PIXELS", "OBS_GAP", "ACTION", "ACTION_IS_PAD", "PRIOR_NOISE", "FLOW_TIME",
    "TIMESTAMP", "OBS_STEP", "OBS_WINDOW", "PIXELS_STEP", "PIXELS_WINDOW",
]
