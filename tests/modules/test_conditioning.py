"""One mapping from a batch's inputs to the network's conditioning, shared by the losses,
FlowPolicy, VectorField and the ONNX graph."""

from __future__ import annotations

import pytest
import torch
from tensordict import TensorDict

from rfmp_rl.modules import FlowPolicy, ModelConfig, VectorField, build_model
from rfmp_rl.objectives import make_loss
from rfmp_rl.onnx_export import InferenceGraph


def camera_policy(obs_horizon: int = 2):
    cfg = ModelConfig("srfmp", "S2", obs_dim=3, horizon=4, obs_horizon=obs_horizon,
                      down_dims=[16, 32], time_embed_dim=32, tau_hidden_dim=32,
                      cameras={"cam": [3, 32, 32]}, crop_shape=[28, 28], vision_out_dim=8)
    torch.manual_seed(0)
    model = build_model(cfg)
    model.action_normalizer.fit(model.chunk.unflatten(model.chunk.random_base(16)))
    model.obs_normalizer.fit(torch.randn(16, 3))
    return model.eval()


def batch(model, n: int = 4) -> TensorDict:
    gen = torch.Generator().manual_seed(1)
    td = TensorDict({
        "obs": torch.randn(n, 2, 3, generator=gen),
        "wrist": torch.randint(0, 256, (n, 2, 3, 32, 32), generator=gen, dtype=torch.uint8),
        "action": model.chunk.unflatten(model.chunk.random_base(n)),
        "gap": torch.full((n,), 3),
    }, [n])
    td["x_t"] = model.chunk.random_base(n)
    td["time"] = torch.rand(n, 1, generator=gen)
    return td


def test_policy_loss_field_and_graph_read_the_same_inputs_and_conditioning():
    model = camera_policy()
    keys = dict(observation_key="obs", camera_keys={"cam": "wrist"})
    td = batch(model)
    policy = FlowPolicy(model, nfe=1, **keys)
    field = VectorField(model, **keys)
    loss = make_loss(model, camera_keys={"cam": "wrist"})
    loss.set_keys(observation="obs")
    graph = InferenceGraph(model, nfe=1)
    expected = ["obs", "wrist"]
    assert policy.in_keys == expected and field.in_keys[:-2] == expected
    assert [k for k in loss.in_keys if k in expected] == expected
    assert graph.input_names == ["observation", "cam", "prior_noise"]  # same order, graph names

    seen = []
    encode = model.encode_inputs

    def record(*inputs):
        cond = encode(*inputs)
        seen.append(cond.detach().clone())
        return cond

    model.encode_inputs = record
    with torch.no_grad():
        policy(td.clone())
        field(td.clone())
        loss(td.clone())
        graph(td["obs"], td["wrist"], torch.zeros(4, model.noise_dim))
    assert len(seen) == 4
    for cond in seen[1:]:
        torch.testing.assert_close(cond, seen[0])


def test_a_longer_context_reads_the_gap_everywhere():
    model = camera_policy(obs_horizon=4)
    td = batch(model)
    td["prior_noise"] = torch.zeros(4, model.noise_dim)  # the same start for both calls
    policy = FlowPolicy(model, nfe=1, observation_key="obs", camera_keys={"cam": "wrist"},
                        gap_key="gap")
    assert policy.in_keys == ["obs", "wrist", "gap"]
    with torch.no_grad():
        action = policy(td.clone())["action"]
        torch.testing.assert_close(policy(td.clone())["action"], action)
        other_gap = policy(td.clone().set("gap", torch.full((4,), 2)))["action"]
    assert action.shape == (4, 4, 3)
    assert not torch.allclose(action, other_gap)  # the gap reaches the network
    with pytest.raises(ValueError, match="expected 3 conditioning inputs"):
        model.encode_inputs(td["obs"], td["wrist"])
    # the ONNX graph takes the window alone and conditions on the inference gap, T_o
    graph = InferenceGraph(model, nfe=1)
    assert graph.input_names == ["observation", "cam", "prior_noise"]
    with torch.no_grad():
        at_t_o = policy(td.clone().set("gap", torch.full((4,), 4)))["action"]
        torch.testing.assert_close(graph(td["obs"], td["wrist"], td["prior_noise"]), at_t_o)
