"""The ``rfmp_rl.onnx/1`` metadata contract: parsing and validation of ``metadata_props``.

The exporter (``export/to_onnx.py``) writes every fact the robot needs into the ONNX file's
``metadata_props`` (string values; JSON where structured). `parse_metadata` turns them into a
`PolicyMeta`; every problem is a ``ValueError`` that names the file and the key.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from rfmp_deploy.spaces import ActionSpace

__all__ = [
    "FORMAT",
    "InputSpec",
    "ObservationField",
    "ObservedQuaternion",
    "PolicyMeta",
    "example_metadata",
    "parse_metadata",
]

FORMAT = "rfmp_rl.onnx/1"
#: Observations per graph input window: ``[o^c, o^{s-1}]``, the context then the latest. The
#: controller keeps the last ``obs_horizon`` (T_o) observations and feeds the oldest as the
#: context (``c = s - T_o``; the graph holds the matching gap ``s - c = T_o`` when T_o > 2).
WINDOW = 2
#: T_o of models whose metadata has no ``obs_horizon`` (the window [previous, latest]).
DEFAULT_OBS_HORIZON = 2

REQUIRED_KEYS = (
    "rfmp_rl.format",
    "rfmp_rl.version",
    "algorithm",
    "nfe",
    "method",
    "t_end",
    "schedule",
    "horizon",
    "action_steps",
    "control_rate_hz",
    "inputs",
    "observation_keys",
    "action_manifold",
    "action_low",
    "action_high",
    "noise",
)

#: Optional keys: T_o (default `DEFAULT_OBS_HORIZON`), the network's precision in the graph
#: (default fp32), how far the exported graph was measured from the float32 PyTorch policy
#: (normalised action units) and the observed quaternions whose signs the controller makes
#: canonical (default none: the observation is fed as given, what models exported before the
#: key read).
PRECISIONS = ("fp32", "fp16", "int8", "int8-dynamic")
OPTIONAL_KEYS = ("obs_horizon", "precision", "parity_max_abs_diff", "observation_quaternions")

_DTYPES = {"float32": np.dtype(np.float32), "uint8": np.dtype(np.uint8)}
#: Plausibility bounds: metadata outside them is refused at load (a typo, not a robot).
RATE_RANGE_HZ = (0.1, 2000.0)
MAX_HORIZON = 1024
MAX_OBS_HORIZON = 1024  # observations the controller keeps (camera frames included)

_KIND_DTYPE = {"lowdim": "float32", "image": "uint8", "noise": "float32"}


@dataclass(frozen=True)
class InputSpec:
    """One graph input as the metadata declares it.

    Attributes:
        name: graph input name (a camera's name for images).
        shape: shape without the batch dimension: ``(T_o, D_obs)``, ``(T_o, C, H, W)`` or
            ``(noise_dim,)``.
        dtype: ``"float32"`` or ``"uint8"``.
        kind: ``"lowdim"``, ``"image"`` or ``"noise"``.
        image_size: ``(H, W)`` the graph expects (images only); frames are resized to it.
        crop: ``(h, w)`` of the centre crop done inside the graph (images only; informational).

    Example:
        >>> wrist = parse_metadata(example_metadata()).image_inputs[0]
        >>> wrist.name, wrist.shape, wrist.image_size, wrist.crop
        ('wrist', (2, 3, 84, 84), (84, 84), (76, 76))
    """

    name: str
    shape: tuple[int, ...]
    dtype: str
    kind: str
    image_size: tuple[int, int] | None = None
    crop: tuple[int, int] | None = None

    @property
    def np_dtype(self) -> np.dtype:
        return _DTYPES[self.dtype]


@dataclass(frozen=True)
class ObservationField:
    """A named low-dimensional sensor reading; fields concatenate, in order, into ``observation``.

    Attributes:
        key: the name the robot uses in its observation dict (e.g. ``"eef_pos"``).
        dim: number of coordinates.

    Example:
        >>> parse_metadata(example_metadata()).observation_keys[0]
        ObservationField(key='eef_pos', dim=3)
    """

    key: str
    dim: int


@dataclass(frozen=True)
class ObservedQuaternion:
    """Four columns of the ``observation`` vector holding a quaternion whose sign the controller
    makes canonical (`rfmp_deploy.observation.canonical_quaternion_signs`): continuity from frame
    to frame, the first frame after `Controller.reset` in the hemisphere of ``reference``.

    Attributes:
        start: the first of the four columns.
        reference: four numbers in the columns' order.

    Example:
        >>> meta = parse_metadata({**example_metadata(), "observation_quaternions":
        ...     '[{"columns": [3, 7], "reference": [1, 0, 0, 0]}]'})
        >>> meta.observation_quaternions
        (ObservedQuaternion(start=3, reference=(1.0, 0.0, 0.0, 0.0)),)
    """

    start: int
    reference: tuple[float, float, float, float]

    @property
    def columns(self) -> slice:
        return slice(self.start, self.start + 4)


@dataclass(frozen=True, eq=False)
class PolicyMeta:
    """Everything the controller knows about a policy, read from its ONNX metadata.

    Attributes:
        path: the model file (for messages).
        version: ``rfmp_rl.version`` of the exporting library.
        algorithm: ``rfmp``, ``srfmp`` or ``ddim``.
        nfe: number of function evaluations unrolled in the graph.
        method: ODE solver (``euler``, ``midpoint``, ...).
        t_end: integration end time.
        schedule: solver step schedule.
        obs_horizon: T_o, the observations the controller keeps; the graph's window is the
            oldest and the latest of them, ``[o^(s-T_o), o^(s-1)]`` (``[previous, latest]`` for
            T_o = 2). Models whose metadata has no ``obs_horizon`` have T_o = 2.
        horizon: T_p, actions per predicted chunk.
        action_steps: T_a, actions executed per chunk.
        control_rate_hz: the rate the policy was trained at.
        inputs: graph inputs in metadata order.
        observation_keys: low-dim fields concatenated into the ``observation`` input.
        action_space: the action manifold with its limits.
        noise_dim: size of the ``prior_noise`` input.
        noise_default: ``"standard_normal"`` (sample) or ``"zeros"`` (deterministic mode).
        precision: the networks' precision in the graph (``fp32``, ``fp16``, ``int8``,
            ``int8-dynamic``); inputs and output are float32 in every case.
        parity_max_abs_diff: max |graph - float32 PyTorch| measured at export (normalised action
            units), or None when the exporter did not record it.
        observation_quaternions: the quaternion columns of ``observation`` made canonical
            (empty: the observation is fed as given).
        extra: metadata keys outside the contract, verbatim.

    Example:
        >>> meta = parse_metadata(example_metadata(), "policy.onnx")
        >>> meta.horizon, meta.action_steps, meta.obs_dim, meta.cameras
        (16, 8, 8, ('wrist',))
        >>> str(meta.action_space)
        'R3 x S3 x R1'
    """

    path: str
    version: str
    algorithm: str
    nfe: int
    method: str
    t_end: float
    schedule: str
    obs_horizon: int
    horizon: int
    action_steps: int
    control_rate_hz: float
    inputs: tuple[InputSpec, ...]
    observation_keys: tuple[ObservationField, ...]
    action_space: ActionSpace
    noise_dim: int
    noise_default: str
    precision: str = "fp32"
    parity_max_abs_diff: float | None = None
    observation_quaternions: tuple[ObservedQuaternion, ...] = ()
    extra: dict[str, str] = field(default_factory=dict)

    @property
    def obs_dim(self) -> int:
        """D_obs, the width of the ``observation`` input (0 when there is none)."""
        return sum(f.dim for f in self.observation_keys)

    @property
    def action_dim(self) -> int:
        return self.action_space.dim

    @property
    def lowdim_input(self) -> InputSpec | None:
        return next((s for s in self.inputs if s.kind == "lowdim"), None)

    @property
    def image_inputs(self) -> tuple[InputSpec, ...]:
        return tuple(s for s in self.inputs if s.kind == "image")

    @property
    def cameras(self) -> tuple[str, ...]:
        return tuple(s.name for s in self.image_inputs)

    @property
    def noise_input(self) -> InputSpec:
        return next(s for s in self.inputs if s.kind == "noise")

    @property
    def period(self) -> float:
        """The control period in seconds, ``1 / control_rate_hz``."""
        return 1.0 / self.control_rate_hz

    def summary(self) -> str:
        """A human-readable multi-line description."""
        lines = [
            f"model:        {self.path}",
            f"format:       {FORMAT} (rfmp_rl {self.version})",
            f"algorithm:    {self.algorithm}, NFE {self.nfe}, {self.method}, "
            f"t_end {self.t_end:g}, schedule {self.schedule}",
            f"horizons:     T_o={self.obs_horizon}, T_p={self.horizon}, T_a={self.action_steps}"
            f" at {self.control_rate_hz:g} Hz",
        ]
        fields = ", ".join(f"{f.key}[{f.dim}]" for f in self.observation_keys) or "(none)"
        lines.append(f"observation:  {fields} -> D_obs={self.obs_dim}")
        for s in self.image_inputs:
            c, h, w = s.shape[1:]
            crop = f", centre crop {s.crop[0]}x{s.crop[1]} in the graph" if s.crop else ""
            lines.append(f"camera:       {s.name}: RGB uint8, resized to {h}x{w} (C={c}){crop}")
        low, high = self.action_space.low, self.action_space.high
        lines.append(f"action:       {self.action_space} (D={self.action_dim})")
        lines.append(f"  low:        {np.array2string(low, precision=4, separator=', ')}")
        lines.append(f"  high:       {np.array2string(high, precision=4, separator=', ')}")
        lines.append(f"noise:        standard normal, dim {self.noise_dim}, "
                     f"default {self.noise_default}")
        parity = ("" if self.parity_max_abs_diff is None else
                  f" (max |graph - float32 policy| {self.parity_max_abs_diff:.3g} in normalised "
                  "action units at export)")
        lines.append(f"precision:    {self.precision}{parity}")
        if self.observation_quaternions:
            quats = ", ".join(f"[{q.start}:{q.start + 4}] from {list(q.reference)}"
                              for q in self.observation_quaternions)
            lines.append(f"quaternions:  observation {quats}: signs continuous, each stream "
                         f"starting in its reference's hemisphere")
        return "\n".join(lines)


class _Reader:
    """Parses one key at a time; errors name the file and the key."""

    def __init__(self, props: dict[str, str], path: str) -> None:
        self.props = props
        self.path = path

    def error(self, key: str, message: str) -> ValueError:
        return ValueError(f"{self.path}: metadata key '{key}': {message}")

    def raw(self, key: str) -> str:
        if key not in self.props:
            raise ValueError(
                f"{self.path}: metadata key '{key}' is missing (an rfmp_rl.onnx/1 model carries "
                f"{', '.join(REQUIRED_KEYS)})"
            )
        value = self.props[key]
        if not isinstance(value, str):
            raise self.error(key, f"expected a string value, got {type(value).__name__}")
        return value

    def text(self, key: str) -> str:
        value = self.raw(key).strip()
        if not value:
            raise self.error(key, "is empty")
        return value

    def integer(self, key: str, minimum: int) -> int:
        value = self.raw(key)
        try:
            out = int(value.strip())
        except ValueError:
            raise self.error(key, f"expected an integer, got {value!r}") from None
        if out < minimum:
            raise self.error(key, f"must be >= {minimum}, got {out}")
        return out

    def number(self, key: str, positive: bool = False) -> float:
        value = self.raw(key)
        try:
            out = float(value.strip())
        except ValueError:
            raise self.error(key, f"expected a number, got {value!r}") from None
        if not math.isfinite(out) or (positive and out <= 0):
            raise self.error(key, f"expected a finite{' positive' if positive else ''} number, "
                                  f"got {value!r}")
        return out

    def json(self, key: str) -> Any:
        value = self.raw(key)
        try:
            return json.loads(value)
        except json.JSONDecodeError as e:
            raise self.error(key, f"is not valid JSON ({e}): {value[:200]!r}") from None


def _int_list(value: Any, length: int | None = None) -> tuple[int, ...] | None:
    if not isinstance(value, list) or (length is not None and len(value) != length):
        return None
    if not all(isinstance(v, int) and not isinstance(v, bool) and v >= 1 for v in value):
        return None
    return tuple(value)


def _input_spec(r: _Reader, entry: Any, i: int) -> InputSpec:
    where = f"entry {i}"
    if not isinstance(entry, dict):
        raise r.error("inputs", f"{where} must be an object, got {entry!r}")
    for k in ("name", "shape", "dtype", "kind"):
        if k not in entry:
            raise r.error("inputs", f"{where} has no '{k}': {entry!r}")
    name, kind, dtype = entry["name"], entry["kind"], entry["dtype"]
    if not isinstance(name, str) or not name:
        raise r.error("inputs", f"{where}: 'name' must be a non-empty string, got {name!r}")
    where = f"input '{name}'"
    if kind not in _KIND_DTYPE:
        raise r.error("inputs", f"{where}: unknown kind {kind!r} (lowdim, image or noise)")
    if dtype != _KIND_DTYPE[kind]:
        raise r.error("inputs", f"{where}: a {kind} input must be {_KIND_DTYPE[kind]}, "
                                f"got {dtype!r}")
    rank = {"lowdim": 2, "image": 4, "noise": 1}[kind]
    shape = _int_list(entry["shape"], rank)
    if shape is None:
        raise r.error("inputs", f"{where}: 'shape' must be {rank} positive integers (without "
                                f"the batch dimension), got {entry['shape']!r}")
    image_size = crop = None
    if kind == "image":
        image_size = _int_list(entry.get("image_size"), 2)
        if image_size is None:
            raise r.error("inputs", f"{where}: 'image_size' must be [H, W], "
                                    f"got {entry.get('image_size')!r}")
        if image_size != shape[2:]:
            raise r.error("inputs", f"{where}: image_size {list(image_size)} differs from the "
                                    f"shape's H, W {list(shape[2:])}")
        if shape[1] not in (1, 3):
            raise r.error("inputs", f"{where}: expected 1 or 3 channels, got {shape[1]}")
        if "crop" in entry and entry["crop"] is not None:
            crop = _int_list(entry["crop"], 2)
            if crop is None:
                raise r.error("inputs", f"{where}: 'crop' must be [h, w], got {entry['crop']!r}")
    return InputSpec(name, shape, dtype, kind, image_size, crop)


def _observation_quaternions(r: _Reader, obs_dim: int) -> tuple[ObservedQuaternion, ...]:
    key = "observation_quaternions"
    if key not in r.props:
        return ()
    entries = r.json(key)
    if not isinstance(entries, list):
        raise r.error(key, f"expected a JSON list, got {entries!r}")
    out: list[ObservedQuaternion] = []
    for i, e in enumerate(entries):
        shape = "{'columns': [a, a + 4], 'reference': [4 numbers]}"
        if not isinstance(e, dict) or set(e) != {"columns", "reference"}:
            raise r.error(key, f"entry {i} must be {shape}, got {e!r}")
        cols, ref = e["columns"], e["reference"]
        if (not isinstance(cols, list) or len(cols) != 2 or not all(
                isinstance(c, int) and not isinstance(c, bool) for c in cols)
                or cols[0] < 0 or cols[1] - cols[0] != 4):
            raise r.error(key, f"entry {i}: columns must be [a, a + 4], got {cols!r}")
        if cols[1] > obs_dim:
            raise r.error(key, f"entry {i}: columns {cols} are outside the observation's "
                               f"D_obs={obs_dim}")
        numbers = isinstance(ref, list) and len(ref) == 4 and all(
            isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)
            for v in ref)
        if not numbers or not any(ref):
            raise r.error(key, f"entry {i}: reference must be 4 finite numbers, not all zero, "
                               f"got {ref!r}")
        for other in out:
            if cols[0] < other.start + 4 and other.start < cols[1]:
                raise r.error(key, f"entry {i}: columns {cols} overlap "
                                   f"[{other.start}, {other.start + 4}]")
        out.append(ObservedQuaternion(cols[0], tuple(float(v) for v in ref)))
    return tuple(out)


def parse_metadata(props: dict[str, str], path: str = "<model>") -> PolicyMeta:
    """Parse and validate ``rfmp_rl.onnx/1`` metadata (graph-independent checks).

    Args:
        props: ``metadata_props`` as a dict of strings (onnxruntime's
            ``session.get_modelmeta().custom_metadata_map``).
        path: the model file, used in error messages.

    Raises:
        ValueError: naming ``path`` and the offending key, when the format is not
            ``rfmp_rl.onnx/1``, a key is missing, a value is malformed or values disagree with
            each other (e.g. ``observation_keys`` dims vs the ``observation`` input's shape).
    """
    r = _Reader(props, path)
    fmt = r.raw("rfmp_rl.format")
    if fmt != FORMAT:
        raise ValueError(
            f"{path}: metadata key 'rfmp_rl.format' is {fmt!r}; this controller reads {FORMAT!r} "
            f"only (re-export the policy with a matching rfmp_rl, or use a matching rfmp_deploy)"
        )
    obs_horizon = DEFAULT_OBS_HORIZON
    if "obs_horizon" in props:
        obs_horizon = r.integer("obs_horizon", WINDOW)
        if obs_horizon > MAX_OBS_HORIZON:
            raise r.error("obs_horizon", f"T_o={obs_horizon} is implausible (at most "
                                         f"{MAX_OBS_HORIZON} observations kept)")
    horizon = r.integer("horizon", 1)
    action_steps = r.integer("action_steps", 1)
    if action_steps > horizon:
        raise r.error("action_steps", f"T_a={action_steps} exceeds the horizon T_p={horizon}")
    if horizon > MAX_HORIZON:
        raise r.error("horizon", f"T_p={horizon} is implausible (at most {MAX_HORIZON} actions "
                                 f"per chunk)")
    control_rate_hz = r.number("control_rate_hz", positive=True)
    if not RATE_RANGE_HZ[0] <= control_rate_hz <= RATE_RANGE_HZ[1]:
        raise r.error("control_rate_hz", f"{control_rate_hz:g} Hz is implausible for a robot "
                                         f"controller (expected {RATE_RANGE_HZ[0]:g}-"
                                         f"{RATE_RANGE_HZ[1]:g} Hz)")

    raw_inputs = r.json("inputs")
    if not isinstance(raw_inputs, list) or not raw_inputs:
        raise r.error("inputs", f"expected a non-empty JSON list, got {raw_inputs!r}")
    inputs = tuple(_input_spec(r, e, i) for i, e in enumerate(raw_inputs))
    names = [s.name for s in inputs]
    if len(set(names)) != len(names):
        raise r.error("inputs", f"duplicate input names {names}")
    kinds = [s.kind for s in inputs]
    if kinds.count("noise") != 1:
        raise r.error("inputs", f"expected exactly one 'noise' input, got {kinds.count('noise')}")
    if kinds.count("lowdim") > 1:
        raise r.error("inputs", "expected at most one 'lowdim' input")
    for s in inputs:
        if s.kind in ("lowdim", "image") and s.shape[0] != WINDOW:
            raise r.error("inputs", f"input '{s.name}' has a window of {s.shape[0]} "
                                    f"observations, expected {WINDOW} ([context, latest])")

    raw_keys = r.json("observation_keys")
    if not isinstance(raw_keys, list):
        raise r.error("observation_keys", f"expected a JSON list, got {raw_keys!r}")
    fields = []
    for i, e in enumerate(raw_keys):
        ok = isinstance(e, dict) and isinstance(e.get("key"), str) and e["key"]
        ok = ok and isinstance(e.get("dim"), int) and not isinstance(e["dim"], bool)
        if not ok or e["dim"] < 1:
            raise r.error("observation_keys", f"entry {i} must be {{'key': str, 'dim': int >= 1}}"
                                              f", got {e!r}")
        fields.append(ObservationField(e["key"], e["dim"]))
    keys = [f.key for f in fields]
    if len(set(keys)) != len(keys):
        raise r.error("observation_keys", f"duplicate keys {keys}")
    lowdim = next((s for s in inputs if s.kind == "lowdim"), None)
    obs_dim = sum(f.dim for f in fields)
    if lowdim is None and fields:
        raise r.error("observation_keys", f"lists {keys} but 'inputs' has no lowdim input")
    if lowdim is not None and lowdim.shape[1] != obs_dim:
        raise r.error("observation_keys", f"dims sum to {obs_dim}, the '{lowdim.name}' input "
                                          f"has D_obs={lowdim.shape[1]}")
    clash = sorted(set(keys) & {s.name for s in inputs if s.kind == "image"})
    if clash:
        raise r.error("observation_keys", f"{clash} are also camera names")

    spec = r.json("action_manifold")
    low, high = r.json("action_low"), r.json("action_high")
    try:
        space = ActionSpace(spec, low, high)
    except ValueError as e:
        key = "action_manifold"
        if "action_low" in str(e):
            key = "action_low"
        elif "action_high" in str(e):
            key = "action_high"
        raise r.error(key, str(e)) from None
    for seg in space.spheres:  # unit vectors span [-1, 1] in every coordinate
        if (space.low[seg.slice] > -1).any() or (space.high[seg.slice] < 1).any():
            raise r.error("action_low", f"limits on the {seg} component at {seg.start}:{seg.stop}"
                          f" ([{space.low[seg.slice].tolist()}, {space.high[seg.slice].tolist()}])"
                          f" are not enforced on a sphere: give -1 and 1 (or null) there")

    noise = r.json("noise")
    if not isinstance(noise, dict):
        raise r.error("noise", f"expected a JSON object, got {noise!r}")
    if noise.get("distribution") != "standard_normal":
        raise r.error("noise", f"distribution {noise.get('distribution')!r} is not supported "
                               f"(standard_normal)")
    noise_dim = noise.get("dim")
    noise_spec = next(s for s in inputs if s.kind == "noise")
    if not isinstance(noise_dim, int) or isinstance(noise_dim, bool) or noise_dim < 1:
        raise r.error("noise", f"'dim' must be an integer >= 1, got {noise_dim!r}")
    if noise_spec.shape != (noise_dim,):
        raise r.error("noise", f"dim {noise_dim} differs from the '{noise_spec.name}' input's "
                               f"shape {list(noise_spec.shape)}")
    default = noise.get("default", "standard_normal")
    if default not in ("standard_normal", "zeros"):
        raise r.error("noise", f"'default' must be 'standard_normal' or 'zeros', got {default!r}")

    precision = props.get("precision", "fp32")
    if precision not in PRECISIONS:
        raise r.error("precision", f"must be one of {', '.join(PRECISIONS)}, got {precision!r}")
    parity = r.number("parity_max_abs_diff") if "parity_max_abs_diff" in props else None
    if parity is not None and parity < 0:
        raise r.error("parity_max_abs_diff", f"must be >= 0, got {parity!r}")

    quaternions = _observation_quaternions(r, obs_dim)

    return PolicyMeta(
        path=path,
        version=r.text("rfmp_rl.version"),
        algorithm=r.text("algorithm"),
        nfe=r.integer("nfe", 1),
        method=r.text("method"),
        t_end=r.number("t_end", positive=True),
        schedule=r.text("schedule"),
        obs_horizon=obs_horizon,
        horizon=horizon,
        action_steps=action_steps,
        control_rate_hz=control_rate_hz,
        inputs=inputs,
        observation_keys=tuple(fields),
        action_space=space,
        noise_dim=noise_dim,
        noise_default=default,
        precision=precision,
        parity_max_abs_diff=parity,
        observation_quaternions=quaternions,
        extra={k: v for k, v in props.items() if k not in REQUIRED_KEYS + OPTIONAL_KEYS},
    )


def example_metadata() -> dict[str, str]:
    """Metadata of a typical arm policy: R^3 x S^3 x R^1 actions, a wrist camera (for examples).

    Example:
        >>> example_metadata()["rfmp_rl.format"]
        'rfmp_rl.onnx/1'
    """
    manifold = {"type": "product", "components": [
        {"type": "euclidean", "dim": 3}, {"type": "sphere", "n": 3}, {"type": "euclidean", "dim": 1}
    ]}
    return {
        "rfmp_rl.format": FORMAT,
        "rfmp_rl.version": "0.1.0",
        "algorithm": "srfmp",
        "nfe": "1",
        "method": "euler",
        "t_end": "1.0",
        "schedule": "srfmp",
        "obs_horizon": "2",
        "horizon": "16",
        "action_steps": "8",
        "control_rate_hz": "10.0",
        "inputs": json.dumps([
            {"name": "observation", "shape": [2, 8], "dtype": "float32", "kind": "lowdim"},
            {"name": "wrist", "shape": [2, 3, 84, 84], "dtype": "uint8", "kind": "image",
             "image_size": [84, 84], "crop": [76, 76]},
            {"name": "prior_noise", "shape": [8], "dtype": "float32", "kind": "noise"},
        ]),
        "observation_keys": json.dumps([{"key": "eef_pos", "dim": 3},
                                        {"key": "eef_quat", "dim": 4},
                                        {"key": "gripper", "dim": 1}]),
        "action_manifold": json.dumps(manifold),
        "action_low": json.dumps([-0.5, -0.5, 0.0, -1, -1, -1, -1, 0.0]),
        "action_high": json.dumps([0.5, 0.5, 0.6, 1, 1, 1, 1, 0.08]),
        "noise": json.dumps({"distribution": "standard_normal", "dim": 8,
                             "default": "standard_normal"}),
    }
