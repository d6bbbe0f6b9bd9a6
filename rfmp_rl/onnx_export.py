"""Export a trained policy's whole fixed-NFE inference to one ONNX graph, with parity checks.

The graph normalises observations, encodes them (images included), unrolls exactly NFE solver
evaluations with the manifold maps (or the DDIM steps), unnormalises and returns the action
chunk ``(B, T_p, D)``. The prior noise is a graph input (``prior_noise``, standard normal,
``(B, noise_dim)``): a controller draws it, and zeros give the deterministic mode — for every
prior, zero noise maps to the prior's mode (Gaussian mean, wrapped-Gaussian base point, the
sphere's origin for the uniform prior, DDIM's zero start).

Metadata (``metadata_props``, contract ``rfmp_rl.onnx/1``) describes inputs, horizons, the
action manifold and limits; `deploy/` reads only that.
"""

from __future__ import annotations

import json
import statistics
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from rfmp_rl import __version__
from rfmp_rl.manifolds import Manifold, Sphere, leaf_slices
from rfmp_rl.modules.policy_model import DiffusionModel, FlowModel

__all__ = ["InferenceGraph", "ExportReport", "export_onnx", "onnx_metadata", "ONNX_FORMAT"]

ONNX_FORMAT = "rfmp_rl.onnx/1"


class InferenceGraph(nn.Module):
    """``(observation?, *camera images, prior_noise) -> action`` with a fixed solver budget.

    Example:
        >>> from rfmp_rl.modules import ModelConfig, build_model
        >>> model = build_model(ModelConfig("srfmp", "S2", obs_dim=3, horizon=4,
        ...                                 down_dims=[16, 32])).eval()
        >>> graph = InferenceGraph(model, nfe=1)
        >>> graph(torch.randn(2, 2, 3), torch.zeros(2, model.noise_dim)).shape
        torch.Size([2, 4, 3])
    """

    def __init__(
        self,
        model: FlowModel | DiffusionModel,
        nfe: int,
        method: str = "euler",
        t_end: float = 1.0,
        schedule: str | None = None,
        refine_dt: float | None = None,
    ) -> None:
        super().__init__()
        self.model = model
        self.solver = {
            "nfe": int(nfe),
            "method": method,
            "t_end": float(t_end),
            "schedule": schedule,
            "refine_dt": refine_dt,
        }
        self.has_obs = model.cfg.obs_dim > 0
        self.cameras = tuple(model.cameras)
        self.input_names = (
            (["observation"] if self.has_obs else []) + list(self.cameras) + ["prior_noise"]
        )

    def forward(self, *inputs: torch.Tensor) -> torch.Tensor:
        obs = inputs[0] if self.has_obs else None
        offset = 1 if self.has_obs else 0
        images = dict(zip(self.cameras, inputs[offset : offset + len(self.cameras)], strict=True))
        noise = inputs[-1]
        cond = self.model.encode(obs, images or None)
        return self.model.sample(cond, noise, **self.solver)


def onnx_metadata(graph: InferenceGraph) -> dict[str, str]:
    """The ``rfmp_rl.onnx/1`` metadata for an inference graph."""
    model, cfg = graph.model, graph.model.cfg
    if not bool(model.action_normalizer.fitted):
        raise ValueError(
            "the action normaliser was never fitted (no action statistics): refusing to export a "
            "policy whose action limits are unknown"
        )
    # Euclidean coordinates: the demonstrated range; sphere coordinates: [-1, 1].
    norm = model.action_normalizer
    action_low = torch.where(norm.mask, norm.data_min, -1.0).tolist()
    action_high = torch.where(norm.mask, norm.data_max, 1.0).tolist()
    inputs: list[dict[str, Any]] = []
    if graph.has_obs:
        inputs.append(
            {"name": "observation", "shape": [2, cfg.obs_dim], "dtype": "float32", "kind": "lowdim"}
        )
    for name in graph.cameras:
        c, h, w = (int(v) for v in cfg.cameras[name])
        inputs.append(
            {
                "name": name,
                "shape": [2, c, h, w],
                "dtype": "uint8",
                "kind": "image",
                "image_size": [h, w],
                "crop": list(cfg.crop_shape or [h, w]),
            }
        )
    inputs.append(
        {"name": "prior_noise", "shape": [model.noise_dim], "dtype": "float32", "kind": "noise"}
    )
    schedule = graph.solver["schedule"] or (
        "srfmp" if isinstance(model, FlowModel) and model.stable else "uniform"
    )
    meta = {
        "rfmp_rl.format": ONNX_FORMAT,
        "rfmp_rl.version": __version__,
        "algorithm": cfg.algorithm,
        "nfe": str(graph.solver["nfe"]),
        "method": graph.solver["method"] if cfg.algorithm != "ddim" else "ddim",
        "t_end": repr(graph.solver["t_end"]),
        "schedule": schedule if cfg.algorithm != "ddim" else "ddim",
        "obs_horizon": str(cfg.obs_horizon),
        "horizon": str(cfg.horizon),
        "action_steps": str(cfg.action_steps),
        "control_rate_hz": repr(float(cfg.control_rate_hz)),
        "inputs": json.dumps(inputs),
        "observation_keys": json.dumps([{"key": k, "dim": int(d)} for k, d in cfg.obs_keys]),
        "action_manifold": json.dumps(model.step_manifold.spec()),
        "action_low": json.dumps(action_low),
        "action_high": json.dumps(action_high),
        "noise": json.dumps(
            {
                "distribution": "standard_normal",
                "dim": model.noise_dim,
                "default": "standard_normal",
            }
        ),
    }
    return meta


@dataclass
class ExportReport:
    """What `export_onnx` measured."""

    path: Path
    max_abs_diff: float  # in normalised action units
    max_sphere_error: float
    max_raw_diff: float
    onnx_latency_ms: float
    torch_latency_ms: float
    metadata: dict[str, str]

    def summary(self) -> str:
        return (
            f"wrote {self.path}\n"
            f"parity: max |onnxruntime - torch| = {self.max_abs_diff:.3g} in normalised action "
            f"units (limit 1e-4; {self.max_raw_diff:.3g} in raw units); "
            f"max | |q| - 1 | over sphere components = {self.max_sphere_error:.3g} (limit 1e-5)\n"
            f"latency at batch 1: onnxruntime {self.onnx_latency_ms:.2f} ms, "
            f"torch eager {self.torch_latency_ms:.2f} ms "
            f"({self.torch_latency_ms / max(self.onnx_latency_ms, 1e-9):.1f}x)"
        )


def _sphere_error(manifold: Manifold, action: np.ndarray) -> float:
    """Largest | |x| - 1 | over the sphere components of ``action (..., D)``."""
    errors = [
        np.abs(np.linalg.norm(action[..., part].astype(np.float64), axis=-1) - 1).max()
        for part, leaf in leaf_slices(manifold)
        if isinstance(leaf, Sphere)
    ]
    return float(max(errors, default=0.0))


def _example_inputs(graph: InferenceGraph, batch: int, generator: torch.Generator):
    model, cfg = graph.model, graph.model.cfg
    tensors = []
    if graph.has_obs:
        lo, hi = model.obs_normalizer.data_min, model.obs_normalizer.data_max
        u = torch.rand(batch, 2, cfg.obs_dim, generator=generator)
        tensors.append((lo + (hi - lo) * u).to(torch.float32))
    for name in graph.cameras:
        shape = cfg.cameras[name]
        tensors.append(
            torch.randint(0, 256, (batch, 2, *shape), generator=generator, dtype=torch.uint8)
        )
    tensors.append(torch.randn(batch, model.noise_dim, generator=generator))
    return tuple(tensors)


def export_onnx(
    model: FlowModel | DiffusionModel,
    path: str | Path,
    nfe: int,
    method: str = "euler",
    t_end: float = 1.0,
    schedule: str | None = None,
    refine_dt: float | None = None,
    opset: int = 18,
    atol: float = 1e-4,
    sphere_tol: float = 1e-5,
    latency_runs: int = 20,
) -> ExportReport:
    """Export, check with ``onnx.checker``, and compare onnxruntime with PyTorch.

    Raises:
        RuntimeError: when the max difference exceeds ``atol`` or a sphere component of an
            onnxruntime action is off the manifold by more than ``sphere_tol``. The file is
            written before the check so it can be inspected.
    """
    import onnx
    import onnxruntime as ort

    model = model.eval()
    graph = InferenceGraph(model, nfe, method, t_end, schedule, refine_dt).eval()
    metadata = onnx_metadata(graph)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    generator = torch.Generator().manual_seed(0)
    example = _example_inputs(graph, 2, generator)
    batch = torch.export.Dim("batch", min=1, max=4096)
    with torch.no_grad():
        program = torch.onnx.export(
            graph,
            example,
            dynamo=True,
            opset_version=opset,
            input_names=graph.input_names,
            output_names=["action"],
            dynamic_shapes=(tuple({0: batch} for _ in example),),  # one entry: *inputs
            verbose=False,
        )
    proto = program.model_proto
    del proto.metadata_props[:]
    for key, value in metadata.items():
        entry = proto.metadata_props.add()
        entry.key, entry.value = key, value
    onnx.save_model(proto, str(path))
    onnx.checker.check_model(str(path), full_check=True)
    for tensor in [*proto.graph.input, *proto.graph.output]:
        first = tensor.type.tensor_type.shape.dim[0]
        if not first.dim_param:
            raise ValueError(
                f"{path}: the batch axis of {tensor.name!r} was specialised to {first.dim_value} "
                "during export (a model op depends on the batch size); it must stay dynamic"
            )

    session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    worst = worst_raw = sphere = 0.0
    for b in (1, 3, 8):
        inputs = _example_inputs(graph, b, generator)
        with torch.no_grad():
            expected = graph(*inputs).numpy()
        feed = {name: t.numpy() for name, t in zip(graph.input_names, inputs, strict=True)}
        got = session.run(["action"], feed)[0]
        # Compared in normalised action units (Euclidean coordinates divided by their half-range,
        # sphere coordinates as they are), so the 1e-4 limit means the same for metres, pixels
        # or quaternions; float32 rounding alone exceeds 1e-4 in raw pixel units (Push-T: 0-512).
        scale = model.action_normalizer.scale.numpy()
        worst = max(worst, float((np.abs(got - expected) / scale).max()))
        worst_raw = max(worst_raw, float(np.abs(got - expected).max()))
        sphere = max(sphere, _sphere_error(model.step_manifold, got))
    one = _example_inputs(graph, 1, generator)
    feed = {name: t.numpy() for name, t in zip(graph.input_names, one, strict=True)}
    onnx_ms, torch_ms = [], []
    for _ in range(latency_runs):
        start = time.perf_counter()
        session.run(["action"], feed)
        onnx_ms.append((time.perf_counter() - start) * 1e3)
        start = time.perf_counter()
        with torch.no_grad():
            graph(*one)
        torch_ms.append((time.perf_counter() - start) * 1e3)
    report = ExportReport(
        path, worst, sphere, worst_raw, statistics.median(onnx_ms), statistics.median(torch_ms),
        metadata,
    )
    if worst > atol:
        raise RuntimeError(
            f"{path}: onnxruntime differs from PyTorch by {worst:.3g} > {atol} "
            "(normalised action units)"
        )
    if sphere > sphere_tol:
        raise RuntimeError(
            f"{path}: a sphere component is off the manifold by {sphere:.3g} > {sphere_tol}"
        )
    return report
