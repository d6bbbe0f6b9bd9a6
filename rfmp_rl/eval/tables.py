"""Result tables and plots of an evaluation sweep (rows from `rfmp_rl.eval.sweep`).

`write_tables` writes ``<name>.md`` and ``<name>.csv``: the command that regenerates them on the
first line, then one row per (NFE, T) setting naming the NFE, the end time asked for and the time
the solver actually reached (SRFMP at NFE 1 stops at ``1 / lambda_x``). Figures the paper reports
get a ``paper`` column beside them, from a mapping ``{(NFE, T): value}``. `plot_sweep` draws a
figure against NFE (one line per T) and against T (one line per NFE).

Example::

    columns = [Column("score", "score (max coverage)", paper=True), Column("success", "success",
               "{:.2f}")]
    write_tables(rows, out, title="Push-T state", command="python recipes/pusht/eval.py ...",
                 columns=columns, labels=["algo"], paper={(1, 1.0): 0.875})
    plot_sweep(rows, out / "eval.png", "score", ylabel="mean max coverage", ylim=(0, 1))
"""

from __future__ import annotations

import csv
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

__all__ = ["Column", "write_tables", "read_table", "plot_sweep", "setting_label"]

Paper = Mapping[tuple[int, float], float]


@dataclass(frozen=True)
class Column:
    """One figure of the markdown table.

    Args:
        key: the row's field.
        header: the column's header.
        fmt: a format string for the value, or ``fmt(row) -> str``; NaN prints as ``-``.
        paper: the paper reports this figure (a ``paper`` column follows it when paper values
            are given).

    Example:
        >>> Column("success", "success", "{:.2f}").cell({"success": 0.5})
        '0.50'
    """

    key: str
    header: str
    fmt: str | Callable[[Mapping[str, Any]], str] = "{:.3f}"
    paper: bool = False

    def cell(self, row: Mapping[str, Any]) -> str:
        if callable(self.fmt):
            return self.fmt(row)
        value = row[self.key]
        if isinstance(value, float) and math.isnan(value):
            return "-"
        return self.fmt.format(value)


def setting_label(row: Mapping[str, Any]) -> str:
    """``NFE n, T reached`` (and the T asked for when the solver stopped elsewhere).

    Example:
        >>> setting_label({"nfe": 1, "t_end": 1.0, "t_reached": 0.4})
        'NFE 1, T 0.40 (asked 1)'
    """
    text = f"NFE {row['nfe']}, T {row['t_reached']:.2f}"
    if not math.isclose(float(row["t_reached"]), float(row["t_end"]), abs_tol=1e-6):
        text += f" (asked {row['t_end']:g})"
    return text


def _paper_value(paper: Paper | None, row: Mapping[str, Any]) -> float | None:
    if not paper:
        return None
    for (nfe, t_end), value in paper.items():
        if int(nfe) == int(row["nfe"]) and math.isclose(float(t_end), float(row["t_end"])):
            return float(value)
    return None


def _paper_cell(*values: float | None) -> str:
    """The paper's figures for one setting, ``-`` when it gives none; two tables that disagree
    both (``0.851 / 0.862``)."""
    texts = list(dict.fromkeys(f"{v:.3f}" for v in values if v is not None))
    return " / ".join(texts) or "-"


def _fields(rows: Sequence[Mapping[str, Any]], columns: Sequence[Column], paper: Paper | None
            ) -> list[str]:
    fields = [k for k in rows[0] if k != "per_seed"]
    if paper:
        after = next(c.key for c in columns if c.paper)
        fields.insert(fields.index(after) + 1, "paper")
    return fields


def write_tables(rows: Sequence[Mapping[str, Any]], out_dir: str | Path, *, title: str,
                 command: str, columns: Sequence[Column], labels: Sequence[str] = (),
                 paper: Paper | None = None, time_table: Sequence[Sequence] = (),
                 time_paper: Paper | None = None, notes: Sequence[str] = (),
                 name: str = "eval") -> Path:
    """Write ``<name>.md`` and ``<name>.csv`` into ``out_dir``; returns the markdown's path.

    Args:
        rows: the sweep's rows (`rfmp_rl.eval.sweep`): ``nfe``, ``t_end``, ``t_reached``, the
            figures; ``per_seed`` is left out.
        out_dir: created when missing.
        title: the table's heading.
        command: the command line that regenerates the files (their first line).
        columns: the figures shown in the markdown table (the CSV has every field).
        labels: row fields shown before NFE / T (e.g. ``["algo"]``).
        paper: the paper's figure per setting ``{(NFE, T): value}`` for the column marked
            ``paper=True``; settings the paper does not report show ``-``.
        time_table: ``[NFE, T]`` pairs shown again side by side (the paper's integration-time
            table), each cell naming its NFE and reached T.
        time_paper: the paper's integration-time table's own figures ``{(NFE, T): value}``;
            where one differs from ``paper``'s at the same setting, the side-by-side paper row
            gives both (``paper`` first: ``0.851 / 0.862``).
        notes: lines printed under the table.
        name: the files' stem.
    """
    if not rows:
        raise ValueError("write_tables: no rows to write")
    if paper and not any(c.paper for c in columns):
        raise ValueError("write_tables: paper figures given but no column is marked paper=True")
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    fields = _fields(rows, columns, paper)
    with open(out_dir / f"{name}.csv", "w", newline="") as f:
        f.write(f"# {command}\n")
        writer = csv.DictWriter(f, fieldnames=fields, extrasaction="ignore")
        writer.writeheader()
        for row in rows:
            value = _paper_value(paper, row)
            writer.writerow({**row, **({"paper": "" if value is None else value}
                                       if paper else {})})

    headers = [*labels, "NFE", "T", "T reached"]
    for c in columns:
        headers += [c.header] + (["paper"] if paper and c.paper else [])
    lines = [f"Command: `{command}`", "", f"## {title}", "",
             "| " + " | ".join(headers) + " |", "|" + "---|" * len(headers)]
    for row in rows:
        cells = [str(row[k]) for k in labels]
        cells += [str(row["nfe"]), f"{row['t_end']:g}", f"{row['t_reached']:.2f}"]
        for c in columns:
            cells.append(c.cell(row))
            if paper and c.paper:
                value = _paper_value(paper, row)
                cells.append("-" if value is None else f"{value:.3f}")
        lines.append("| " + " | ".join(cells) + " |")
    if notes:
        lines += ["", *notes]
    main = next((c for c in columns if c.paper), columns[0])
    pairs = [(int(n), float(t)) for n, t in (time_table or [])]
    chosen = [r for p in pairs for r in rows if (int(r["nfe"]), float(r["t_end"])) == p]
    if chosen:
        label = " ".join(str(chosen[0][k]) for k in labels) or "measured"
        lines += ["", f"Integration time ({main.header} at each NFE and reached end time T)", "",
                  "| | " + " | ".join(setting_label(r) for r in chosen) + " |",
                  "|---|" + "---|" * len(chosen),
                  f"| {label} | " + " | ".join(main.cell(r) for r in chosen) + " |"]
        reported = [_paper_cell(_paper_value(paper, r), _paper_value(time_paper, r))
                    for r in chosen]
        if any(v != "-" for v in reported):
            lines.append("| paper | " + " | ".join(reported) + " |")
    path = out_dir / f"{name}.md"
    path.write_text("\n".join(lines) + "\n")
    return path


def read_table(path: str | Path) -> list[dict[str, str]]:
    """The rows of a CSV written by `write_tables` (its command line skipped)."""
    with open(path, newline="") as f:
        lines = [line for line in f if not line.startswith("#")]
    return list(csv.DictReader(lines))


def plot_sweep(rows: Sequence[Mapping[str, Any]], path: str | Path, key: str, *,
               ylabel: str | None = None, title: str = "",
               ylim: tuple[float, float] | None = None) -> Path:
    """``key`` against NFE (one line per end time T asked for) and against the reached end time
    (one line per NFE), saved as a PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(9, 3.5))
    for t_end in sorted({float(r["t_end"]) for r in rows}):
        sel = sorted((r for r in rows if float(r["t_end"]) == t_end), key=lambda r: r["nfe"])
        axes[0].plot([r["nfe"] for r in sel], [r[key] for r in sel], "o-", label=f"T={t_end:g}")
    axes[0].set(xlabel="NFE", ylabel=ylabel or key, title=f"{key} vs NFE", ylim=ylim)
    axes[0].legend()
    for nfe in sorted({int(r["nfe"]) for r in rows}):
        sel = sorted((r for r in rows if int(r["nfe"]) == nfe), key=lambda r: r["t_reached"])
        axes[1].plot([r["t_reached"] for r in sel], [r[key] for r in sel], "o-",
                     label=f"NFE={nfe}")
    axes[1].set(xlabel="end time T reached", title=f"{key} vs T", ylim=ylim)
    axes[1].legend()
    fig.suptitle(title)
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path
