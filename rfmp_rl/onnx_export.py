"""Export a trained policy's whole fixed-NFE inference to one ONNX graph, with parity checks.

The graph normalises observations, encodes them (images included), unrolls exactly NFE solver
evaluations with the manifold maps (or the DDIM steps), unnormalises and returns the action
chunk ``(B, T_p, D)``. The prior noise is a graph input (``prior_noise``, standard normal,
``(B, noise_dim)``; the Consistency Policy's multistep sampling takes one draw per evaluation,
``(B, NFE * noise_dim)``, `PolicyModel.prior_noise_dim`): a controller draws it, and zeros give
the deterministic mode — for every prior, zero noise maps to the prior's mode (Gaussian mean,
wrapped-Gaussian base point, the sphere's origin for the uniform prior, DDIM's zero start).

The observation inputs are the window ``[o^c, o^{s-1}]`` ``(B, 2, ...)``, context first, for
every T_o (``obs_horizon``). Training draws the context ``c`` from ``[s - T_o, s - 2]`` and, when
T_o > 2, conditions on the gap ``s - c``; at inference the context is always the oldest of the
last T_o observations (``c = s - T_o``; at an episode's start the first observation repeated, as
the training sampler pads), so the gap is the constant T_o and the graph builds it itself: a
controller keeps the last ``obs_horizon`` observations and feeds ``[oldest, latest]``, with the
same inputs as for T_o = 2.

Metadata (``metadata_props``, contract ``rfmp_rl.onnx/1``) describes inputs, horizons (including
``obs_horizon``), the action manifold and limits and, for a model trained on canonical quaternion
signs (``ModelConfig.obs_quaternions``), ``observation_quaternions``: the columns the controller
makes canonical the same way; `deploy/` reads only that.

Reduced precision (``precision=``) changes the networks (observation encoder, UNet) only; the
normalisers, the manifold maps and the solver steps stay float32, and so do the graph's inputs
and output, so a controller runs every variant unchanged:

- ``fp16``: the networks' weights and arithmetic in float16 (half the file size; fast where the
  execution provider has float16 kernels, such as CUDA or ARM CPUs).
- ``int8``: onnxruntime's static quantisation of the networks' convolutions and linear layers
  (int8 weights per output channel, uint8 activations whose ranges are calibrated by running the
  graph on calibration inputs: observation windows from the training data when given, otherwise
  windows drawn uniformly in the observation normaliser's range).
- ``int8-dynamic``: onnxruntime's dynamic quantisation: int8 weights, activation ranges computed
  at every call, no calibration.

Every export is compared with the float32 PyTorch graph on the same inputs and prior noise; the
largest difference (normalised action units) is printed and stored in the metadata
(``precision``, ``parity_max_abs_diff``), and must stay below the precision's limit.
"""

from __future__ import annotations

import contextlib
import copy
import json
import logging
import os
import statistics
import time
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from rfmp_rl import __version__, keys
from rfmp_rl.manifolds import Manifold, Sphere, leaf_slices
from rfmp_rl.modules.policy_model import DiffusionModel, FlowModel, unwrap_policy_model
from rfmp_rl.solvers import SolverConfig

__all__ = ["InferenceGraph", "ExportReport", "export_onnx", "onnx_metadata", "ONNX_FORMAT",
           "EXPORT_PRECISIONS", "PARITY_LIMITS", "calibration_inputs"]

ONNX_FORMAT = "rfmp_rl.onnx/1"

#: Export precisions (see the module docstring).
EXPORT_PRECISIONS = ("fp32", "fp16", "int8", "int8-dynamic")

#: Default limit on max |onnxruntime - float32 PyTorch| in normalised action units, per precision
#: (Euclidean coordinates divided by their half-range, so 1.0 is half the demonstrated range).
#: fp32 is exact up to rounding; the reduced precisions guard against a broken conversion, not
#: against a score change: measure that in closed loop (recipes/pusht/eval_onnx.py).
PARITY_LIMITS = {"fp32": 1e-4, "fp16": 1e-2, "int8": 0.2, "int8-dynamic": 0.1}

#: The graph's modules whose operators reduced precision may change.
_NETWORK_SCOPES = ("model.network", "model.obs_encoder")
#: Kept in float32 by int8 quantisation: the UNet's first residual block and its output layers
#: (final projection, tau head). They hold a small share of the arithmetic and most of the
#: accuracy loss (Push-T: mean action error 0.015 -> 0.008 in normalised units).
_FLOAT_SCOPES = ("model.network.down.0.0", "model.network.final", "model.network.tau_head")


class InferenceGraph(nn.Module):
    """``(observation?, *camera images, prior_noise) -> action`` with a fixed solver budget.

    The observation inputs are the window ``[o^c, o^{s-1}]`` ``(B, 2, ...)``. For T_o > 2 the
    policy's gap input is the constant ``obs_gap`` = T_o (the inference rule: the context is the
    oldest of the last T_o observations), built inside the graph, so the inputs are the same for
    every T_o.

    Example:
        >>> from rfmp_rl.modules import ModelConfig, build_model
        >>> model = build_model(ModelConfig("srfmp", "S2", obs_dim=3, horizon=4,
        ...                                 down_dims=[16, 32])).eval()
        >>> graph = InferenceGraph(model, nfe=1)
        >>> graph(torch.randn(2, 2, 3), torch.zeros(2, model.noise_dim)).shape
        torch.Size([2, 4, 3])
        >>> longer = build_model(ModelConfig("srfmp", "S2", obs_dim=3, horizon=4, obs_horizon=4,
        ...                                  down_dims=[16, 32])).eval()
        >>> graph = InferenceGraph(longer, nfe=1)  # T_o = 4: same inputs, gap 4 inside
        >>> graph.input_names, graph.obs_gap
        (['observation', 'prior_noise'], 4.0)
    """

    def __init__(
        self,
        model: FlowModel | DiffusionModel,
        nfe: int | None = None,
        method: str = "euler",
        t_end: float = 1.0,
        schedule: str | None = None,
        refine_dt: float | None = None,
        *,
        solver: SolverConfig | None = None,
    ) -> None:
        super().__init__()
        model = unwrap_policy_model(model, "InferenceGraph")
        self.model = model
        self.solver = _solver(model, solver, nfe, method, t_end, schedule, refine_dt)
        self.has_obs = model.cfg.obs_dim > 0
        self.cameras = tuple(model.cameras)
        # s - c at inference: the context is the oldest of the last T_o observations
        self.obs_gap = float(model.cfg.obs_horizon) if model.cfg.obs_horizon > 2 else None
        # the conditioning inputs as the model orders them (`condition_keys`) without the gap,
        # which the graph builds, then the noise
        names = model.condition_keys(gap_key=keys.OBS_GAP)
        if self.obs_gap is not None:
            names = names[:-1]  # the gap comes last
        self.input_names = [*map(str, names), "prior_noise"]
        self.noise_dim = model.prior_noise_dim(self.solver.nfe)  # width of prior_noise

    def forward(self, *inputs: torch.Tensor) -> torch.Tensor:
        *conditioning, noise = inputs
        if self.obs_gap is not None:
            gap = noise.new_full((noise.shape[0],), self.obs_gap)  # (B,), follows the batch
            conditioning.append(gap)
        cond = self.model.encode_inputs(*conditioning)
        return self.model.sample(cond, noise, **self.solver.sample_kwargs())


def _solver(model, solver, nfe, method, t_end, schedule, refine_dt) -> SolverConfig:
    """``solver`` or one built from the separate arguments, resolved for the model."""
    if solver is None:
        solver = SolverConfig(1 if nfe is None else nfe, t_end, method, schedule, refine_dt)
    elif nfe is not None:
        raise TypeError("give either solver= or nfe (with method, t_end, ...), not both")
    return solver.resolve(model.cfg.algorithm)


def onnx_metadata(graph: InferenceGraph, control_rate_hz: float | None = None) -> dict[str, str]:
    """The ``rfmp_rl.onnx/1`` metadata for an inference graph executed at ``control_rate_hz``
    (the environment's rate; a checkpoint carries it as ``payload["control_rate_hz"]``)."""
    model, cfg = graph.model, graph.model.cfg
    if not bool(model.action_normalizer.fitted):
        raise ValueError(
            "the action normaliser was never fitted (no action statistics): refusing to export a "
            "policy whose action limits are unknown"
        )
    if control_rate_hz is None or not float(control_rate_hz) > 0:
        raise ValueError(
            f"control_rate_hz must be the rate (Hz, > 0) the policy's actions are executed at, "
            f"got {control_rate_hz!r} (export/to_onnx.py: --rate)"
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
        {"name": "prior_noise", "shape": [graph.noise_dim], "dtype": "float32", "kind": "noise"}
    )
    solver = graph.solver
    meta = {
        "rfmp_rl.format": ONNX_FORMAT,
        "rfmp_rl.version": __version__,
        "algorithm": cfg.algorithm,
        "nfe": str(solver.nfe),
        "method": solver.method,
        "t_end": repr(solver.t_end),
        "schedule": solver.schedule,
        "obs_horizon": str(cfg.obs_horizon),
        "horizon": str(cfg.horizon),
        "action_steps": str(cfg.action_steps),
        "control_rate_hz": repr(float(control_rate_hz)),
        "inputs": json.dumps(inputs),
        "observation_keys": json.dumps([{"key": k, "dim": int(d)} for k, d in cfg.obs_keys]),
        "action_manifold": json.dumps(model.step_manifold.spec()),
        "action_low": json.dumps(action_low),
        "action_high": json.dumps(action_high),
        "noise": json.dumps(
            {
                "distribution": "standard_normal",
                "dim": graph.noise_dim,
                "default": "standard_normal",
            }
        ),
    }
    if cfg.obs_quaternions:  # the controller makes these observed quaternions canonical
        meta["observation_quaternions"] = json.dumps(cfg.obs_quaternions)
    return meta


@dataclass
class ExportReport:
    """What `export_onnx` measured."""

    path: Path
    max_abs_diff: float  # against float32 PyTorch, in normalised action units
    max_sphere_error: float
    max_raw_diff: float
    onnx_latency_ms: float
    torch_latency_ms: float
    metadata: dict[str, str]
    precision: str = "fp32"
    mean_abs_diff: float = 0.0
    parity_limit: float = PARITY_LIMITS["fp32"]

    def summary(self) -> str:
        size = self.path.stat().st_size / 1e6 if self.path.exists() else float("nan")
        return (
            f"wrote {self.path} ({self.precision}, {size:.1f} MB)\n"
            f"parity against float32 PyTorch: max |onnxruntime - torch| = "
            f"{self.max_abs_diff:.3g} (mean {self.mean_abs_diff:.3g}) in normalised action "
            f"units (limit {self.parity_limit:g}; {self.max_raw_diff:.3g} in raw units); "
            f"max | |q| - 1 | over sphere components = {self.max_sphere_error:.3g} (limit 1e-5)\n"
            f"latency at batch 1: onnxruntime {self.onnx_latency_ms:.2f} ms, "
            f"torch eager float32 {self.torch_latency_ms:.2f} ms "
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
    tensors.append(torch.randn(batch, graph.noise_dim, generator=generator))
    return tuple(tensors)


def calibration_inputs(
    model: FlowModel | DiffusionModel, samples, batch_size: int = 8, seed: int = 0, nfe: int = 1
) -> list[tuple[torch.Tensor, ...]]:
    """int8 calibration batches (graph inputs, in `InferenceGraph` order) from training samples.

    Args:
        samples: a TensorDict of training samples as the store's replay buffer returns them:
            the observation window under ``observation`` ``(B, 2, D_obs)`` (raw units) and each
            camera's window under its name ``(B, 2, C, H, W)``. With T_o > 2 their contexts
            lie 2 to T_o steps back (the training gaps) while the graph's is T_o steps back:
            the same observation ranges, which is what calibration measures.
        batch_size: windows per calibration run.
        seed: seed of the standard-normal prior noise drawn for each window.
        nfe: the NFE of the graph (the width of its prior noise, `PolicyModel.prior_noise_dim`).
    """
    generator = torch.Generator().manual_seed(seed)
    columns = []
    if model.cfg.obs_dim > 0:
        columns.append(samples.get(keys.OBSERVATION)[:, -2:].float())
    columns += [samples.get(name)[:, -2:] for name in model.cameras]
    n = columns[0].shape[0] if columns else samples.batch_size[0]
    columns.append(torch.randn(n, model.prior_noise_dim(nfe), generator=generator))
    return [tuple(c[i:i + batch_size].cpu() for c in columns) for i in range(0, n, batch_size)]


def _name_scope(node) -> str:
    """The PyTorch module path the dynamo exporter recorded for an ONNX node ('' if none)."""
    for prop in node.metadata_props:
        if prop.key == "pkg.torch.onnx.name_scopes":
            return prop.value
    return ""


def _kept_in_float(proto) -> list[str]:
    """Names of the nodes int8 quantisation leaves alone: everything outside the networks
    (normalisers, manifold maps, solver steps) and the `_FLOAT_SCOPES` layers."""
    nodes = list(proto.graph.node)
    scopes = [_name_scope(n) for n in nodes]
    if not any(scope in s for s in scopes for scope in _NETWORK_SCOPES):
        raise RuntimeError(
            "the exported graph records no module scopes (pkg.torch.onnx.name_scopes), so the "
            "network's operators cannot be told from the solver's: cannot quantise"
        )
    return [n.name for n, s in zip(nodes, scopes, strict=True)
            if not any(scope in s for scope in _NETWORK_SCOPES)
            or any(scope in s for scope in _FLOAT_SCOPES)]


def _quantize(proto, precision: str, work: Path, feeds: list[dict[str, np.ndarray]]):
    """The int8 model of ``proto``: the networks' Conv / Gemm / MatMul quantised, every other
    node excluded. ``work`` is a scratch folder (the quantiser reads and writes files)."""
    import onnx
    from onnxruntime.quantization import CalibrationDataReader

    class Calibration(CalibrationDataReader):
        def __init__(self) -> None:
            self.feeds = iter(feeds)

        def get_next(self) -> dict[str, np.ndarray] | None:
            return next(self.feeds, None)

    source, target = work / "float32.onnx", work / f"{precision}.onnx"
    onnx.save_model(proto, str(source))
    exclude = _kept_in_float(proto)
    ops = ["Conv", "Gemm", "MatMul"]
    logging.disable(logging.WARNING)  # the quantiser logs every initializer it deduplicates
    try:
        _run_quantiser(precision, source, target, exclude, ops, Calibration)
    finally:
        logging.disable(logging.NOTSET)
    quantized = onnx.load(str(target))
    if not any(n.op_type in ("QLinearConv", "ConvInteger", "QLinearMatMul", "MatMulInteger",
                             "DynamicQuantizeMatMul") for n in quantized.graph.node):
        raise RuntimeError("onnxruntime's quantiser left every operator in float32")
    return quantized


def _run_quantiser(precision, source, target, exclude, ops, calibration) -> None:
    from onnxruntime.quantization import (
        QuantFormat,
        QuantType,
        quantize_dynamic,
        quantize_static,
    )

    if precision == "int8":
        quantize_static(
            str(source), str(target), calibration(), quant_format=QuantFormat.QOperator,
            op_types_to_quantize=ops, nodes_to_exclude=exclude, per_channel=True,
            activation_type=QuantType.QUInt8, weight_type=QuantType.QInt8,
        )
    else:
        quantize_dynamic(
            str(source), str(target), op_types_to_quantize=ops, nodes_to_exclude=exclude,
            per_channel=True, weight_type=QuantType.QInt8,
        )


@contextlib.contextmanager
def _quiet(*names: str):
    """Raise the named loggers to WARNING for the duration (an app logging at INFO, such as a
    Hydra recipe, would otherwise print one line per exported initializer)."""
    loggers = [logging.getLogger(name) for name in names]
    levels = [lg.level for lg in loggers]
    for lg in loggers:
        lg.setLevel(max(lg.getEffectiveLevel(), logging.WARNING))
    try:
        yield
    finally:
        for lg, level in zip(loggers, levels, strict=True):
            lg.setLevel(level)


def _save_atomic(proto, path: Path) -> None:
    """Write ``proto`` to ``path`` through a temporary file in the same folder and a rename."""
    import onnx

    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}")
    try:
        onnx.save_model(proto, str(tmp))
        with open(tmp, "rb") as f:
            os.fsync(f.fileno())
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def export_onnx(
    model: FlowModel | DiffusionModel,
    path: str | Path,
    nfe: int | None = None,
    method: str = "euler",
    t_end: float = 1.0,
    schedule: str | None = None,
    refine_dt: float | None = None,
    opset: int = 18,
    atol: float | None = None,
    sphere_tol: float = 1e-5,
    latency_runs: int = 20,
    precision: str = "fp32",
    calibration: Iterable[Sequence[torch.Tensor]] | None = None,
    solver: SolverConfig | None = None,
    control_rate_hz: float | None = None,
) -> ExportReport:
    """Export, check with ``onnx.checker``, and compare onnxruntime with float32 PyTorch.

    Args:
        control_rate_hz: the rate (Hz) the actions are executed at, written into the metadata
            (required; a checkpoint carries its environment's as ``payload["control_rate_hz"]``).
        nfe, method, t_end, schedule, refine_dt: the solver unrolled in the graph, or
            ``solver``: a `SolverConfig` (then leave ``nfe`` unset).
        precision: one of `EXPORT_PRECISIONS` (see the module docstring).
        atol: parity limit in normalised action units (default: `PARITY_LIMITS[precision]`).
        calibration: ``int8`` only: batches of graph inputs (``(observation?, *images,
            prior_noise)``, raw units, as `InferenceGraph` takes them) whose activations set
            the quantisation ranges. Default: 32 batches of 8 windows drawn uniformly in the
            observation normaliser's range, with standard-normal prior noise.

    Raises:
        RuntimeError: when the max difference exceeds ``atol`` or a sphere component of an
            onnxruntime action is off the manifold by more than ``sphere_tol``. The file is
            written before the check so it can be inspected.
    """
    import tempfile

    import onnx
    import onnxruntime as ort

    if precision not in EXPORT_PRECISIONS:
        raise ValueError(f"precision must be one of {EXPORT_PRECISIONS}, got {precision!r}")
    atol = PARITY_LIMITS[precision] if atol is None else float(atol)
    model = unwrap_policy_model(model, "export_onnx").eval()
    solver = _solver(model, solver, nfe, method, t_end, schedule, refine_dt)
    graph = InferenceGraph(model, solver=solver).eval()
    exported = graph
    if precision == "fp16":
        half = copy.deepcopy(model).store_networks_in(torch.float16)
        exported = InferenceGraph(half, solver=solver).eval()
    metadata = onnx_metadata(graph, control_rate_hz)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    generator = torch.Generator().manual_seed(0)
    example = _example_inputs(graph, 2, generator)
    batch = torch.export.Dim("batch", min=1, max=4096)
    with torch.no_grad(), _quiet("onnx_ir", "onnxscript"):  # per-initializer info lines
        program = torch.onnx.export(
            exported,
            example,
            dynamo=True,
            opset_version=opset,
            input_names=graph.input_names,
            output_names=["action"],
            dynamic_shapes=(tuple({0: batch} for _ in example),),  # one entry: *inputs
            verbose=False,
        )
    proto = program.model_proto
    for tensor in [*proto.graph.input, *proto.graph.output]:
        first = tensor.type.tensor_type.shape.dim[0]
        if not first.dim_param:
            raise ValueError(
                f"{path}: the batch axis of {tensor.name!r} was specialised to {first.dim_value} "
                "during export (a model op depends on the batch size); it must stay dynamic"
            )

    def feed(inputs) -> dict[str, np.ndarray]:
        return {name: torch.as_tensor(t).numpy() for name, t in
                zip(graph.input_names, inputs, strict=True)}

    if precision.startswith("int8"):
        if precision == "int8" and calibration is None:
            calibration = [_example_inputs(graph, 8, generator) for _ in range(32)]
            metadata["calibration"] = "uniform in the observation normaliser's range (256 windows)"
        elif precision == "int8":
            calibration = list(calibration)
            windows = sum(len(inputs[0]) for inputs in calibration)
            metadata["calibration"] = f"given inputs ({windows} windows)"
        with tempfile.TemporaryDirectory(dir=path.parent, prefix=f".{path.stem}.") as work:
            proto = _quantize(proto, precision, Path(work),
                              [feed(inputs) for inputs in calibration or []])

    session = ort.InferenceSession(proto.SerializeToString(), providers=["CPUExecutionProvider"])
    worst = worst_raw = sphere = 0.0
    diffs = []
    scale = model.action_normalizer.scale.numpy()
    for b in (1, 3, 8, 64):
        inputs = _example_inputs(graph, b, generator)
        with torch.no_grad():
            expected = graph(*inputs).numpy()
        got = session.run(["action"], feed(inputs))[0]
        # Compared in normalised action units (Euclidean coordinates divided by their half-range,
        # sphere coordinates as they are), so the 1e-4 limit means the same for metres, pixels
        # or quaternions; float32 rounding alone exceeds 1e-4 in raw pixel units (Push-T: 0-512).
        diff = np.abs(got - expected) / scale
        diffs.append(diff.ravel())
        worst = max(worst, float(diff.max()))
        worst_raw = max(worst_raw, float(np.abs(got - expected).max()))
        sphere = max(sphere, _sphere_error(model.step_manifold, got))
    mean = float(np.concatenate(diffs).mean())
    metadata.update({
        "precision": precision,
        "parity_max_abs_diff": f"{worst:.3g}",
        "parity_mean_abs_diff": f"{mean:.3g}",
    })
    del proto.metadata_props[:]
    for key, value in metadata.items():
        entry = proto.metadata_props.add()
        entry.key, entry.value = key, value
    _save_atomic(proto, path)
    onnx.checker.check_model(str(path), full_check=True)

    one = _example_inputs(graph, 1, generator)
    onnx_ms, torch_ms = [], []
    for _ in range(latency_runs):
        start = time.perf_counter()
        session.run(["action"], feed(one))
        onnx_ms.append((time.perf_counter() - start) * 1e3)
        start = time.perf_counter()
        with torch.no_grad():
            graph(*one)
        torch_ms.append((time.perf_counter() - start) * 1e3)
    report = ExportReport(
        path, worst, sphere, worst_raw, statistics.median(onnx_ms), statistics.median(torch_ms),
        metadata, precision, mean, atol,
    )
    if worst > atol:
        raise RuntimeError(
            f"{path}: onnxruntime ({precision}) differs from PyTorch (float32) by {worst:.3g} > "
            f"{atol:g} (normalised action units)"
        )
    if sphere > sphere_tol:
        raise RuntimeError(
            f"{path}: a sphere component is off the manifold by {sphere:.3g} > {sphere_tol}"
        )
    return report
