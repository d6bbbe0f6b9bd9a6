"""Export-readiness: the manifold maps and a solver step trace into one ONNX graph."""

from __future__ import annotations

import pytest
import torch

from rfmp_rl.manifolds import Horizon, parse_manifold
from rfmp_rl.solvers import integrate

onnx = pytest.importorskip("onnx")
ort = pytest.importorskip("onnxruntime")
pytest.importorskip("onnxscript")

POSE = parse_manifold("R3 x S3 x R1")


class ManifoldOps(torch.nn.Module):
    """expmap, logmap and one RK4 + one Euler-Exp step of a state-dependent field."""

    def __init__(self) -> None:
        super().__init__()
        self.manifold = Horizon(POSE, steps=4)
        self.weight = torch.nn.Parameter(torch.randn(self.manifold.dim, self.manifold.dim) * 0.3)

    def field(self, t: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
        return torch.tanh(x @ self.weight) * (1.0 + t)

    def forward(self, x: torch.Tensor, y: torch.Tensor, u: torch.Tensor):
        m = self.manifold
        log = m.logmap(x, y)
        exp = m.expmap(x, m.proju(x, u))
        stepped = integrate(self.field, x, m, nfe=4, method="rk4")
        euler = integrate(self.field, x, m, nfe=2, method="euler", t_end=1.5)
        return log, exp, stepped, euler, m.dist(x, y)


def test_manifold_ops_export_to_onnx_and_match_pytorch(tmp_path):
    torch.manual_seed(0)
    module = ManifoldOps().eval()
    m = module.manifold
    x, y = m.random_base(5), m.random_base(5)
    y[0] = x[0]  # identical points must survive export too
    u = torch.randn(5, m.dim)
    path = tmp_path / "ops.onnx"
    batch = torch.export.Dim("batch", min=1, max=1024)
    torch.onnx.export(
        module,
        (x, y, u),
        str(path),
        dynamo=True,
        opset_version=18,
        input_names=["x", "y", "u"],
        dynamic_shapes={"x": {0: batch}, "y": {0: batch}, "u": {0: batch}},
    )
    onnx.checker.check_model(onnx.load(str(path)))
    session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    for n in (5, 1, 17):  # the batch axis is dynamic
        xs, ys, us = m.random_base(n), m.random_base(n), torch.randn(n, m.dim)
        with torch.no_grad():
            expected = module(xs, ys, us)
        got = session.run(None, {"x": xs.numpy(), "y": ys.numpy(), "u": us.numpy()})
        assert len(got) == len(expected)
        for g, e in zip(got, expected, strict=True):
            torch.testing.assert_close(torch.from_numpy(g), e, atol=1e-5, rtol=1e-5)
