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


def test_flow_policy_declares_its_keys_and_output_spec(make_tiny_model):
    from torchrl.data import Bounded, Composite

    from rfmp_rl.modules import ModelConfig, build_model

    cfg = ModelConfig("srfmp", "S2", obs_dim=3, horizon=4, obs_horizon=4, down_dims=[16, 32],
                      cameras={"cam": [3, 16, 16]}, vision_out_dim=8)
    model = build_model(cfg)
    policy = FlowPolicy(model, nfe=1, observation_key="obs_window",
                        camera_keys={"cam": "cam_window"}, action_key=("agent", "action"))
    assert policy.in_keys == ["obs_window", "cam_window", "obs_gap"]
    assert policy.out_keys == [("agent", "action")]
    assert isinstance(policy.spec, Composite) and policy.action_spec is None
    assert list(policy.spec.keys(True, True)) == [("agent", "action")]
    # an env's action spec (a Composite holding the action key) or the leaf spec
    leaf = Bounded(-1.0, 1.0, shape=(4, 3))
    env_spec = Composite(agent=Composite(action=leaf))
    for given in (leaf, env_spec):
        spec_policy = FlowPolicy(model, nfe=1, spec=given, action_key=("agent", "action"))
        assert spec_policy.spec[("agent", "action")] == leaf == spec_policy.action_spec
    with pytest.raises(KeyError, match="no 'action' entry"):
        FlowPolicy(model, spec=Composite(other=leaf))
    with pytest.raises(ValueError, match="action size 3"):
        FlowPolicy(model, spec=Bounded(-1.0, 1.0, shape=(4, 2)))
    with pytest.raises(TypeError, match="TensorSpec"):
        FlowPolicy(model, spec="box")
    # it writes exactly its out_keys
    n = 2
    td = TensorDict({"obs_window": torch.randn(n, 2, 3), "obs_gap": torch.full((n,), 3),
                     "cam_window": torch.randint(0, 256, (n, 2, 3, 16, 16), dtype=torch.uint8)},
                    [n])
    out = policy(td.clone())
    assert set(out.keys(True, True)) - set(td.keys(True, True)) == {("agent", "action")}
    assert out["agent", "action"].shape == (n, 4, 3)


def test_small_preset_embeddings_scale_with_the_network():
    from rfmp_rl.modules import ModelConfig, build_model

    small = ModelConfig("srfmp", "R2", obs_dim=2, unet_preset="small")
    paper = ModelConfig("srfmp", "R2", obs_dim=2, unet_preset="paper")
    custom = ModelConfig("srfmp", "R2", obs_dim=2, down_dims=[32, 64])
    explicit = ModelConfig("srfmp", "R2", obs_dim=2, time_embed_dim=16, tau_hidden_dim=24)
    assert (small.time_embed_dim, small.tau_hidden_dim) == (64, 128)
    assert (paper.time_embed_dim, paper.tau_hidden_dim) == (256, 512)
    assert (custom.time_embed_dim, custom.tau_hidden_dim) == (32, 64)
    assert (explicit.time_embed_dim, explicit.tau_hidden_dim) == (16, 24)
    # the resolved sizes are stored, so a config rebuilds the same network
    assert ModelConfig.from_dict(small.to_dict()) == small
    net = build_model(small).network
    assert net.time_embed_dim == 64 and net.tau_hidden_dim == 128
    assert net.time_encoder[-1].out_features == 64
