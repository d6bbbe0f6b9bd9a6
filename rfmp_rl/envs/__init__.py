"""TorchRL environments for RFMP evaluation."""

from rfmp_rl.envs.kitchen import FrankaKitchenEnv, kitchen_episodes, make_kitchen_env
from rfmp_rl.envs.lasa_sphere import LasaSphereEnv, make_lasa_sphere_env
from rfmp_rl.envs.pusht import PushTEnv, make_pusht_env, pusht_episodes
from rfmp_rl.envs.robosuite import RobosuiteEnv, make_robosuite_env
from rfmp_rl.envs.transforms import ContextWindow, observation_windows, window_transforms

__all__ = [
    "FrankaKitchenEnv",
    "make_kitchen_env",
    "kitchen_episodes",
    "LasaSphereEnv",
    "make_lasa_sphere_env",
    "PushTEnv",
    "make_pusht_env",
    "pusht_episodes",
    "RobosuiteEnv",
    "make_robosuite_env",
    "ContextWindow",
    "observation_windows",
    "window_transforms",
]
