"""Tiny ONNX policies that follow the ``rfmp_rl.onnx/1`` contract, built with ``onnx.helper``.

The graph is linear, so tests know every answer::

    features = [observation window flattened (2 * D_obs), mean pixel / 255 per camera, noise]
    action[b, t] = features[b] @ W + bias + offsets[t]        # (B, T_p, D)

Sphere coordinates get a large bias (norm ~5), so the controller must renormalise them.
Neither torch nor rfmp_rl is needed.
"""

from __future__ import annotations

import json
import threading
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper

WINDOW = 2  # rows of every graph input window: [context, latest]

R3_S3_R1 = {"type": "product", "components": [
    {"type": "euclidean", "dim": 3}, {"type": "sphere", "n": 3}, {"type": "euclidean", "dim": 1}
]}


def _leaves(spec: dict) -> list[tuple[str, int, int]]:
    """(kind, start, stop) of each leaf."""
    out: list[tuple[str, int, int]] = []

    def walk(s: dict, start: int) -> int:
        if s["type"] == "product":
            for c in s["components"]:
                start = walk(c, start)
            return start
        size = s["dim"] if s["type"] == "euclidean" else s["n"] + 1
        out.append((s["type"], start, start + size))
        return start + size

    walk(spec, 0)
    return out


@dataclass
class ToySpec:
    """What to build. ``weight``/``bias``/``offsets`` default to seeded random values."""

    obs_keys: list[tuple[str, int]] = field(default_factory=lambda: [("pos", 3), ("quat", 4)])
    cameras: dict[str, tuple[int, int, int]] = field(default_factory=dict)  # name -> (C, H, W)
    crop: tuple[int, int] | None = None
    manifold: dict = field(default_factory=lambda: R3_S3_R1)
    low: list | None = None  # default: -1 for Euclidean, -1 for sphere coordinates
    high: list | None = None
    horizon: int = 4
    action_steps: int = 2
    obs_horizon: int = 2  # T_o in the metadata; the graph's windows always hold 2 rows
    noise_dim: int = 8
    control_rate_hz: float = 10.0
    noise_default: str = "standard_normal"
    seed: int = 0
    weight: np.ndarray | None = None  # (F, D)
    bias: np.ndarray | None = None  # (D,)
    offsets: np.ndarray | None = None  # (T_p, D)
    batch: str | int = "B"  # the graph's batch dimension (the contract: dynamic)

    @property
    def obs_dim(self) -> int:
        return sum(d for _, d in self.obs_keys)

    @property
    def action_dim(self) -> int:
        return _leaves(self.manifold)[-1][2]

    @property
    def n_features(self) -> int:
        return WINDOW * self.obs_dim + len(self.cameras) + self.noise_dim

    def params(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        rng = np.random.default_rng(self.seed)
        d, f = self.action_dim, self.n_features
        weight = self.weight if self.weight is not None else 0.1 * rng.standard_normal((f, d))
        if self.bias is not None:
            bias = self.bias
        else:
            bias = np.zeros(d)
            for kind, _, stop in _leaves(self.manifold):
                if kind == "sphere":
                    bias[stop - 1] = 5.0
        offsets = (self.offsets if self.offsets is not None
                   else 0.01 * np.arange(self.horizon)[:, None] * np.ones(d))
        return (np.asarray(weight, np.float32), np.asarray(bias, np.float32),
                np.asarray(offsets, np.float32))


def toy_metadata(spec: ToySpec) -> dict[str, str]:
    inputs = []
    if spec.obs_keys:
        inputs.append({"name": "observation", "shape": [WINDOW, spec.obs_dim],
                       "dtype": "float32", "kind": "lowdim"})
    for name, (c, h, w) in spec.cameras.items():
        inputs.append({"name": name, "shape": [WINDOW, c, h, w], "dtype": "uint8",
                       "kind": "image", "image_size": [h, w], "crop": list(spec.crop or (h, w))})
    inputs.append({"name": "prior_noise", "shape": [spec.noise_dim], "dtype": "float32",
                   "kind": "noise"})
    d = spec.action_dim
    low, high = [-1.0] * d, [1.0] * d
    return {
        "rfmp_rl.format": "rfmp_rl.onnx/1",
        "rfmp_rl.version": "0.1.0",
        "algorithm": "srfmp",
        "nfe": "1",
        "method": "euler",
        "t_end": "1.0",
        "schedule": "srfmp",
        "obs_horizon": str(spec.obs_horizon),
        "horizon": str(spec.horizon),
        "action_steps": str(spec.action_steps),
        "control_rate_hz": repr(float(spec.control_rate_hz)),
        "inputs": json.dumps(inputs),
        "observation_keys": json.dumps([{"key": k, "dim": dd} for k, dd in spec.obs_keys]),
        "action_manifold": json.dumps(spec.manifold),
        "action_low": json.dumps(spec.low if spec.low is not None else low),
        "action_high": json.dumps(spec.high if spec.high is not None else high),
        "noise": json.dumps({"distribution": "standard_normal", "dim": spec.noise_dim,
                             "default": spec.noise_default}),
    }


def build_graph(spec: ToySpec) -> onnx.ModelProto:
    weight, bias, offsets = spec.params()
    nodes, inputs, features, inits = [], [], [], []

    def const(name: str, array: np.ndarray) -> str:
        inits.append(numpy_helper.from_array(np.asarray(array), name))
        return name

    if spec.obs_keys:
        inputs.append(helper.make_tensor_value_info(
            "observation", TensorProto.FLOAT, [spec.batch, WINDOW, spec.obs_dim]))
        shape = const("obs_flat_shape", np.array([-1, WINDOW * spec.obs_dim], np.int64))
        nodes.append(helper.make_node("Reshape", ["observation", shape], ["obs_flat"]))
        features.append("obs_flat")
    for name, (c, h, w) in spec.cameras.items():
        inputs.append(helper.make_tensor_value_info(
            name, TensorProto.UINT8, [spec.batch, WINDOW, c, h, w]))
        axes = const(f"{name}_axes", np.array([1, 2, 3, 4], np.int64))
        col = const(f"{name}_col", np.array([-1, 1], np.int64))
        scale = const(f"{name}_scale", np.array(1 / 255, np.float32))
        nodes += [
            helper.make_node("Cast", [name], [f"{name}_f"], to=TensorProto.FLOAT),
            helper.make_node("ReduceMean", [f"{name}_f", axes], [f"{name}_m"], keepdims=1),
            helper.make_node("Reshape", [f"{name}_m", col], [f"{name}_c"]),
            helper.make_node("Mul", [f"{name}_c", scale], [f"{name}_feat"]),
        ]
        features.append(f"{name}_feat")
    inputs.append(helper.make_tensor_value_info("prior_noise", TensorProto.FLOAT,
                                                [spec.batch, spec.noise_dim]))
    features.append("prior_noise")
    const("W", weight)
    const("bias", bias)
    const("offsets", offsets)
    const("unsq_axes", np.array([1], np.int64))
    nodes += [
        helper.make_node("Concat", features, ["features"], axis=1),
        helper.make_node("MatMul", ["features", "W"], ["lin"]),
        helper.make_node("Add", ["lin", "bias"], ["step"]),
        helper.make_node("Unsqueeze", ["step", "unsq_axes"], ["step3"]),
        helper.make_node("Add", ["step3", "offsets"], ["action"]),
    ]
    output = helper.make_tensor_value_info("action", TensorProto.FLOAT,
                                           [spec.batch, spec.horizon, spec.action_dim])
    graph = helper.make_graph(nodes, "toy_policy", inputs, [output], initializer=inits)
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 18)],
                              producer_name="rfmp_deploy tests")
    model.ir_version = 9
    onnx.checker.check_model(model)
    return model


def write_model(
    path: str | Path,
    spec: ToySpec | None = None,
    meta_spec: ToySpec | None = None,
    overrides: dict[str, str | None] | None = None,
) -> Path:
    """Write a toy policy; metadata from ``meta_spec`` (default ``spec``) with ``overrides``
    applied (``None`` deletes a key)."""
    spec = spec or ToySpec()
    model = build_graph(spec)
    props = toy_metadata(meta_spec or spec)
    for key, value in (overrides or {}).items():
        if value is None:
            props.pop(key, None)
        else:
            props[key] = value
    onnx.helper.set_model_props(model, props)
    path = Path(path)
    onnx.save_model(model, str(path))
    return path


def reference(
    spec: ToySpec,
    observation: np.ndarray | None,
    images: dict[str, np.ndarray],
    noise: np.ndarray,
) -> np.ndarray:
    """What the toy graph computes, in numpy: ``(B, T_p, D)``."""
    weight, bias, offsets = (p.astype(np.float64) for p in spec.params())
    batch = noise.shape[0]
    parts = []
    if spec.obs_keys:
        parts.append(observation.reshape(batch, -1).astype(np.float64))
    for name in spec.cameras:
        parts.append(images[name].reshape(batch, -1).mean(axis=1, keepdims=True) / 255.0)
    parts.append(noise.astype(np.float64))
    features = np.concatenate(parts, axis=1)
    return (features @ weight + bias)[:, None, :] + offsets[None]


def example_spec() -> ToySpec:
    """The toy counterpart of ``rfmp_deploy.metadata.example_metadata()`` (docstring examples)."""
    return ToySpec(
        obs_keys=[("eef_pos", 3), ("eef_quat", 4), ("gripper", 1)],
        cameras={"wrist": (3, 84, 84)},
        crop=(76, 76),
        horizon=16,
        action_steps=8,
        noise_dim=8,
        low=[-0.5, -0.5, 0.0, -1, -1, -1, -1, 0.0],
        high=[0.5, 0.5, 0.6, 1, 1, 1, 1, 0.08],
    )


def project(spec: ToySpec, action: np.ndarray) -> np.ndarray:
    """Clip Euclidean coordinates and renormalise spheres, as the controller should."""
    meta = toy_metadata(spec)
    low, high = np.array(json.loads(meta["action_low"])), np.array(json.loads(meta["action_high"]))
    out = np.asarray(action, np.float64).copy()
    for kind, start, stop in _leaves(spec.manifold):
        if kind == "euclidean":
            out[..., start:stop] = np.clip(out[..., start:stop], low[start:stop], high[start:stop])
        else:
            block = out[..., start:stop]
            out[..., start:stop] = block / np.linalg.norm(block, axis=-1, keepdims=True)
    return out


def make_observation(spec: ToySpec, k: float = 0.0, frame_size: tuple[int, int] = (48, 64)
                     ) -> dict[str, np.ndarray]:
    """A valid observation dict: low-dim values depend on ``k``, frames are constant ``10 * k``."""
    out: dict[str, np.ndarray] = {}
    for i, (key, dim) in enumerate(spec.obs_keys):
        out[key] = 0.1 * k + 0.01 * i + 0.001 * np.arange(dim)
    for name, (c, _, _) in spec.cameras.items():
        out[name] = np.full((*frame_size, c), int(10 * k) % 256, np.uint8)
    return out


def lowdim_vector(spec: ToySpec, observation: dict) -> np.ndarray:
    return np.concatenate([np.ravel(observation[key]) for key, _ in spec.obs_keys])


class Recording:
    """Wraps a policy and records every call's inputs (copies)."""

    def __init__(self, policy) -> None:
        self.policy = policy
        self.meta = policy.meta
        self.calls: list[tuple] = []

    def __call__(self, observation, images, noise):
        self.calls.append((None if observation is None else observation.copy(),
                           {k: v.copy() for k, v in images.items()}, noise.copy()))
        return self.policy(observation, images, noise)


class Gated(Recording):
    """A policy that blocks in ``__call__`` until ``gate`` is set (a model as slow as wanted)."""

    def __init__(self, policy) -> None:
        super().__init__(policy)
        self.gate = threading.Event()
        self.started = threading.Event()

    def __call__(self, observation, images, noise):
        self.started.set()
        if not self.gate.wait(timeout=10):
            raise TimeoutError("gate never opened")
        return super().__call__(observation, images, noise)


__all__ = ["R3_S3_R1", "Gated", "Recording", "ToySpec", "build_graph", "example_spec",
           "lowdim_vector", "make_observation", "project", "reference", "replace",
           "toy_metadata", "write_model"]
