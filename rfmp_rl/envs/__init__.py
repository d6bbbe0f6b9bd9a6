"""TorchRL environments for RFMP evaluation."""

from rfmp_rl.envs.lasa_sphere import LasaSphereEnv, make_lasa_sphere_env

__all__ = ["LasaSphereEnv", "make_lasa_sphere_env"]
