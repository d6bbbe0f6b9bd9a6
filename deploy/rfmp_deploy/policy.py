"""An exported policy: one onnxruntime session plus its validated ``rfmp_rl.onnx/1`` metadata."""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import onnxruntime as ort

from rfmp_deploy.metadata import FORMAT, WINDOW, InputSpec, PolicyMeta, parse_metadata

__all__ = ["Policy"]

_ORT_TYPES = {"tensor(float)": "float32", "tensor(uint8)": "uint8"}


def _check_dims(path: str, what: str, key: str, declared: Sequence[Any], expected: Sequence[int],
                graph_type: str, dtype: str) -> None:
    """Compare a graph input/output with the metadata: the batch dimension must be dynamic;
    other dims must equal the metadata's where the graph fixes them (symbolic dims match)."""
    if _ORT_TYPES.get(graph_type) != dtype:
        raise ValueError(f"{path}: metadata key '{key}': {what} is {graph_type} in the graph, "
                         f"the metadata says {dtype}")
    if declared and isinstance(declared[0], int):
        raise ValueError(f"{path}: {what} has a fixed batch size {declared[0]} in the graph; "
                         f"{FORMAT} needs a dynamic batch dimension (re-export with a dynamic "
                         f"batch axis on every input and on 'action')")
    if len(declared) != 1 + len(expected):
        raise ValueError(f"{path}: metadata key '{key}': {what} has shape {list(declared)} in the "
                         f"graph, the metadata says [B, {', '.join(map(str, expected))}]")
    for axis, (got, want) in enumerate(zip(declared[1:], expected, strict=True), start=1):
        if isinstance(got, int) and got != want:
            raise ValueError(f"{path}: metadata key '{key}': {what} has size {got} on axis "
                             f"{axis} in the graph, the metadata says {want}")


class Policy:
    """A ``rfmp_rl.onnx/1`` policy: ``(observation window, camera windows, noise) -> chunk``.

    Loading validates the metadata and checks it against the inputs and output the graph
    declares, so a mismatched file fails here and not on the robot's first step. Calling runs
    one batch and checks every array's shape and dtype first.

    Args:
        path: the ``.onnx`` file written by ``export/to_onnx.py``.
        providers: onnxruntime execution providers, in order of preference.
        intra_op_threads: threads onnxruntime may use inside an operator (``None``: its
            default, all cores). On a robot PC shared with drivers, 1-2 is usually right.

    Attributes:
        path: the model file.
        meta: the parsed `PolicyMeta`.
        session: the onnxruntime ``InferenceSession``.

    Raises:
        FileNotFoundError: when ``path`` does not exist.
        ValueError: naming the file (and the metadata key) when onnxruntime cannot load it, the
            format is not ``rfmp_rl.onnx/1``, a metadata key is missing or malformed, or the
            metadata disagrees with the graph's declared inputs/output.

    Example:
        >>> policy = Policy("policy.onnx")
        >>> policy.meta.horizon, policy.meta.action_dim
        (16, 8)
        >>> inputs = policy.random_inputs(batch=3, rng=np.random.default_rng(0))
        >>> sorted(inputs)
        ['images', 'noise', 'observation']
        >>> policy(**inputs).shape
        (3, 16, 8)
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        providers: Sequence[str] = ("CPUExecutionProvider",),
        intra_op_threads: int | None = None,
    ) -> None:
        self.path = Path(path)
        if not self.path.is_file():
            raise FileNotFoundError(f"{self.path}: no such model file")
        options = ort.SessionOptions()
        if intra_op_threads is not None:
            options.intra_op_num_threads = int(intra_op_threads)
        options.inter_op_num_threads = 1
        try:
            self.session = ort.InferenceSession(
                str(self.path), sess_options=options, providers=list(providers)
            )
        except Exception as e:
            raise ValueError(f"{self.path}: onnxruntime cannot load the model: {e}") from e
        props = dict(self.session.get_modelmeta().custom_metadata_map)
        self.meta: PolicyMeta = parse_metadata(props, str(self.path))
        self._check_graph()

    def _check_graph(self) -> None:
        path, meta = str(self.path), self.meta
        graph = {i.name: i for i in self.session.get_inputs()}
        declared = [s.name for s in meta.inputs]
        missing = [n for n in declared if n not in graph]
        extra = [n for n in graph if n not in declared]
        if missing or extra:
            raise ValueError(
                f"{path}: metadata key 'inputs': declares {declared}, the graph's inputs are "
                f"{list(graph)} (missing from the graph: {missing}; not in the metadata: {extra})"
            )
        for spec in meta.inputs:
            node = graph[spec.name]
            _check_dims(path, f"input '{spec.name}'", "inputs", node.shape, spec.shape,
                        node.type, spec.dtype)
        outputs = {o.name: o for o in self.session.get_outputs()}
        if "action" not in outputs:
            raise ValueError(f"{path}: the graph has no 'action' output (outputs: "
                             f"{list(outputs)})")
        node = outputs["action"]
        dims = list(node.shape)
        horizon_ok = len(dims) == 3 and (not isinstance(dims[1], int) or dims[1] == meta.horizon)
        key = "action_manifold" if horizon_ok else "horizon"
        _check_dims(path, "output 'action'", key, node.shape, (meta.horizon, meta.action_dim),
                    node.type, "float32")

    @property
    def providers(self) -> list[str]:
        """The execution providers onnxruntime actually uses."""
        return self.session.get_providers()

    def __repr__(self) -> str:
        return (f"Policy({str(self.path)!r}, {self.meta.algorithm}, NFE {self.meta.nfe}, "
                f"actions {self.meta.action_space})")

    def _check(self, spec: InputSpec, value: Any, batch: int) -> np.ndarray:
        expected = (batch, *spec.shape)
        if not isinstance(value, np.ndarray):
            raise ValueError(f"input '{spec.name}': expected a numpy array {spec.dtype} "
                             f"{list(expected)}, got {type(value).__name__}")
        if value.dtype != spec.np_dtype:
            raise ValueError(f"input '{spec.name}': expected dtype {spec.dtype}, got {value.dtype}")
        if value.shape != expected:
            raise ValueError(f"input '{spec.name}': expected shape {list(expected)}, "
                             f"got {list(value.shape)}")
        return value

    def __call__(
        self,
        observation: np.ndarray | None,
        images: Mapping[str, np.ndarray],
        noise: np.ndarray,
    ) -> np.ndarray:
        """Run one batch.

        Args:
            observation: ``(B, 2, D_obs)`` float32, the window ``[context, latest]`` (the
                context is the oldest of the last ``meta.obs_horizon`` observations); ``None``
                when the model has no low-dimensional input.
            images: camera name -> ``(B, 2, C, H, W)`` uint8 RGB (context frame first), at
                the model's ``image_size``.
            noise: ``(B, noise_dim)`` float32 standard normal draws; zeros give the
                deterministic mode.

        Returns:
            ``(B, T_p, D)`` float32 action chunk in raw action units.

        Raises:
            ValueError: when an input is missing, unexpected, or has the wrong shape or dtype.
        """
        meta = self.meta
        if not isinstance(noise, np.ndarray) or noise.ndim != 2 or noise.shape[0] < 1:
            raise ValueError(f"input '{meta.noise_input.name}': expected a (B, {meta.noise_dim}) "
                             f"float32 array")
        batch = noise.shape[0]
        feeds = {meta.noise_input.name: self._check(meta.noise_input, noise, batch)}
        lowdim = meta.lowdim_input
        if lowdim is None:
            if observation is not None:
                raise ValueError("this model has no low-dimensional observation input; pass None")
        else:
            if observation is None:
                raise ValueError(f"input '{lowdim.name}' is required: "
                                 f"(B, {WINDOW}, {meta.obs_dim}) float32")
            feeds[lowdim.name] = self._check(lowdim, observation, batch)
        unknown = sorted(set(images) - set(meta.cameras))
        if unknown:
            raise ValueError(f"unknown camera(s) {unknown}; the model's cameras are "
                             f"{list(meta.cameras)}")
        for spec in meta.image_inputs:
            if spec.name not in images:
                raise ValueError(f"camera input '{spec.name}' is missing")
            feeds[spec.name] = self._check(spec, images[spec.name], batch)
        action = self.session.run(["action"], feeds)[0]
        expected = (batch, meta.horizon, meta.action_dim)
        if action.shape != expected or action.dtype != np.float32:
            raise ValueError(f"{self.path}: the graph returned {action.dtype} {list(action.shape)}"
                             f", expected float32 {list(expected)}")
        return action

    def random_inputs(
        self, batch: int = 1, rng: np.random.Generator | None = None
    ) -> dict[str, Any]:
        """Valid random inputs (standard normal observation and noise, random pixels).

        Returns:
            keyword arguments for ``__call__``: ``observation``, ``images``, ``noise``.
        """
        rng = np.random.default_rng() if rng is None else rng
        meta = self.meta
        observation = None
        if meta.lowdim_input is not None:
            observation = rng.standard_normal((batch, *meta.lowdim_input.shape), np.float32)
        images = {
            s.name: rng.integers(0, 256, (batch, *s.shape), dtype=np.uint8)
            for s in meta.image_inputs
        }
        noise = rng.standard_normal((batch, meta.noise_dim), np.float32)
        return {"observation": observation, "images": images, "noise": noise}
