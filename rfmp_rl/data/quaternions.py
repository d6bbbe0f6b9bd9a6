"""Quaternion signs in demonstration episodes: one rule for every reader.

A rotation is the pair of antipodal unit quaternions ``q`` and ``-q``. Recorders pick either,
sometimes switching mid-episode, sometimes recording a whole episode as ``-q`` while the others
are ``+q``; to a policy on S^3 both look like jumps of length pi. Every reader therefore applies
`canonicalize_episode_quaternions` to the quaternion fields it knows, and takes further fields
from the caller:

1. the episode's first sample is put in the ``w >= 0`` hemisphere (the whole episode is negated
   when its first ``w`` is negative);
2. every later sample is negated when its dot product with the (corrected) previous one is
   negative (`rfmp_rl.manifolds.quaternion.hemisphere_continuous`).

Values are not normalised (an observed quaternion keeps its norm); only signs change.
``raw=True`` (``--raw-quaternion-signs``) keeps the recorded signs; the manifest records that.

Fields the readers know: robomimic's observed ``obs/<name>_quat`` (and ``next_obs``) keys with 4
values per step, xyzw as robosuite writes them; ROS pose orientations, nested
(``<key>/orientation``) and inside flat vectors, xyzw as ROS writes them. Other fields are named
in a spec (``--quaternions`` on the command line)::

    KEY[COLUMNS][:ORDER], ...      e.g.  action[3:7],obs/eef_quat:wxyz

``KEY`` is a store key in the ``"a/b"`` form the manifest prints; ``[a:b]`` picks four columns of
its last axis (default: the whole field, which must have 4 values per step); ``ORDER`` is
``xyzw`` (default: ``w`` last, as ROS, robosuite and scipy write them and the S3 convention of
`rfmp_rl.manifolds`) or ``wxyz`` (``w`` first).

The manifest's ``extra["quaternions"]`` holds ``{"raw_signs": bool, "fields": [{"key",
"columns", "order", "w_index", "first_flipped", "continuity_flipped"}]}``: per field, how many
episodes were negated to put their first sample at ``w >= 0``, and how many had a sign switch
within the episode (with ``raw_signs`` the counts say how many episodes would have changed).

The rule itself is `canonical_quaternion_signs` (below), the one definition that the readers,
the recipes' observation vectors (`canonicalize_observation_quaternions`), the evaluation envs
(`rfmp_rl.envs.transforms.QuaternionSigns`) and the torch-free controller
(``rfmp_deploy.quaternions``, a numpy mirror checked against this one) all apply.
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import torch
from tensordict import TensorDict

from rfmp_rl.data.episodes import DataError, Manifest, key_name, parse_key

__all__ = ["QuaternionField", "parse_quaternion_fields", "canonicalize_episode_quaternions",
           "robomimic_quaternion_fields", "canonical_quaternion_signs", "ObservedQuaternion",
           "parse_observation_quaternions", "canonicalize_observation_quaternions"]

_SPEC_RE = re.compile(r"^(?P<key>[^\[\]:,]+?)(?:\[(?P<a>\d+):(?P<b>\d+)\])?(?::(?P<order>\w+))?$")
ORDERS = {"xyzw": -1, "wxyz": 0}


@dataclass(frozen=True)
class QuaternionField:
    """Four columns of an episode field that hold a quaternion.

    Attributes:
        key: the store key, ``"a/b"`` form.
        columns: ``(start, stop)`` on the field's last axis (``stop - start == 4``), or ``None``
            for the whole field (4 values per step).
        order: ``"xyzw"`` (``w`` last) or ``"wxyz"`` (``w`` first).

    Example:
        >>> QuaternionField("action", (3, 7)).spec, QuaternionField("obs/q", order="wxyz").w_index
        ('action[3:7]:xyzw', 0)
    """

    key: str
    columns: tuple[int, int] | None = None
    order: str = "xyzw"

    def __post_init__(self) -> None:
        if self.order not in ORDERS:
            raise DataError(f"quaternion order must be xyzw or wxyz, got {self.order!r}",
                            key=self.spec)
        if self.columns is not None and self.columns[1] - self.columns[0] != 4:
            raise DataError(f"a quaternion spans 4 columns, got [{self.columns[0]}:"
                            f"{self.columns[1]}]", key=self.spec)

    @property
    def w_index(self) -> int:
        """Position of ``w`` within the four columns: 3 (xyzw) or 0 (wxyz)."""
        return 3 if self.order == "xyzw" else 0

    @property
    def reference(self) -> tuple[float, ...]:
        """The identity rotation in this field's order: the first sample's hemisphere is
        ``w >= 0``."""
        return tuple(1.0 if i == self.w_index else 0.0 for i in range(4))

    @property
    def spec(self) -> str:
        cols = "" if self.columns is None else f"[{self.columns[0]}:{self.columns[1]}]"
        return f"{self.key}{cols}:{self.order}"


def parse_quaternion_fields(
    spec: str | Iterable[str | QuaternionField] | None,
) -> list[QuaternionField]:
    """Parse ``"KEY[a:b][:ORDER],..."`` (see the module docstring) into `QuaternionField` s.

    Raises:
        DataError: an entry that does not follow the syntax, naming it.

    Example:
        >>> [f.spec for f in parse_quaternion_fields("action[3:7],obs/eef_quat:wxyz")]
        ['action[3:7]:xyzw', 'obs/eef_quat:wxyz']
        >>> parse_quaternion_fields("action[3:6]")
        Traceback (most recent call last):
        ...
        rfmp_rl.data.episodes.DataError: key action[3:6]:xyzw: a quaternion spans 4 columns, got...
    """
    if spec is None:
        return []
    items = spec.split(",") if isinstance(spec, str) else list(spec)
    out = []
    for item in items:
        if isinstance(item, QuaternionField):
            out.append(item)
            continue
        text = item.strip()
        if not text:
            continue
        match = _SPEC_RE.match(text)
        if match is None or (match["order"] is not None and match["order"] not in ORDERS):
            raise DataError(f"quaternion field {text!r} is not KEY, KEY[a:b] or KEY[a:b]:ORDER "
                            "(ORDER xyzw or wxyz; e.g. action[3:7]:xyzw)")
        columns = (int(match["a"]), int(match["b"])) if match["a"] is not None else None
        key = key_name(parse_key(match["key"].strip()))
        out.append(QuaternionField(key, columns, match["order"] or "xyzw"))
    return out


def robomimic_quaternion_fields(episode: TensorDict) -> list[QuaternionField]:
    """The observed quaternions of a robomimic episode: ``obs`` / ``next_obs`` keys ending in
    ``quat`` with 4 values per step (robosuite's ``robot0_eef_quat``, xyzw).

    Example:
        >>> ep = TensorDict({"obs": {"robot0_eef_quat": torch.zeros(2, 4),
        ...                          "robot0_eef_pos": torch.zeros(2, 3)}}, [2])
        >>> [f.spec for f in robomimic_quaternion_fields(ep)]
        ['obs/robot0_eef_quat:xyzw']
    """
    out = []
    for group in ("obs", "next_obs"):
        sub = episode.get(group, None)
        if not isinstance(sub, TensorDict):
            continue
        for name, value in sub.items():
            if name.endswith("quat") and isinstance(value, torch.Tensor) \
                    and tuple(value.shape[1:]) == (4,) and value.is_floating_point():
                out.append(QuaternionField(f"{group}/{name}"))
    return out


def _columns(value: torch.Tensor, qf: QuaternionField, file: str, episode: Any) -> slice:
    width = value.shape[-1] if value.ndim >= 2 else 0
    if qf.columns is None:
        if value.ndim != 2 or width != 4:
            raise DataError(f"quaternion field needs 4 values per step, the field has per-step "
                            f"shape {list(value.shape[1:])} (name columns: KEY[a:b])",
                            file=file, key=qf.spec, episode=episode)
        return slice(0, 4)
    if value.ndim != 2 or qf.columns[1] > width:
        raise DataError(f"columns [{qf.columns[0]}:{qf.columns[1]}] are outside the field's "
                        f"per-step shape {list(value.shape[1:])}", file=file, key=qf.spec,
                        episode=episode)
    return slice(*qf.columns)


def canonicalize_episode_quaternions(
    episodes: Sequence[TensorDict],
    manifest: Manifest,
    fields: Sequence[QuaternionField],
    *,
    raw: bool = False,
    names: Sequence[Any] | None = None,
) -> None:
    """Make the quaternion signs of ``fields`` canonical in every episode (in place) and record
    what was done in ``manifest.extra["quaternions"]``.

    Args:
        episodes: episodes of batch ``[T]``.
        manifest: the reader's manifest (``source`` names the file in errors).
        fields: the quaternion fields; a field absent from every episode is an error.
        raw: keep the recorded signs (only the manifest entry is written).
        names: the episodes' names for error messages (default: ``manifest.episode_names``).

    Raises:
        DataError: a field missing from an episode (listing the episode's keys, ``"a/b"``
            form), not 4 values per step, or columns outside the field, or an integer field.

    Example:
        >>> q = torch.tensor([[0.0, 0.0, 0.6, -0.8], [0.0, 0.0, -0.6, 0.8]])
        >>> m = Manifest(source="d", format="toy")
        >>> eps = [TensorDict({"action": torch.cat([torch.zeros(2, 3), q], -1)}, [2])]
        >>> canonicalize_episode_quaternions(eps, m, parse_quaternion_fields("action[3:7]"))
        >>> eps[0]["action"][:, 5:].tolist()  # z, w of both steps: first step negated
        [[-0.6000000238418579, 0.800000011920929], [-0.6000000238418579, 0.800000011920929]]
        >>> m.extra["quaternions"]["fields"][0]["first_flipped"]
        1
    """
    names = list(manifest.episode_names if names is None else names)
    record: list[dict[str, Any]] = []
    for qf in fields:
        key = parse_key(qf.key)
        first_flipped = continuity_flipped = 0
        for i, ep in enumerate(episodes):
            name = names[i] if i < len(names) else i
            value = ep.get(key, None)
            if not isinstance(value, torch.Tensor):
                listed = ", ".join(key_name(k) for k in ep.keys(include_nested=True,
                                                                leaves_only=True))
                raise DataError(f"quaternion field not in the episode; its keys: {listed}",
                                file=manifest.source, key=qf.spec, episode=name)
            if not value.is_floating_point():
                raise DataError(f"quaternion field has dtype {value.dtype}, expected float",
                                file=manifest.source, key=qf.spec, episode=name)
            cols = _columns(value, qf, manifest.source, name)
            q = value[:, cols]
            cont = canonical_quaternion_signs(q, qf.reference)
            if len(q) and float((cont[0] * q[0]).sum()) < 0:
                first_flipped += 1
            signs = (cont * q).sum(-1) < 0  # steps whose sign differs from the recorded one
            if bool((signs != signs[0]).any()):
                continuity_flipped += 1
            if not raw:
                new = value.clone()
                new[:, cols] = cont
                ep.set(key, new)
        record.append({"key": qf.key, "columns": list(qf.columns) if qf.columns else None,
                       "order": qf.order, "w_index": qf.w_index,
                       "first_flipped": first_flipped, "continuity_flipped": continuity_flipped})
    manifest.extra["quaternions"] = {"raw_signs": bool(raw), "fields": record}


# ----- the sign rule ---------------------------------------------------------------------------
#: The identity rotation, ``xyzw``: the default reference (first samples at ``w >= 0``).
IDENTITY_XYZW = (0.0, 0.0, 0.0, 1.0)


def canonical_quaternion_signs(
    q: torch.Tensor,
    reference: torch.Tensor | Sequence[float] = IDENTITY_XYZW,
    *,
    previous: torch.Tensor | None = None,
    dim: int = -2,
) -> torch.Tensor:
    """The sign rule for a stream of quaternions: each sample takes the sign closest to the
    (canonical) sample before it; the first takes the reference's hemisphere.

    ``p_{-1} = reference`` (or ``previous``, the last canonical sample of the stream so far), and
    ``p_k = q_k`` if ``<q_k, p_{k-1}> >= 0`` else ``-q_k`` (a dot product of exactly 0 keeps the
    recorded sign). Only signs change, never norms.

    Why continuity and not a hemisphere: a quantity observed frame by frame crosses the boundary
    of any fixed hemisphere as it turns, and a hemisphere rule then negates it between two frames
    a hair apart in rotation, a jump of length 2 in the vector the policy reads. robosuite's
    Panda hand points down, a half-turn about x from the world frame: its quaternion is
    ``(+-1, 0, 0, w)`` with ``|w| < 0.015``, and ``w`` changes sign within most scripted Lift
    and Can episodes, so ``w >= 0`` would flip the observation back and forth, and split the
    episodes' starts between ``x = +1`` and ``x = -1``. With continuity consecutive samples stay
    within 90 degrees of each other on S^3 (180 degrees of rotation), always true at control
    rates. The first sample has no predecessor; it takes the hemisphere of ``reference``,
    which should sit where streams start (a robot's home orientation), so that the first
    sample is far from that hemisphere's boundary, a half-turn of rotation away. No rule can
    avoid a boundary everywhere (S^3 -> SO(3) has no continuous inverse): a stream that starts
    a half-turn from the reference gets a sign that varies between episodes.

    The rule is causal: sample k depends on samples 0..k only. A stream processed online with
    one quaternion of state (the last canonical sample, reset to the reference with the
    episode) therefore gets exactly what the whole recorded episode gets offline, which is
    what makes the training data, the evaluation env and a deployed controller agree.

    Args:
        q: quaternions along time, ``(..., T, 4)`` (time at ``dim``), in any component order.
        reference: ``(4,)`` or ``(..., 4)``, in the order of ``q``; only its hemisphere
            matters. Default: the identity ``xyzw`` (first samples at ``w >= 0``).
        previous: ``(..., 4)``, the last canonical sample of the stream; it takes the place of
            ``reference`` (to continue a stream in pieces).
        dim: the time dimension.

    Returns:
        The same rotations with canonical signs, shape and dtype of ``q``.

    Example:
        >>> hand = torch.tensor([[1.0, 0.0, 0.0, 0.01], [-1.0, 0.0, 0.0, 0.01],
        ...                      [1.0, 0.0, 0.0, -0.01]])  # xyzw, recorded with sign jumps
        >>> canonical_quaternion_signs(hand, (1.0, 0.0, 0.0, 0.0))[:, [0, 3]].tolist()
        [[1.0, 0.009999999776482582], [1.0, -0.009999999776482582], [1.0, -0.009999999776482582]]
        >>> canonical_quaternion_signs(-hand[:1], previous=hand[2])[:, 0].tolist()  # continued
        [1.0]
    """
    if q.shape[-1] != 4 or q.ndim < 2:
        raise ValueError(f"canonical_quaternion_signs: expected shape (..., T, 4), got "
                         f"{tuple(q.shape)}")
    q = q.movedim(dim, -2)  # (..., T, 4)
    if q.shape[-2] == 0:
        return q.movedim(-2, dim)
    start = reference if previous is None else previous
    start = torch.as_tensor(start, dtype=q.dtype, device=q.device)
    if start.shape[-1] != 4:
        raise ValueError(f"canonical_quaternion_signs: the reference/previous quaternion needs 4 "
                         f"values, got shape {tuple(start.shape)}")
    first = (q[..., 0, :] * start).sum(-1, keepdim=True)  # (..., 1)
    dots = torch.cat([first, (q[..., 1:, :] * q[..., :-1, :]).sum(-1)], dim=-1)  # (..., T)
    # s_k = s_{k-1} * sign(d_k), and s_k = +1 where d_k == 0 (k >= 1): a running product of
    # the raw signs, restarted at the zeros
    running = torch.cumprod(torch.where(dots < 0, -1.0, 1.0).to(q.dtype), dim=-1)
    steps = torch.arange(dots.shape[-1], device=q.device).expand_as(dots)
    restart = (dots == 0) & (steps > 0)
    last = torch.where(restart, steps, torch.zeros_like(steps)).cummax(dim=-1).values
    base = torch.where(last > 0, running.gather(-1, last), torch.ones_like(running))
    return (q * (running * base).unsqueeze(-1)).movedim(-2, dim)


@dataclass(frozen=True)
class ObservedQuaternion:
    """Four columns of an observation vector holding a quaternion, and the reference whose
    hemisphere a stream's first sample takes (`canonical_quaternion_signs`).

    ``to_dict`` is the form a `rfmp_rl.modules.ModelConfig` (``obs_quaternions``), a checkpoint
    and the ONNX metadata (``observation_quaternions``) store.

    Attributes:
        start: the first of the four columns.
        reference: four numbers in the columns' own order (only the hemisphere matters).

    Example:
        >>> ObservedQuaternion(3, (1.0, 0.0, 0.0, 0.0)).to_dict()
        {'columns': [3, 7], 'reference': [1.0, 0.0, 0.0, 0.0]}
    """

    start: int
    reference: tuple[float, float, float, float] = IDENTITY_XYZW

    @property
    def columns(self) -> slice:
        return slice(self.start, self.start + 4)

    def to_dict(self) -> dict[str, list]:
        return {"columns": [self.start, self.start + 4],
                "reference": [float(v) for v in self.reference]}


def parse_observation_quaternions(
    spec: Sequence[Mapping[str, Any] | ObservedQuaternion] | None,
    obs_dim: int | None = None,
) -> list[ObservedQuaternion]:
    """Validate ``[{"columns": [a, a + 4], "reference": [4 numbers]}, ...]`` (None: no
    quaternion is canonicalised, the raw observations of models trained before the rule).

    Raises:
        ValueError: naming the entry: columns that are not 4 wide, outside ``obs_dim`` or
            overlapping another entry's, a reference that is not 4 finite numbers of non-zero
            norm.

    Example:
        >>> [q.start for q in parse_observation_quaternions([{"columns": [3, 7],
        ...                                                   "reference": [1, 0, 0, 0]}], 9)]
        [3]
        >>> parse_observation_quaternions([{"columns": [6, 10], "reference": [0, 0, 0, 1]}], 9)
        Traceback (most recent call last):
        ...
        ValueError: obs_quaternions entry 0: columns [6, 10] are outside the observation's 9
    """
    out: list[ObservedQuaternion] = []
    for i, entry in enumerate(spec or []):
        if isinstance(entry, ObservedQuaternion):
            entry = entry.to_dict()
        where = f"obs_quaternions entry {i}"
        if not isinstance(entry, Mapping) or set(entry) != {"columns", "reference"}:
            raise ValueError(f"{where}: expected {{'columns': [a, a + 4], 'reference': [4 "
                             f"numbers]}}, got {entry!r}")
        cols, ref = entry["columns"], entry["reference"]
        ok = (isinstance(cols, Sequence) and len(cols) == 2
              and all(isinstance(c, int) and not isinstance(c, bool) for c in cols))
        if not ok or cols[0] < 0 or cols[1] - cols[0] != 4:
            raise ValueError(f"{where}: columns must be [a, a + 4] with a >= 0, got {cols!r}")
        if obs_dim is not None and cols[1] > obs_dim:
            raise ValueError(f"{where}: columns {list(cols)} are outside the observation's "
                             f"{obs_dim}")
        try:
            ref = tuple(float(v) for v in ref)
        except (TypeError, ValueError):
            ref = ()
        if len(ref) != 4 or not all(math.isfinite(v) for v in ref) or not any(ref):
            raise ValueError(f"{where}: reference must be 4 finite numbers, not all zero, got "
                             f"{entry['reference']!r}")
        for other in out:
            if cols[0] < other.start + 4 and other.start < cols[1]:
                raise ValueError(f"{where}: columns {list(cols)} overlap "
                                 f"{other.to_dict()['columns']}")
        out.append(ObservedQuaternion(int(cols[0]), ref))  # type: ignore[arg-type]
    return out


def canonicalize_observation_quaternions(
    observation: torch.Tensor,
    fields: Sequence[ObservedQuaternion],
    *,
    previous: Sequence[torch.Tensor] | None = None,
    dim: int = -2,
) -> torch.Tensor:
    """`canonical_quaternion_signs` on each field's columns of observation vectors along time.

    Args:
        observation: ``(..., T, D)`` one episode (or a batch of streams) along ``dim``.
        fields: the quaternion columns (`parse_observation_quaternions`).
        previous: per field, ``(..., 4)`` the last canonical sample (to continue streams).
        dim: the time dimension.

    Returns:
        A copy of ``observation`` with canonical signs in the fields' columns.

    Example:
        >>> obs = torch.tensor([[0.5, -1.0, 0.0, 0.0, 0.01], [0.25, 1.0, 0.0, 0.0, 0.01]])
        >>> hand = [ObservedQuaternion(1, (1.0, 0.0, 0.0, 0.0))]
        >>> canonicalize_observation_quaternions(obs, hand)[:, :2].tolist()
        [[0.5, 1.0], [0.25, 1.0]]
    """
    out = observation.movedim(dim, -2).clone()
    for i, f in enumerate(fields):
        prev = None if previous is None else previous[i]
        out[..., f.columns] = canonical_quaternion_signs(out[..., f.columns], f.reference,
                                                         previous=prev)
    return out.movedim(-2, dim)
