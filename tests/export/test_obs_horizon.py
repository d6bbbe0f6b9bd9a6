"""T_o > 2 in the exported graph: the inputs stay the window ``[o^c, o^{s-1}]`` and the graph
holds the inference gap ``s - c = T_o``; it matches `FlowPolicy` given the same window and gap."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from tensordict import TensorDict

from rfmp_rl import keys
from rfmp_rl.modules import FlowPolicy, ModelConfig, build_model
from rfmp_rl.onnx_export import PARITY_LIMITS, InferenceGraph, export_onnx

onnx = pytest.importorskip("onnx")
ort = pytest.importorskip("onnxruntime")
sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "deploy"))

T_O = 4


def _model(algorithm: str, cameras: bool) -> torch.nn.Module:
    extra = ({"cameras": {"cam": [3, 32, 32]}, "crop_shape": [28, 28], "vision_out_dim": 16}
             if cameras else {})
    torch.manual_seed(0)
    model = build_model(ModelConfig(algorithm, "R3 x S3 x R1", obs_dim=3, horizon=4,
                                    obs_horizon=T_O, down_dims=[16, 32], time_embed_dim=32,
                                    tau_hidden_dim=32, **extra))
    gen = torch.Generator().manual_seed(0)
    chunk = model.chunk.unflatten(model.chunk.random_base(64, generator=gen))
    model.action_normalizer.fit(chunk * 2 + 1)  # Euclidean parts span about [-1, 3]
    model.obs_normalizer.fit(torch.randn(32, 3, generator=gen) * 4)
    return model.eval()


def _inputs(model, batch: int, gen: torch.Generator, nfe: int = 1) -> dict[str, torch.Tensor]:
    out = {keys.OBSERVATION: torch.randn(batch, 2, 3, generator=gen) * 4,
           keys.PRIOR_NOISE: torch.randn(batch, model.prior_noise_dim(nfe), generator=gen)}
    for name in model.cameras:
        out[name] = torch.randint(0, 256, (batch, 2, 3, 32, 32), generator=gen, dtype=torch.uint8)
    return out


def _flow_policy(model, inputs: dict[str, torch.Tensor], gap: float, nfe: int) -> np.ndarray:
    batch = inputs[keys.PRIOR_NOISE].shape[0]
    td = TensorDict({**inputs, keys.OBS_GAP: torch.full((batch,), gap)}, [batch])
    return FlowPolicy(model, nfe=nfe)(td)[keys.ACTION].numpy()


@pytest.mark.parametrize(("algorithm", "cameras"), [("srfmp", False), ("ddim", False),
                                                    ("cp", False), ("srfmp", True)])
def test_t_o_4_graph_matches_flowpolicy_on_the_window_and_gap(tmp_path, algorithm, cameras):
    from rfmp_deploy import Policy

    model = _model(algorithm, cameras)
    nfe = 2
    report = export_onnx(model, tmp_path / "p.onnx", nfe=nfe, latency_runs=1, control_rate_hz=10.0)
    assert report.max_abs_diff <= PARITY_LIMITS["fp32"]
    meta = {p.key: p.value for p in onnx.load(str(tmp_path / "p.onnx")).metadata_props}
    assert meta["obs_horizon"] == str(T_O)
    inputs = json.loads(meta["inputs"])
    expected_names = ["observation", *model.cameras, "prior_noise"]
    assert [i["name"] for i in inputs] == expected_names  # no gap input
    assert all(i["shape"][0] == 2 for i in inputs if i["kind"] != "noise")
    session = ort.InferenceSession(str(tmp_path / "p.onnx"), providers=["CPUExecutionProvider"])
    assert [i.name for i in session.get_inputs()] == expected_names

    scale = model.action_normalizer.scale.numpy()
    gen = torch.Generator().manual_seed(1)
    for batch in (1, 5):
        inputs = _inputs(model, batch, gen, nfe)
        got = session.run(["action"], {k: v.numpy() for k, v in inputs.items()})[0]
        expected = _flow_policy(model, inputs, float(T_O), nfe)
        assert (np.abs(got - expected) / scale).max() <= PARITY_LIMITS["fp32"]
        # the gap is really T_o: the policy at the smallest training gap acts differently
        other = _flow_policy(model, inputs, 2.0, nfe)
        assert (np.abs(got - other) / scale).max() > 100 * PARITY_LIMITS["fp32"]

    # the torch-free side reads the same horizon
    assert Policy(tmp_path / "p.onnx").meta.obs_horizon == T_O


def test_graph_inputs_leave_the_gap_to_the_graph():
    graph = InferenceGraph(_model("srfmp", True), nfe=1)
    assert graph.input_names == ["observation", "cam", "prior_noise"] and graph.obs_gap == T_O
    assert InferenceGraph(_model("srfmp", False), nfe=1).input_names == ["observation",
                                                                          "prior_noise"]
    two = build_model(ModelConfig("srfmp", "S2", obs_dim=3, horizon=4, down_dims=[16, 32],
                                  time_embed_dim=32, tau_hidden_dim=32))
    assert InferenceGraph(two, nfe=1).obs_gap is None
