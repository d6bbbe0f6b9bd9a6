"""The loss, the checkpoint and the exporter accept the acting policy (or its wrappers) as well
as the bare model; the deterministic exploration types all act from the prior's mode."""

from __future__ import annotations

import pytest
import torch
from tensordict import TensorDict
from torchrl.envs.utils import ExplorationType, set_exploration_type
from torchrl.modules import MultiStepActorWrapper

from rfmp_rl.checkpoint import load_checkpoint, save_checkpoint
from rfmp_rl.modules import EMA, FlowPolicy, unwrap_policy_model
from rfmp_rl.objectives import RFMPLoss, make_loss
from rfmp_rl.onnx_export import InferenceGraph


def test_wrappers_unwrap_to_the_policy_model(tmp_path, make_tiny_model):
    model = make_tiny_model("rfmp", "S2", horizon=4)
    policy = FlowPolicy(model, nfe=2)
    actor = MultiStepActorWrapper(policy, n_steps=4, replan_interval=2)
    for wrapped in (model, policy, actor, EMA(model)):
        found = unwrap_policy_model(wrapped, "test")
        assert found.cfg == model.cfg
    assert unwrap_policy_model(actor, "test") is model
    assert isinstance(make_loss(actor), RFMPLoss) and RFMPLoss(policy).model is model
    path = save_checkpoint(tmp_path / "a.pt", actor)
    assert load_checkpoint(path)[0].cfg == model.cfg
    assert InferenceGraph(actor, nfe=1).model is model
    with pytest.raises(TypeError, match=r"make_loss takes a policy model .* got Linear"):
        make_loss(torch.nn.Linear(2, 2))
    with pytest.raises(TypeError, match="save_checkpoint takes a policy model"):
        save_checkpoint(tmp_path / "b.pt", "model.pt")


@pytest.mark.parametrize("kind", [ExplorationType.DETERMINISTIC, ExplorationType.MODE,
                                  ExplorationType.MEAN])
def test_every_deterministic_exploration_type_acts_from_the_mode(make_tiny_model, kind):
    model = make_tiny_model("srfmp", "S2", horizon=4).eval()
    policy = FlowPolicy(model, nfe=1)
    td = TensorDict({"observation": torch.randn(3, 2, 3)}, [3])
    with set_exploration_type(kind):
        a, b = policy(td.clone())["action"], policy(td.clone())["action"]
    torch.testing.assert_close(a, b)
    with set_exploration_type(ExplorationType.RANDOM):
        c, d = policy(td.clone())["action"], policy(td.clone())["action"]
    assert not torch.allclose(c, d)


def test_safe_policy_keeps_actions_in_the_demonstrated_range_and_its_spec(make_tiny_model):
    from torchrl.data import Bounded

    model = make_tiny_model("rfmp", "R3 x S3 x R1", horizon=4)
    chunk = model.chunk.unflatten(model.chunk.random_base(64))
    model.action_normalizer.fit(chunk * 0.01)  # a tiny demonstrated range
    model.eval()
    with torch.no_grad():  # an untrained field overshoots the range
        model.network.final[-1].bias.fill_(5.0)
    spec = Bounded(-0.005, 0.005, shape=(4, 8))
    td = TensorDict({"observation": torch.randn(2, 2, 3)}, [2])
    raw = FlowPolicy(model, nfe=1)(td.clone())["action"]
    safe = FlowPolicy(model, nfe=1, safe=True)(td.clone())["action"]
    norm = model.action_normalizer
    assert (raw[..., :3] > norm.data_max[:3]).any()
    assert (safe[..., :3] <= norm.data_max[:3] + 1e-6).all()
    assert (safe[..., :3] >= norm.data_min[:3] - 1e-6).all()
    torch.testing.assert_close(safe[..., 3:7].norm(dim=-1), torch.ones(2, 4))
    projected = FlowPolicy(model, nfe=1, safe=True, spec=spec)(td.clone())["action"]
    assert projected.abs().max() <= 0.005 + 1e-7
    assert FlowPolicy(model, spec=spec).action_spec == spec
