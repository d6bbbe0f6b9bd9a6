"""ONNX export of the small UNet preset: onnxruntime must match PyTorch."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from rfmp_rl.models import make_unet

ort = pytest.importorskip("onnxruntime", reason="install the 'export' extra (onnxruntime)")
pytest.importorskip("onnxscript", reason="install the 'export' extra (onnxscript)")


@pytest.mark.parametrize("predict_tau", [False, True], ids=["rfmp", "srfmp"])
def test_small_unet_exports_and_matches_onnxruntime(tmp_path: Path, predict_tau: bool) -> None:
    torch.manual_seed(0)
    net = make_unet("small", input_dim=2, global_cond_dim=40, predict_tau=predict_tau).eval()
    args = (torch.randn(2, 16, 2), torch.rand(2), torch.randn(2, 40))
    path = tmp_path / "unet.onnx"
    torch.onnx.export(net, args, path, dynamo=True, opset_version=18)

    session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    names = [i.name for i in session.get_inputs()]
    assert len(names) == 3
    outputs = session.run(None, {n: a.numpy() for n, a in zip(names, args, strict=True)})

    with torch.no_grad():
        expected = net(*args)
    expected = expected if isinstance(expected, tuple) else (expected,)
    assert len(outputs) == len(expected)
    for got, want in zip(outputs, expected, strict=True):
        torch.testing.assert_close(torch.from_numpy(got), want, atol=1e-4, rtol=1e-4)
