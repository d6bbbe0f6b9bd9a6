"""T_o = 4 end to end: a Push-T state policy trained on a few batches, exported by
``export/to_onnx.py`` and run by the torch-free controller in the Push-T env acts exactly as the
PyTorch `FlowPolicy` on the same observations, with the inference window ``[o^(s-T_o), o^(s-1)]``
and gap T_o (the first observation repeated at the episode's start)."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from tensordict import TensorDict
from torchrl.envs.utils import ExplorationType, set_exploration_type

pytest.importorskip("gym_pusht")
pytest.importorskip("onnxruntime")

from rfmp_rl import keys  # noqa: E402
from rfmp_rl.checkpoint import save_checkpoint  # noqa: E402
from rfmp_rl.data import DemonstrationStore  # noqa: E402
from rfmp_rl.envs.pusht import PushTEnv, block_keypoints, pusht_episodes  # noqa: E402
from rfmp_rl.eval.controller import run_controller, split_fields  # noqa: E402
from rfmp_rl.modules import FlowPolicy, ModelConfig, build_model  # noqa: E402
from rfmp_rl.objectives import make_loss  # noqa: E402
from rfmp_rl.solvers import SolverConfig  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "deploy"))

T_O, T_P, T_A = 4, 8, 4
STEPS = 24  # six chunks; the first T_o steps plan from padded windows


def _episodes(n: int = 3, length: int = 40) -> list[TensorDict]:
    """Push-T state episodes in Diffusion Policy's layout (agent circling the block), converted
    by the library as the real data is: observation (T, 20) px, action (T, 2) px."""
    gen = torch.Generator().manual_seed(0)
    out = []
    for _ in range(n):
        t = torch.linspace(0, 3, length + 1)[:, None]
        centre = 200 + 100 * torch.rand(1, 2, generator=gen)
        phase = 6.28 * torch.rand(1, generator=gen)
        agent = centre + 80 * torch.cat([torch.cos(t + phase), torch.sin(t + phase)], 1)
        pose = torch.cat([centre.expand(length + 1, 2), 0.2 * t], 1)  # block: slow rotation
        out.append(TensorDict({
            "state": torch.cat([agent, pose], 1)[:-1],
            "keypoint": block_keypoints(pose)[:-1],
            "action": agent[1:],  # the next agent position
        }, [length]))
    return pusht_episodes(out, "state", "euclidean")


def _train(store: DemonstrationStore, steps: int = 3) -> FlowPolicy:
    torch.manual_seed(0)
    model = build_model(ModelConfig("srfmp", "R2", obs_dim=20, horizon=T_P, action_steps=T_A,
                                    obs_horizon=T_O, down_dims=[16, 32], time_embed_dim=32,
                                    tau_hidden_dim=32))
    model.obs_normalizer.set_stats(*store.stats(keys.OBSERVATION))
    model.action_normalizer.set_stats(*store.stats(keys.ACTION))
    policy = FlowPolicy(model, solver=SolverConfig(nfe=2), safe=True)
    loss = make_loss(policy)
    rb = store.replay_buffer(T_P, [keys.OBSERVATION], obs_horizon=T_O, batch_size=16,
                             generator=torch.Generator().manual_seed(0))
    optim = torch.optim.Adam(model.parameters(), lr=1e-3)
    gaps = set()
    for _ in range(steps):
        batch = rb.sample()
        gaps |= set(batch[keys.OBS_GAP].tolist())
        out = loss(batch)
        total = sum(v for k, v in out.items() if k.startswith("loss_"))
        optim.zero_grad()
        total.backward()
        optim.step()
    assert gaps <= {2.0, 3.0, 4.0} and len(gaps) > 1  # trained on contexts from [s - 4, s - 2]
    return policy.eval()


class _Recorder:
    """The controller as `run_controller` drives it, keeping what it saw and sent."""

    def __init__(self, controller) -> None:
        self.controller, self.observations, self.actions = controller, [], []

    @property
    def events(self):
        return self.controller.events

    def reset(self) -> None:
        self.controller.reset()

    def step(self, observation):
        action = self.controller.step(observation)
        self.observations.append(np.concatenate(list(observation.values())))
        self.actions.append(action)
        return action


def test_t_o_4_pusht_policy_acts_the_same_in_pytorch_and_through_the_onnx_controller(
    tmp_path, to_onnx_cli
):
    from rfmp_deploy import Controller, Policy

    policy = _train(DemonstrationStore.from_episodes(_episodes()))
    checkpoint = save_checkpoint(tmp_path / "ckpt.pt", policy, solver=policy.solver,
                                 control_rate_hz=10.0)
    # export/to_onnx.py with no flag for T_o (the checkpoint has it)
    export = to_onnx_cli("--checkpoint", checkpoint, "--out", tmp_path / "policy.onnx")
    assert export.returncode == 0, export.stderr

    controller = Controller(Policy(tmp_path / "policy.onnx", intra_op_threads=1),
                            deterministic=True)
    assert (controller.meta.obs_horizon, controller.meta.nfe) == (T_O, 2)
    fields = controller.meta.observation_keys
    recorder = _Recorder(controller)
    result = run_controller(
        recorder, lambda seed: PushTEnv([1], seeds=[seed]), [100000], STEPS,
        observe=lambda td: split_fields(td[keys.OBSERVATION][0].numpy(), fields),
        outcome=lambda td: float(td["max_coverage"][0, 0]),
    )
    assert len(recorder.actions) == STEPS and controller.plan_count == STEPS // T_A
    assert not [e for _, e in result.events if e.kind != "clamped"]

    # PyTorch on the same observations: a chunk every T_a steps from [o^(p-T_o+1)..., o^p]'s
    # oldest and latest (the first observation repeated before T_o were seen), gap T_o.
    torch_policy = FlowPolicy.from_checkpoint(checkpoint, safe=True)
    observations = torch.as_tensor(np.stack(recorder.observations))  # (STEPS, 20)
    expected = []
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        for plan in range(0, STEPS, T_A):
            window = observations[[max(plan - (T_O - 1), 0), plan]][None]  # (1, 2, 20)
            td = TensorDict({keys.OBSERVATION: window,
                             keys.OBS_GAP: torch.full((1,), float(T_O))}, [1])
            expected += list(torch_policy(td)[keys.ACTION][0, :T_A])  # (T_a, 2) executed
    expected = torch.stack(expected).numpy()
    got = np.stack(recorder.actions)
    scale = torch_policy.model.action_normalizer.scale.numpy()  # px per normalised unit
    assert (np.abs(got - expected) / scale).max() <= 1e-4  # every step, the first T_o included
    # the padded start matters: the PyTorch policy without padding acts differently at step 0
    unpadded = TensorDict({keys.OBSERVATION: observations[[0, 0]][None],
                           keys.OBS_GAP: torch.full((1,), 2.0)}, [1])
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        other = torch_policy(unpadded)[keys.ACTION][0, 0].numpy()
    assert (np.abs(other - got[0]) / scale).max() > 1e-3
