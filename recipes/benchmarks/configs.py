"""The paper's task configurations used by the benchmark scripts (observation and action sizes).

Push-T state: 9 block keypoints (x, y) + agent (x, y) = 20-D per step, actions in R^2.
Push-T image: one 96x96 RGB camera (84x84 crop) + agent position (2-D), actions in R^2.
robomimic state (Lift): object (10) + eef position (3) + eef quaternion (4) + gripper (2) = 19-D,
actions in R^7 (delta pose + gripper).
robomimic image (Lift): agentview + eye-in-hand 84x84 (76x76 crop) + 9-D proprioception.
Real robot: R^3 x S^3 x R^1 actions (position, unit quaternion, gripper).
"""

from __future__ import annotations

from rfmp_rl.modules import ModelConfig

#: paper Table "hyperParamRFMP": (RFMP VF params, SRFMP VF params, ResNet params per camera)
PAPER_COUNTS = {
    "pusht_state": (None, None, None),
    "pusht_image": (8.0e7, 8.14e7, 1.12e7),
    "robomimic_state": (6.58e7, 6.68e7, None),
    "robomimic_image": (9.48e7, 9.69e7, 1.12e7),
}


def task_config(task: str, algorithm: str, preset: str) -> ModelConfig:
    common = dict(algorithm=algorithm, unet_preset=preset, horizon=16, action_steps=8)
    if task == "pusht_state":
        return ModelConfig(action_manifold="R2", obs_dim=20, **common)
    if task == "pusht_image":
        return ModelConfig(
            action_manifold="R2",
            obs_dim=2,
            cameras={"image": [3, 96, 96]},
            crop_shape=[84, 84],
            **common,
        )
    if task == "robomimic_state":
        return ModelConfig(action_manifold="R7", obs_dim=19, **common)
    if task == "robomimic_image":
        return ModelConfig(
            action_manifold="R7",
            obs_dim=9,
            cameras={"agentview": [3, 84, 84], "eye_in_hand": [3, 84, 84]},
            crop_shape=[76, 76],
            **common,
        )
    if task == "real_pose":
        return ModelConfig(action_manifold="R3 x S3 x R1", obs_dim=8, **common)
    raise KeyError(task)
