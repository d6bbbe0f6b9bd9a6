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
"""

from __future__ import annotations

import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import torch
from tensordict import TensorDict

from rfmp_rl.data.episodes import DataError, Manifest, key_name, parse_key
from rfmp_rl.manifolds.quaternion import hemisphere_continuous

__all__ = ["QuaternionField", "parse_quaternion_fields", "canonicalize_episode_quaternions",
           "robomimic_quaternion_fields"]

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
            cont = hemisphere_continuous(q, dim=-2)
            if cont[0, qf.w_index] < 0:
                cont = -cont
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
