"""The exported controller drives a simulated task exactly like the PyTorch policy."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest
import torch
from tensordict import TensorDict
from torchrl.envs.utils import ExplorationType, set_exploration_type
from torchrl.modules import MultiStepActorWrapper

from rfmp_rl.envs import make_lasa_sphere_env
from rfmp_rl.modules import FlowPolicy
from rfmp_rl.onnx_export import export_onnx

pytest.importorskip("onnxruntime")
sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "deploy"))


@pytest.mark.parametrize("algorithm", ["srfmp", "rfmp"])
def test_onnx_controller_matches_flowpolicy_with_multistep_wrapper(tmp_path, make_tiny_model,
                                                                   algorithm):
    from rfmp_deploy import Controller, Policy

    model = make_tiny_model(algorithm, "S2", horizon=8)  # T_p = 8, T_a = 4
    demo = torch.nn.functional.normalize(torch.randn(64, 3) + torch.tensor([0, 0, 3.0]), dim=-1)
    model.action_normalizer.fit(demo)
    model.obs_normalizer.fit(demo)
    model.eval()
    nfe = 3 if algorithm == "srfmp" else 4
    export_onnx(model, tmp_path / "p.onnx", nfe=nfe, control_rate_hz=10.0)
    start = torch.nn.functional.normalize(torch.tensor([[0.3, -0.2, 0.9]]), dim=-1)
    steps = 30

    env = make_lasa_sphere_env(start, batch_size=[1], max_move=0.5, goal_tolerance=0.0,
                               max_steps=None, seed=0)
    actor = MultiStepActorWrapper(FlowPolicy(model, nfe=nfe, observation_key="obs_window"),
                                  n_steps=8, replan_interval=4)
    with set_exploration_type(ExplorationType.DETERMINISTIC), torch.no_grad():
        td = env.reset(TensorDict({"start": start}, batch_size=[1]))
        rollout = env.rollout(steps, actor, tensordict=td, auto_reset=False,
                              break_when_any_done=False)
    torch_actions = rollout["action"][0]  # (steps, 3)

    controller = Controller(Policy(str(tmp_path / "p.onnx")), deterministic=True)
    td = env.reset(TensorDict({"start": start}, batch_size=[1]))
    onnx_actions = []
    for _ in range(steps):
        action = controller.step({"observation": td["observation"][0].numpy()})
        onnx_actions.append(torch.as_tensor(action))
        td["action"] = torch.as_tensor(action, dtype=torch.float32)[None]
        td = env.step(td)["next"]
    onnx_actions = torch.stack(onnx_actions)
    assert controller.plan_count == 8  # one chunk every T_a = 4 steps over 30 steps
    assert not [e for e in controller.events if e.kind != "clamped"]
    torch.testing.assert_close(onnx_actions.float(), torch_actions, atol=1e-4, rtol=0)
