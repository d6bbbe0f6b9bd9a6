"""The paper's figures that the recipes' tables and ``results/paper_comparison.md`` set beside
ours, each under the caption of the paper table it comes from (Braun et al., "Riemannian Flow
Matching Policies" / "SRFMP", the version in ``shared/paper``).

Figures are keyed by ``(NFE, T)``: the number of function evaluations and the integration end
time the paper states for them (T = 1 wherever it states none). A paper table whose rows carry
a spread (mean ± std over its seeds) keeps it in `PaperTable.spread`.

Example::

    from recipes import paper

    paper.PUSHT_NFE.figure("srfmp", 1, 1.0)        # 0.875
    paper.pusht_euclidean("rfmp")[(4, 1.6)]         # 0.191 (integration-time table)
    paper.ROBOMIMIC_STATE.cell("NutAssemblySquare/rfmp", 3, 1.0)  # '0.920 ± 0.018'
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

__all__ = [
    "PaperTable", "PUSHT_NFE", "PUSHT_TIME", "SPHERE_PRIORS", "ROBOMIMIC_STATE",
    "ROBOMIMIC_VISION", "KITCHEN", "TRAIN_TIME", "TRAIN_TIME_TABLE", "EFFICIENCY_FIGURE",
    "EFFICIENCY_CLAIMS", "FIFTY_EPOCH_ROWS", "ORIENTATION_CLAIM", "REAL_ROBOT_CLAIM",
    "RFMP_BEYOND_T1_FIGURE", "RFMP_BEYOND_T1_CLAIM", "LASA_FLOWS_FIGURE", "LASA_FLOWS_CLAIM",
    "TABLES", "pusht_euclidean", "pusht_sphere", "robomimic_state",
]

Setting = tuple[int, float]


@dataclass(frozen=True)
class PaperTable:
    """One table of the paper.

    Args:
        caption: the paper's caption (how the reports name the table).
        label: its LaTeX label.
        observations: what the paper's policies observe in it ("images", "state").
        rows: ``{row key: {(NFE, T): figure}}``.
        spread: ``{row key: {(NFE, T): std}}`` where the paper gives mean ± std.

    Example:
        >>> t = PaperTable("A", "table:a", "state", {"x": {(1, 1.0): 0.5}}, {"x": {(1, 1.0): 0.1}})
        >>> t.cell("x", 1, 1.0), t.cell("x", 3, 1.0)
        ('0.500 ± 0.100', '-')
    """

    caption: str
    label: str
    observations: str
    rows: dict[str, dict[Setting, float]]
    spread: dict[str, dict[Setting, float]] = field(default_factory=dict)

    def figure(self, row: str, nfe: int, t_end: float) -> float | None:
        """The paper's figure at (NFE, T), or None where it reports none."""
        if row not in self.rows:
            raise KeyError(f"paper table {self.caption!r} has no row {row!r} "
                           f"(rows: {', '.join(self.rows)})")
        for (n, t), value in self.rows[row].items():
            if n == int(nfe) and math.isclose(t, float(t_end)):
                return value
        return None

    def cell(self, row: str, nfe: int, t_end: float) -> str:
        """The figure as the paper prints it (``mean ± std`` where it gives the spread);
        ``-`` where it reports none."""
        value = self.figure(row, nfe, t_end)
        if value is None:
            return "-"
        std = next((s for (n, t), s in self.spread.get(row, {}).items()
                    if n == int(nfe) and math.isclose(t, float(t_end))), None)
        return f"{value:.3f}" + ("" if std is None else f" ± {std:.3f}")


def _at_t1(nfes: tuple[int, ...], values: tuple[float, ...]) -> dict[Setting, float]:
    return {(n, 1.0): v for n, v in zip(nfes, values, strict=True)}


_NFE4 = (1, 3, 5, 10)
_NFE5 = (1, 2, 3, 5, 10)

#: Euclidean Push-T from images: score (mean max coverage, 50 seeds) against NFE at T = 1.
PUSHT_NFE = PaperTable(
    "Euclidean Push-T: Impact of NFE on policies", "table:ODEstep euclidean pusht", "images", {
        "rfmp": _at_t1(_NFE4, (0.848, 0.855, 0.923, 0.891)),
        "srfmp": _at_t1(_NFE4, (0.875, 0.851, 0.837, 0.856)),
        "ddim": _at_t1(_NFE4, (0.109, 0.79, 0.838, 0.862)),
    })

#: Push-T and Sphere Push-T from images at NFE 3 (T 1 and 1.2) and NFE 4 (T 1.6), as its text
#: states. Its SRFMP Euclidean figure at NFE 3, T 1 (0.862) differs from the NFE table's (0.851).
PUSHT_TIME = PaperTable(
    "Influence of Integration Time on RFMP and SRFMP", "table:time boudary influence", "images", {
        "euclidean/rfmp": {(3, 1.0): 0.855, (3, 1.2): 0.492, (4, 1.6): 0.191},
        "euclidean/srfmp": {(3, 1.0): 0.862, (3, 1.2): 0.851, (4, 1.6): 0.829},
        "sphere/rfmp": {(3, 1.0): 0.736, (3, 1.2): 0.574, (4, 1.6): 0.264},
        "sphere/srfmp": {(3, 1.0): 0.727, (3, 1.2): 0.736, (4, 1.6): 0.685},
    })

#: Sphere Push-T from images: score against NFE at T = 1 by algorithm and prior. ``uniform``:
#: the spherical uniform; ``wrapped``: the wrapped Gaussian; ``euclidean``: DP's Euclidean
#: Gaussian with its actions projected onto the sphere afterwards (our DDIM's sphere setting).
SPHERE_PRIORS = PaperTable(
    "Impact of the prior distribution on Sphere Push-T Task", "table:sphere pusht", "images", {
        "rfmp/uniform": _at_t1(_NFE4, (0.871, 0.746, 0.77, 0.817)),
        "rfmp/wrapped": _at_t1(_NFE4, (0.587, 0.724, 0.748, 0.733)),
        "srfmp/uniform": _at_t1(_NFE4, (0.772, 0.736, 0.796, 0.829)),
        "srfmp/wrapped": _at_t1(_NFE4, (0.707, 0.706, 0.735, 0.707)),
        "ddim/uniform": _at_t1(_NFE4, (0.274, 0.261, 0.235, 0.197)),
        "ddim/wrapped": _at_t1(_NFE4, (0.170, 0.162, 0.231, 0.227)),
        "ddim/euclidean": _at_t1(_NFE4, (0.227, 0.796, 0.813, 0.885)),
    })

_STATE = {  # (task, algo): (means, stds) at NFE 1, 2, 3, 5, 10
    ("Lift", "rfmp"): ((0.992, 0.992, 0.992, 0.992, 0.992), (0.010,) * 5),
    ("Lift", "srfmp"): ((1.000, 0.992, 0.992, 0.996, 1.000), (0.000, 0.010, 0.010, 0.008, 0.000)),
    ("Lift", "ddim"): ((0.008, 0.756, 0.948, 0.956, 0.976), (0.010, 0.034, 0.016, 0.015, 0.015)),
    ("PickPlaceCan", "rfmp"): ((0.976, 0.996, 0.996, 0.996, 0.996),
                               (0.023, 0.008, 0.008, 0.008, 0.008)),
    ("PickPlaceCan", "srfmp"): ((0.980, 0.980, 0.996, 0.992, 0.968),
                                (0.022, 0.013, 0.008, 0.010, 0.020)),
    ("PickPlaceCan", "ddim"): ((0.004, 0.340, 0.836, 0.924, 0.908),
                               (0.008, 0.013, 0.020, 0.015, 0.010)),
    ("NutAssemblySquare", "rfmp"): ((0.792, 0.848, 0.920, 0.896, 0.912),
                                    (0.027, 0.020, 0.018, 0.041, 0.016)),
    ("NutAssemblySquare", "srfmp"): ((0.776, 0.800, 0.828, 0.824, 0.848),
                                     (0.029, 0.052, 0.016, 0.008, 0.030)),
    ("NutAssemblySquare", "ddim"): ((0.012, 0.384, 0.628, 0.672, 0.684),
                                    (0.010, 0.023, 0.016, 0.020, 0.015)),
    ("ToolHang", "rfmp"): ((0.152, 0.316, 0.368, 0.572, 0.716),
                           (0.020, 0.023, 0.032, 0.027, 0.023)),
    ("ToolHang", "srfmp"): ((0.240, 0.224, 0.308, 0.516, 0.568),
                            (0.028, 0.020, 0.020, 0.023, 0.035)),
    ("ToolHang", "ddim"): ((0.000, 0.008, 0.008, 0.092, 0.092),
                           (0.000, 0.010, 0.010, 0.024, 0.016)),
}

#: robomimic with state observations (proficient-human demonstrations): success rate, mean ±
#: std, against NFE at T = 1; rows ``<robosuite task>/<algo>``. The paper's 50-epoch flows
#: (Tool Hang: 100) against DP trained 300 epochs. It gives no state-based Transport figures.
ROBOMIMIC_STATE = PaperTable(
    "Success rate as a function of different NFE values on the state-based Robomimic tasks",
    "table:robomimic", "state",
    {f"{task}/{algo}": _at_t1(_NFE5, means) for (task, algo), (means, _) in _STATE.items()},
    {f"{task}/{algo}": _at_t1(_NFE5, stds) for (task, algo), (_, stds) in _STATE.items()})

_VISION = {  # (task, algo): success at NFE 1, 2, 3, 5, 10
    ("Lift", "rfmp"): (1, 1, 1, 1, 1), ("Lift", "srfmp"): (1, 1, 1, 1, 1),
    ("Lift", "ddim"): (0, 0.7, 0.96, 0.98, 0.98), ("Lift", "cp"): (0.5, 0.44, 0.46, 0.46, 0.4),
    ("PickPlaceCan", "rfmp"): (0.78, 0.82, 0.9, 0.96, 0.94),
    ("PickPlaceCan", "srfmp"): (0.88, 0.88, 0.9, 0.9, 0.86),
    ("PickPlaceCan", "ddim"): (0, 0.38, 0.66, 0.68, 0.66),
    ("PickPlaceCan", "cp"): (0.82, 0.82, 0.84, 0.84, 0.82),
    ("NutAssemblySquare", "rfmp"): (0.56, 0.74, 0.9, 0.9, 0.9),
    ("NutAssemblySquare", "srfmp"): (0.86, 0.82, 0.9, 0.88, 0.9),
    ("NutAssemblySquare", "ddim"): (0, 0.04, 0.16, 0.26, 0.12),
    ("NutAssemblySquare", "cp"): (0.32, 0.52, 0.54, 0.48, 0.52),
    ("TwoArmTransport", "rfmp"): (0.6, 0.82, 0.78, 0.78, 0.8),
    ("TwoArmTransport", "srfmp"): (0.8, 0.82, 0.82, 0.78, 0.78),
    ("TwoArmTransport", "ddim"): (0, 0.54, 0.66, 0.78, 0.82),
    ("TwoArmTransport", "cp"): (0.4, 0.36, 0.44, 0.38, 0.36),
}

#: robomimic from images (one over-the-shoulder and one in-hand camera; Transport four):
#: success rate against NFE at T = 1, including the Consistency Policy baseline (``cp``).
ROBOMIMIC_VISION = PaperTable(
    "Success rate as a function of NFE on vision-based robomimic tasks", "table:robomimic vision",
    "images", {f"{task}/{algo}": _at_t1(_NFE5, tuple(float(v) for v in values))
               for (task, algo), values in _VISION.items()})

#: Franka Kitchen (end-effector pose actions on R^3 x S^3 x R^2): success against NFE at T = 1.
KITCHEN = PaperTable(
    "Success rate as a function of NFE on the Franka kitchen benchmark", "table:kitchen_reward",
    "state", {"rfmp": _at_t1(_NFE5, (0.04, 0.08, 0.12, 0.14, 0.14)),
              "srfmp": _at_t1(_NFE5, (1.0, 1.0, 1.0, 1.0, 1.0)),
              "ddim": _at_t1(_NFE5, (0.0, 0.0, 0.0, 0.02, 0.02))})

#: Training time per epoch on robomimic from images (seconds, mean ± std; an NVIDIA RTX 4060 Ti,
#: one batch size for all): ``{(task, algo): (mean, std)}``. CP's epoch includes the frozen
#: teacher's forward passes, not the teacher's own training.
TRAIN_TIME_TABLE = ("Training time (in seconds) per epoch on Robomimic vision-based Lift and "
                    "Square", "table:train time")
TRAIN_TIME = {
    ("Lift", "rfmp"): (17.49, 0.03), ("Lift", "srfmp"): (17.63, 0.15),
    ("Lift", "ddim"): (16.07, 0.20), ("Lift", "cp"): (31.44, 0.27),
    ("NutAssemblySquare", "rfmp"): (57.62, 0.30), ("NutAssemblySquare", "srfmp"): (56.67, 0.18),
    ("NutAssemblySquare", "ddim"): (53.16, 0.16), ("NutAssemblySquare", "cp"): (102.86, 0.61),
}

#: The training-efficiency figure (state observations, success every 10 epochs to 50 at NFE 3
#: for Lift, Can, Square; mean and std): it prints curves, no numbers.
EFFICIENCY_FIGURE = ("Success rate (mean and standard deviation) on Robomimic tasks with "
                     "state-based observations at different checkpoints",
                     "fig:robomimic epoch influence")
#: The tasks of that figure.
EFFICIENCY_TASKS = ("Lift", "PickPlaceCan", "NutAssemblySquare")
#: What its text reads off the curves, by (task, algo).
EFFICIENCY_CLAIMS = {
    **{(task, algo): "high success after 20 epochs"
       for task in ("Lift", "PickPlaceCan") for algo in ("rfmp", "srfmp")},
    **{(task, "ddim"): "success still low after 50 epochs" for task in ("Lift", "PickPlaceCan")},
    **{("NutAssemblySquare", algo): "high success significantly faster than DP"
       for algo in ("rfmp", "srfmp")},
    ("NutAssemblySquare", "ddim"): "slower to reach high success than RFMP / SRFMP",
}
#: The ``(task, algo)`` rows of ROBOMIMIC_STATE that are the paper's 50-epoch models, the last
#: point of its training-efficiency curves; its DP rows are trained 300 epochs, its Tool Hang
#: flows 100.
FIFTY_EPOCH_ROWS = frozenset((task, algo) for task in EFFICIENCY_TASKS
                             for algo in ("rfmp", "srfmp"))

#: The paper's case for the Riemannian orientation: no simulated figure; its real-robot tasks
#: and its summary ("unit-norm normalization as a post-processing step for quaternions would
#: break the stability guarantees in SRFMP").
ORIENTATION_CLAIM = ("it gives no simulated figure; it argues from its real-robot tasks (Pick & "
                     "Place, Mug flipping; plotted, not tabulated) and from SRFMP's stability "
                     "guarantee, which post-hoc quaternion normalisation breaks")

#: The real-robot tasks (Pick & Place, Mug flipping): success and jerk against NFE in a figure
#: ("Success rate and predicted actions jerkiness as a function of NFE"), no numbers printed.
REAL_ROBOT_CLAIM = ("its figure prints no numbers; its text: RFMP and SRFMP \"display high "
                    "performance with only 2 NFE\" on Pick & Place, \"DP requires more NFEs to "
                    "achieve a success rate competitive to RFMP and SRFMP\" and is \"highly "
                    "jerky\" at 2 NFE; on Mug flipping both flows are \"significantly more "
                    "robust to different NFE in terms of success rate when compared to DP\"")

#: RFMP integrated past t = 1 (Euclidean Push-T and robomimic Square): the paper plots curves in a
#: figure and gives no table (caption, label).
RFMP_BEYOND_T1_FIGURE = ("RFMP performance when extending inference time beyond t=1 on the "
                         "Euclidean PushT and Robomimic Square tasks", "figure:rfmp_beyond_t1")
#: What its text (Sec. "Stable Riemannian Flow Matching Policy") reads off that figure.
RFMP_BEYOND_T1_CLAIM = (f"it gives no table; its figure \"{RFMP_BEYOND_T1_FIGURE[0]}\" plots "
                        "curves without numbers, and its text reads: RFMP \"performance improves "
                        "when the ODE integration horizon slightly exceeds t=1, but it worsens and "
                        "eventually gets unstable when integrating for longer time horizons\"")

#: The flows of RFM and SRFM on the L-shape LASA data projected on S^2 at t = 0, 1, 1.5 (the
#: quickstart's setting): a figure without numbers (caption, label).
LASA_FLOWS_FIGURE = ("Flows of the RFM (top) and SRFM (bottom) trained on the L-shape LASA dataset "
                     "projected on the sphere manifold", "fig:lasaRfmSrfm")
#: What its text says of that figure.
LASA_FLOWS_CLAIM = (f"its figure \"{LASA_FLOWS_FIGURE[0]}\" plots the flows at t = 0, 1, 1.5 "
                    "without numbers; its text: \"The RFM flow diverges from the target "
                    "distribution at time t>1, while the SRFM flow is stable and adheres to the "
                    "target distribution for t >= 1\"")

#: Every table above by a short name (the manifest of ``recipes/paper_comparison.py`` refers to
#: them by it).
TABLES = {"pusht_nfe": PUSHT_NFE, "pusht_time": PUSHT_TIME, "sphere_priors": SPHERE_PRIORS,
          "robomimic_state": ROBOMIMIC_STATE, "robomimic_vision": ROBOMIMIC_VISION,
          "kitchen": KITCHEN}


def pusht_euclidean(algo: str) -> dict[Setting, float]:
    """The paper's Euclidean Push-T figures of ``algo`` at every (NFE, T) it reports: the NFE
    table at T = 1, then the integration-time table at NFE 3, T 1.2 and NFE 4, T 1.6 (at NFE 3,
    T 1 the NFE table's figure). ``{}`` for an algorithm the paper does not report."""
    out = dict(PUSHT_NFE.rows.get(algo, {}))
    for setting, value in PUSHT_TIME.rows.get(f"euclidean/{algo}", {}).items():
        out.setdefault(setting, value)
    return out


def pusht_sphere(algo: str, prior: str) -> dict[Setting, float]:
    """The paper's Sphere Push-T figures of ``algo`` with the sphere prior ``prior`` (``uniform``
    | ``wrapped``; DDIM: DP's Euclidean Gaussian projected onto the sphere, whatever ``prior``):
    its prior table at T = 1, then its integration-time table, which states no prior, at NFE 3,
    T 1.2 and NFE 4, T 1.6. ``{}`` for an algorithm the paper does not report.

    Example:
        >>> pusht_sphere("srfmp", "uniform")[(1, 1.0)], pusht_sphere("srfmp", "wrapped")[(4, 1.6)]
        (0.772, 0.685)
    """
    key = "ddim/euclidean" if algo == "ddim" else f"{algo}/{prior}"
    out = dict(SPHERE_PRIORS.rows.get(key, {}))
    for setting, value in PUSHT_TIME.rows.get(f"sphere/{algo}", {}).items():
        out.setdefault(setting, value)
    return out


def robomimic_state(task: str, algo: str) -> dict[Setting, float]:
    """The paper's state-based robomimic success rates of ``algo`` on ``task`` (a robosuite task
    name) at every NFE, T = 1; ``{}`` where it reports none."""
    return dict(ROBOMIMIC_STATE.rows.get(f"{task}/{algo}", {}))
