"""Reduced-precision export (fp16, int8, int8-dynamic): only the networks change, the parity to
float32 PyTorch is measured and recorded, and the deploy controller runs the files unchanged."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from rfmp_rl.checkpoint import save_checkpoint
from rfmp_rl.data import DemonstrationStore
from rfmp_rl.onnx_export import PARITY_LIMITS, calibration_inputs, export_onnx

onnx = pytest.importorskip("onnx")
ort = pytest.importorskip("onnxruntime")
ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "deploy"))

QUANTIZED_OPS = {"QLinearConv", "ConvInteger", "QLinearMatMul", "MatMulInteger"}


def pose_policy(make_tiny_model):
    """An SRFMP policy on R3 x S3 x R1 with fitted normalisers (Euclidean range [-1, 3])."""
    model = make_tiny_model("srfmp", "R3 x S3 x R1", horizon=8)
    gen = torch.Generator().manual_seed(0)
    chunk = model.chunk.unflatten(model.chunk.random_base(64, generator=gen))
    model.action_normalizer.fit(chunk * 2 + 1)
    model.obs_normalizer.fit(torch.randn(32, model.cfg.obs_dim, generator=gen) * 4)
    return model.eval()


def metadata(path: Path) -> dict[str, str]:
    return {p.key: p.value for p in onnx.load(str(path)).metadata_props}


def initializer_types(path: Path) -> dict[str, int]:
    return {i.name: i.data_type for i in onnx.load(str(path)).graph.initializer}


def network_bytes(path: Path) -> int:
    """Bytes of the networks' weights in a model file."""
    return sum(len(i.raw_data) for i in onnx.load(str(path)).graph.initializer
               if i.name.startswith("model.network."))


@pytest.fixture(scope="module")
def exports(tmp_path_factory):
    """One tiny pose policy exported at every precision (module-scoped: exports take seconds)."""
    from rfmp_rl.modules import ModelConfig, build_model

    torch.manual_seed(0)
    model = build_model(ModelConfig("srfmp", "R3 x S3 x R1", obs_dim=3, horizon=8,
                                    action_steps=4, down_dims=[16, 32], time_embed_dim=32,
                                    tau_hidden_dim=32))
    gen = torch.Generator().manual_seed(0)
    chunk = model.chunk.unflatten(model.chunk.random_base(64, generator=gen))
    model.action_normalizer.fit(chunk * 2 + 1)
    model.obs_normalizer.fit(torch.randn(32, model.cfg.obs_dim, generator=gen) * 4)
    model.eval()
    folder = tmp_path_factory.mktemp("precision")
    reports = {p: export_onnx(model, folder / f"{p}.onnx", nfe=1, precision=p,
                              control_rate_hz=10.0)
               for p in ("fp32", "fp16", "int8", "int8-dynamic")}
    return model, reports


@pytest.mark.parametrize("precision", ["fp16", "int8", "int8-dynamic"])
def test_reduced_precision_is_recorded_and_within_its_parity_limit(exports, precision):
    _, reports = exports
    report = reports[precision]
    meta = metadata(report.path)
    assert meta["precision"] == precision
    assert float(meta["parity_max_abs_diff"]) == pytest.approx(report.max_abs_diff, rel=0.01)
    assert 0 < report.max_abs_diff <= PARITY_LIMITS[precision]  # reduced: not bit-exact
    assert report.max_sphere_error <= 1e-5  # the manifold maps stay float32
    # The graph's interface is unchanged: float32 in, float32 out.
    proto = onnx.load(str(report.path))
    for tensor in [*proto.graph.input, *proto.graph.output]:
        assert tensor.type.tensor_type.elem_type == onnx.TensorProto.FLOAT, tensor.name
    assert meta["rfmp_rl.format"] == "rfmp_rl.onnx/1"
    # The networks' weights shrink (the tiny test networks: the file is mostly graph).
    ratio = network_bytes(report.path) / network_bytes(reports["fp32"].path)
    assert ratio < (0.51 if precision == "fp16" else 0.75), ratio


def test_fp16_changes_the_networks_only(exports):
    _, reports = exports
    types = initializer_types(reports["fp16"].path)
    network = {k: v for k, v in types.items() if k.startswith("model.network.")}
    assert network and all(v == onnx.TensorProto.FLOAT16 for v in network.values())
    normalisers = {k: v for k, v in types.items() if "normalizer" in k}
    assert normalisers and all(v == onnx.TensorProto.FLOAT for v in normalisers.values())


@pytest.mark.parametrize("precision", ["int8", "int8-dynamic"])
def test_int8_quantises_network_layers_and_nothing_else(exports, precision):
    _, reports = exports
    proto = onnx.load(str(reports[precision].path))
    quantized = [n for n in proto.graph.node if n.op_type in QUANTIZED_OPS]
    assert quantized
    weights = {i for n in quantized for i in n.input if i.endswith(".weight_quantized")}
    assert weights and all(w.startswith("model.network.") for w in weights)
    # Output layers and the first block stay float32 (most of the accuracy, little arithmetic).
    assert not any(w.startswith(("model.network.final", "model.network.tau_head",
                                 "model.network.down.0.0")) for w in weights)
    types = initializer_types(reports[precision].path)
    assert types["model.network.final.1.weight"] == onnx.TensorProto.FLOAT


def test_deploy_controller_runs_every_precision_unchanged(exports):
    from rfmp_deploy import Controller, Policy

    model, reports = exports
    obs = np.random.default_rng(0).standard_normal(model.cfg.obs_dim).astype(np.float32)
    actions = {}
    for precision, report in reports.items():
        controller = Controller(Policy(str(report.path)), deterministic=True)
        assert controller.meta.precision == precision
        assert controller.meta.parity_max_abs_diff == pytest.approx(report.max_abs_diff, rel=0.01)
        assert f"precision:    {precision}" in controller.meta.summary()
        action = controller.step({"observation": obs})
        assert abs(np.linalg.norm(action[3:7]) - 1) < 1e-5
        actions[precision] = action
    # Same observation, zero noise: the reduced graphs act close to the float32 one.
    for precision in ("fp16", "int8", "int8-dynamic"):
        np.testing.assert_allclose(actions[precision], actions["fp32"], atol=0.5)


def test_int8_calibrates_on_given_windows_and_records_it(tmp_path, make_tiny_model):
    model = pose_policy(make_tiny_model)
    samples = {"observation": torch.randn(24, 2, model.cfg.obs_dim) * 4}
    from tensordict import TensorDict

    calibration = calibration_inputs(model, TensorDict(samples, [24]), batch_size=8)
    assert [tuple(t.shape) for t in calibration[0]] == [(8, 2, 3), (8, model.noise_dim)]
    report = export_onnx(model, tmp_path / "q.onnx", nfe=1, precision="int8", control_rate_hz=10.0,
                         calibration=calibration)
    assert metadata(report.path)["calibration"] == "given inputs (24 windows)"
    with pytest.raises(ValueError, match="precision must be one of"):
        export_onnx(model, tmp_path / "x.onnx", nfe=1, precision="int4", control_rate_hz=10.0)
    assert not (tmp_path / "x.onnx").exists()
    # No scratch files are left beside the model.
    assert sorted(p.name for p in tmp_path.iterdir()) == ["q.onnx"]


def test_image_policy_exports_in_fp16(tmp_path):
    from rfmp_rl.modules import ModelConfig, build_model

    cfg = ModelConfig("srfmp", "S2", obs_dim=2, horizon=4, down_dims=[16, 32],
                      time_embed_dim=32, tau_hidden_dim=32, cameras={"cam": [3, 32, 32]},
                      crop_shape=[28, 28], vision_out_dim=16)
    torch.manual_seed(0)
    model = build_model(cfg)
    model.action_normalizer.fit(model.chunk.unflatten(model.chunk.random_base(16)))
    model.obs_normalizer.fit(torch.randn(16, 2))
    report = export_onnx(model.eval(), tmp_path / "img.onnx", nfe=1, precision="fp16",
                         control_rate_hz=10.0)
    assert report.max_abs_diff <= PARITY_LIMITS["fp16"]
    types = initializer_types(report.path)
    vision = [v for k, v in types.items() if k.startswith("model.obs_encoder.vision")]
    assert vision and all(v == onnx.TensorProto.FLOAT16 for v in vision)
    # The original model is untouched (the exporter converts a copy).
    assert all(p.dtype == torch.float32 for p in model.parameters())


def test_cli_exports_int8_with_store_calibration(tmp_path, make_tiny_model, to_onnx_cli):
    model = pose_policy(make_tiny_model)
    ckpt = save_checkpoint(tmp_path / "ckpt.pt", model, control_rate_hz=10.0)
    gen = torch.Generator().manual_seed(1)
    from tensordict import TensorDict

    episodes = [TensorDict({"observation": torch.randn(30, 3, generator=gen) * 4,
                            "action": torch.rand(30, 8, generator=gen)}, [30]) for _ in range(2)]
    store = DemonstrationStore.from_episodes(episodes)
    store.save(tmp_path / "store")
    out = tmp_path / "policy_int8.onnx"
    args = ["--checkpoint", ckpt, "--nfe", "1", "--precision", "int8", "--calibration",
            tmp_path / "store", "--calibration-windows", "40", "--out", out]
    result = to_onnx_cli(*args)
    assert result.returncode == 0, result.stderr
    assert "(int8," in result.stdout and "parity against float32 PyTorch" in result.stdout
    meta = metadata(out)
    assert (meta["precision"], meta["calibration"]) == ("int8", "given inputs (40 windows)")
    # --calibration without int8 is a usage error; a missing store names itself.
    usage = to_onnx_cli(*args[:-6], "--precision", "fp16", "--calibration", "s")
    assert usage.returncode == 2 and "--calibration applies to --precision int8" in usage.stderr
    missing = to_onnx_cli(*args[:6], "--calibration", tmp_path / "nope")
    assert missing.returncode == 1 and "nope" in missing.stderr
    assert "Traceback" not in missing.stderr
