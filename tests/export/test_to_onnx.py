"""export/to_onnx.py: one ONNX graph for the fixed-NFE inference, with metadata and parity."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from rfmp_rl.checkpoint import save_checkpoint
from rfmp_rl.onnx_export import InferenceGraph, export_onnx, onnx_metadata

onnx = pytest.importorskip("onnx")
ort = pytest.importorskip("onnxruntime")

ROOT = Path(__file__).resolve().parents[2]


def fitted(model):
    gen = torch.Generator().manual_seed(0)
    chunk = model.chunk.unflatten(model.chunk.random_base(64, generator=gen))
    model.action_normalizer.fit(chunk * 2 + 1)  # Euclidean parts span [-1, 3]
    model.obs_normalizer.fit(torch.randn(32, model.cfg.obs_dim, generator=gen) * 4)
    return model.eval()


def test_srfmp_pose_policy_exports_with_metadata_and_matches_pytorch(tmp_path, make_tiny_model):
    model = fitted(make_tiny_model("srfmp", "R3 x S3 x R1", horizon=8))
    report = export_onnx(model, tmp_path / "p.onnx", nfe=1, control_rate_hz=20.0)
    assert report.max_abs_diff <= 1e-4 and report.max_sphere_error <= 1e-5
    proto = onnx.load(str(tmp_path / "p.onnx"))
    meta = {p.key: p.value for p in proto.metadata_props}
    assert meta["rfmp_rl.format"] == "rfmp_rl.onnx/1"
    assert (meta["algorithm"], meta["nfe"], meta["schedule"]) == ("srfmp", "1", "srfmp")
    assert (meta["horizon"], meta["action_steps"], meta["obs_horizon"]) == ("8", "4", "2")
    assert meta["control_rate_hz"] == "20.0"
    assert json.loads(meta["action_manifold"])["type"] == "product"
    low, high = json.loads(meta["action_low"]), json.loads(meta["action_high"])
    assert low[3:7] == [-1.0] * 4 and high[3:7] == [1.0] * 4  # quaternion coordinates
    torch.testing.assert_close(torch.tensor(low[:3]), model.action_normalizer.data_min[:3].float())
    inputs = json.loads(meta["inputs"])
    assert [i["name"] for i in inputs] == ["observation", "prior_noise"]
    assert inputs[1]["shape"] == [model.noise_dim]
    # Dynamic batch and exact reuse of the prior noise: onnxruntime == PyTorch for any batch.
    session = ort.InferenceSession(str(tmp_path / "p.onnx"), providers=["CPUExecutionProvider"])
    graph = InferenceGraph(model, nfe=1)
    for batch in (1, 5):
        obs, noise = torch.randn(batch, 2, 3) * 4, torch.randn(batch, model.noise_dim)
        got = session.run(["action"], {"observation": obs.numpy(), "prior_noise": noise.numpy()})
        with torch.no_grad():
            expected = graph(obs, noise)
        np.testing.assert_allclose(got[0], expected.numpy(), atol=1e-4, rtol=0)
    # Zero noise is the deterministic mode of FlowPolicy.
    obs = torch.randn(2, 2, 3)
    zero = session.run(
        ["action"],
        {"observation": obs.numpy(), "prior_noise": np.zeros((2, model.noise_dim), np.float32)},
    )
    with torch.no_grad():
        mode = model.sample(model.encode(obs), None, nfe=1, deterministic=True)
    np.testing.assert_allclose(zero[0], mode.numpy(), atol=1e-4, rtol=0)


def test_the_srfmp_tau_clamp_is_in_the_exported_graph(tmp_path, make_tiny_model):
    # NFE 3: the refinement steps query the network past the first step, where the clamp acts
    model = fitted(make_tiny_model("srfmp", "R3 x S3 x R1", horizon=8))
    last = [m for m in model.network.tau_head.modules() if isinstance(m, torch.nn.Linear)][-1]
    with torch.no_grad():  # v_tau = 5: the first step (1 / lambda_x = 0.4) ends at tau = 2
        last.weight.zero_()
        last.bias.fill_(5.0)
    obs, noise = torch.randn(4, 2, 3) * 4, torch.randn(4, model.noise_dim)
    with torch.no_grad():
        free = model.sample(model.encode(obs), noise, nfe=3)
    model.cfg.tau_max = 0.3
    report = export_onnx(model, tmp_path / "p.onnx", nfe=3, control_rate_hz=20.0)
    assert report.max_abs_diff <= 1e-4 and report.max_sphere_error <= 1e-5
    session = ort.InferenceSession(str(tmp_path / "p.onnx"), providers=["CPUExecutionProvider"])
    got = session.run(["action"], {"observation": obs.numpy(), "prior_noise": noise.numpy()})[0]
    with torch.no_grad():
        clamped = model.sample(model.encode(obs), noise, nfe=3)
    np.testing.assert_allclose(got, clamped.numpy(), atol=1e-4, rtol=0)
    assert not np.allclose(got, free.numpy(), atol=1e-3)


def test_export_refuses_an_unfitted_policy(make_tiny_model):
    model = make_tiny_model("rfmp", "S2")
    with pytest.raises(ValueError, match="never fitted"):
        onnx_metadata(InferenceGraph(model, nfe=1))


def test_parity_failure_is_reported(tmp_path, make_tiny_model):
    model = fitted(make_tiny_model("ddim", "S2"))
    with pytest.raises(RuntimeError, match="differs from PyTorch"):
        export_onnx(model, tmp_path / "d.onnx", nfe=2, atol=-1.0,  # no difference passes < 0
                    control_rate_hz=10.0)
    assert (tmp_path / "d.onnx").exists()  # written before the check, for inspection


def test_cli_exports_a_checkpoint_and_prints_parity(tmp_path, make_tiny_model, to_onnx_cli):
    """The script as a user runs it (a subprocess); its refusals in-process."""
    model = fitted(make_tiny_model("rfmp", "S2", horizon=4))
    ckpt = save_checkpoint(tmp_path / "ckpt.pt", model, control_rate_hz=10.0)
    out = tmp_path / "policy.onnx"
    result = subprocess.run(
        [
            sys.executable,
            str(ROOT / "export" / "to_onnx.py"),
            "--checkpoint",
            str(ckpt),
            "--nfe",
            "2",
            "--t-end",
            "1.2",
            "--method",
            "midpoint",
            "--out",
            str(out),
        ],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert result.returncode == 0, result.stderr
    assert "max |onnxruntime - torch|" in result.stdout and out.exists()
    meta = {p.key: p.value for p in onnx.load(str(out)).metadata_props}
    assert (meta["method"], meta["t_end"], meta["nfe"]) == ("midpoint", "1.2", "2")
    bad = to_onnx_cli("--checkpoint", ckpt, "--nfe", "3", "--method", "rk4",
                      "--out", tmp_path / "x.onnx")
    assert bad.returncode != 0 and "NFE=3" in bad.stderr


def test_image_policy_exports_with_a_dynamic_batch(tmp_path):
    from rfmp_rl.modules import ModelConfig, build_model

    cfg = ModelConfig("srfmp", "S2", obs_dim=2, horizon=4, down_dims=[16, 32],
                      time_embed_dim=32, tau_hidden_dim=32, cameras={"cam": [3, 32, 32]},
                      crop_shape=[28, 28], vision_out_dim=16)
    torch.manual_seed(0)
    model = build_model(cfg)
    model.action_normalizer.fit(model.chunk.unflatten(model.chunk.random_base(16)))
    model.obs_normalizer.fit(torch.randn(16, 2))
    report = export_onnx(model.eval(), tmp_path / "img.onnx", nfe=1, control_rate_hz=10.0)
    assert report.max_abs_diff <= 1e-4
    proto = onnx.load(str(tmp_path / "img.onnx"))
    names = [i.name for i in proto.graph.input]
    assert names == ["observation", "cam", "prior_noise"]
    assert proto.graph.input[1].type.tensor_type.elem_type == onnx.TensorProto.UINT8
    inputs = json.loads({p.key: p.value for p in proto.metadata_props}["inputs"])
    assert inputs[1]["image_size"] == [32, 32] and inputs[1]["crop"] == [28, 28]


def test_the_control_rate_is_an_export_argument(tmp_path, make_tiny_model):
    model = fitted(make_tiny_model("rfmp", "S2", horizon=4))
    with pytest.raises(ValueError, match="control_rate_hz must be the rate"):
        export_onnx(model, tmp_path / "none.onnx", nfe=1)
    assert not (tmp_path / "none.onnx").exists()  # refused before anything is written
    with pytest.raises(ValueError, match="control_rate_hz"):
        onnx_metadata(InferenceGraph(model, nfe=1), control_rate_hz=0.0)
    assert onnx_metadata(InferenceGraph(model, nfe=1), 12.5)["control_rate_hz"] == "12.5"


def test_cli_rate_defaults_to_the_checkpoint_and_asks_for_one_when_it_has_none(
    tmp_path, make_tiny_model, to_onnx_cli
):
    model = fitted(make_tiny_model("srfmp", "S2", horizon=4))
    with_rate = save_checkpoint(tmp_path / "a.pt", model, control_rate_hz=20.0)
    result = to_onnx_cli("--checkpoint", with_rate, "--out", tmp_path / "a.onnx")
    assert result.returncode == 0, result.stderr
    assert {p.key: p.value for p in onnx.load(str(tmp_path / "a.onnx")).metadata_props}[
        "control_rate_hz"] == "20.0"
    result = to_onnx_cli("--checkpoint", with_rate, "--rate", "50", "--out", tmp_path / "b.onnx")
    assert result.returncode == 0, result.stderr
    assert {p.key: p.value for p in onnx.load(str(tmp_path / "b.onnx")).metadata_props}[
        "control_rate_hz"] == "50.0"
    without = save_checkpoint(tmp_path / "c.pt", model)
    result = to_onnx_cli("--checkpoint", without, "--out", tmp_path / "c.onnx")
    assert result.returncode == 1 and "--rate" in result.stderr
    assert "Traceback" not in result.stderr and not (tmp_path / "c.onnx").exists()


def test_cli_exports_a_checkpoint_written_before_the_loss_config(
    tmp_path, make_tiny_model, to_onnx_cli
):
    """An old checkpoint: training options and the rate inside its model config."""
    model = fitted(make_tiny_model("srfmp", "S2", horizon=4))
    path = save_checkpoint(tmp_path / "new.pt", model)
    payload = torch.load(path, weights_only=True)
    payload["model_config"].update(time_sampling="uniform", time_max=2.0, t0_fraction=0.5,
                                   lambda_tau=2.5, control_rate_hz=10.0)
    del payload["loss"], payload["control_rate_hz"]
    torch.save(payload, tmp_path / "old.pt")
    result = to_onnx_cli("--checkpoint", tmp_path / "old.pt", "--out", tmp_path / "old.onnx")
    assert result.returncode == 0, result.stderr
    meta = {p.key: p.value for p in onnx.load(str(tmp_path / "old.onnx")).metadata_props}
    assert (meta["control_rate_hz"], meta["algorithm"]) == ("10.0", "srfmp")
