"""rfmp_deploy: run an exported rfmp_rl policy on a robot PC with numpy and onnxruntime only.

No torch and no rfmp_rl: everything the controller needs (inputs, horizons, action manifold and
limits, noise) is read from the ONNX file's ``rfmp_rl.onnx/1`` metadata. OpenCV is imported only
when the model has cameras.

- `Policy`: the onnxruntime session with validated metadata (`PolicyMeta`).
- `Controller`: observation history, action queue (T_a of every T_p actions), safety (reject
  bad observations and hold, clip and renormalise actions, `Event` s), synchronous or
  background inference.
- `run` and `RobotInterface`: the fixed-rate loop and the two methods a robot implements.
- `GymnasiumRobot`, `BagReplay`: simulation (closed loop) and recorded data (open loop).

Example:
    >>> from rfmp_deploy import Controller, run
    >>> controller = Controller("policy.onnx")
    >>> controller.meta.cameras, controller.meta.action_steps
    (('wrist',), 8)
"""

from __future__ import annotations

from rfmp_deploy.adapters import BagReplay, GymnasiumRobot, ReplayReport
from rfmp_deploy.controller import Controller, FaultController, open_controller
from rfmp_deploy.loop import RobotInterface, RunStats, SendActionError, run
from rfmp_deploy.metadata import FORMAT, InputSpec, ObservationField, PolicyMeta, parse_metadata
from rfmp_deploy.observation import Frame, ObservationError, ObservationProcessor
from rfmp_deploy.policy import Policy
from rfmp_deploy.safety import EVENT_KINDS, Event
from rfmp_deploy.spaces import ActionSpace

__version__ = "0.1.0"

__all__ = [
    "EVENT_KINDS",
    "FORMAT",
    "ActionSpace",
    "BagReplay",
    "Controller",
    "FaultController",
    "SendActionError",
    "open_controller",
    "Event",
    "Frame",
    "GymnasiumRobot",
    "InputSpec",
    "ObservationError",
    "ObservationField",
    "ObservationProcessor",
    "Policy",
    "PolicyMeta",
    "ReplayReport",
    "RobotInterface",
    "RunStats",
    "parse_metadata",
    "run",
]
