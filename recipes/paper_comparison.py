"""The paper's claims beside ours, one table each, read from the run folders: writes
``results/paper_comparison.md``.

    python recipes/paper_comparison.py --record --out results/paper_comparison.md
    python recipes/paper_comparison.py --manifest my_runs.yaml --root /data/rfmp_rl
    python recipes/paper_comparison.py --todo > todo.sh   # the runs still missing, a job a line
    bash todo.sh                                            # ... one after another

``recipes/paper_comparison.yaml`` (the manifest) names every group of training runs (folder per
training seed, training command) and every table: Push-T NFE sweep, integration time, Sphere
Push-T priors, robomimic NFE sweep, training efficiency, Consistency Policy, training time per
epoch, orientation geometry. Each table row is one policy at one NFE and end time T; its columns
are the paper's figure (`recipes.paper`), ours with the paper's training settings and ours tuned.

What is read (run folders relative to ``--root``, default the repository root):

- ``<run>/eval/eval.csv``: written by ``train.py``'s final evaluation or ``eval.py``
  (`rfmp_rl.eval.write_tables`: ``nfe``, ``t_end``, ``t_reached`` and the recipe's figure, Push-T
  ``score``, robosuite and Franka Kitchen ``success``; its first line is the command that wrote it).
- ``<run>/efficiency.csv``: success of per-epoch snapshots (columns ``task``, ``algo``, ``seed``,
  ``epoch``, ``nfe``, ``success``; ``t_reached`` when recorded).
- ``<run>.cmd`` beside the folder, else ``<run>/command.txt`` (which ``train.py`` writes): the
  training command that made it (the manifest's otherwise).
- the epoch-time benchmark's markdown (``results/epoch_time.md``).

Run folders hold checkpoints and stay out of git; their evaluation tables and commands are small.
``--record`` copies them, with each run's ``config.yaml``, into ``results/records/<folder>/...``
(the folder's path under ``--records``), and a folder that is absent is read from its record
there, so the report can be regenerated from a clone that has none of the runs. A record may
carry a second comment line ``# transcribed from <file> ...``: its figures were copied from
committed results text because the run folder itself was not kept; the report names that source
beside the run.

Several training seeds of one row give their mean and sample standard deviation. A run folder
that does not exist reads ``not run``, one without its evaluation ``no evaluation yet``: no cell
holds a figure that no run produced.
"""

from __future__ import annotations

import argparse
import math
import os
import re
import shutil
import statistics
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import yaml

from recipes import paper
from recipes.common import COMMAND_FILE, RECORDS, ROOT
from rfmp_rl.eval import read_table

MANIFEST = Path(__file__).with_name("paper_comparison.yaml")
TRANSCRIBED = "transcribed from "
#: The figure each recipe's eval.csv reports for the paper's metric.
METRICS = {"pusht": "score", "robosuite": "success", "kitchen": "success"}
EFFICIENCY_COLUMNS = ("task", "algo", "seed", "epoch", "nfe", "success")
NOT_RUN = "not run"
NO_EVAL = "no evaluation yet"
NOT_AT_SETTING = "not evaluated at this setting"
_GROUP_KEYS = {"recipe", "folder", "seeds", "command", "file", "note", "evaluate"}
#: What each kind of table must give.
_TABLE_KEYS = {"sweep": ("title", "claim", "settings", "columns", "rows"),
               "efficiency": ("title", "claim", "nfe", "epochs", "rows"),
               "epoch_time": ("title", "claim", "source", "command")}


# ----- the manifest ----------------------------------------------------------------------------
@dataclass(frozen=True)
class RunGroup:
    """Training runs that differ only in their seed (one folder each).

    Example:
        >>> g = RunGroup.from_entry("tuned", {"recipe": "pusht", "folder": "runs/s{seed}",
        ...                                   "seeds": [0, 1], "command": "train.py seed={seed}"})
        >>> g.folders, g.commands[1], g.metric
        (('runs/s0', 'runs/s1'), 'train.py seed=1', 'score')
    """

    name: str
    recipe: str
    folders: tuple[str, ...]
    seeds: tuple[int | None, ...]
    commands: tuple[str, ...]
    files: tuple[str, ...] = ("eval/eval.csv",)
    note: str | None = None
    folder_template: str = ""
    command_template: str = ""
    evaluations: tuple[str, ...] = ()
    evaluate_template: str = ""

    @classmethod
    def from_entry(cls, name: str, entry: dict) -> RunGroup:
        if not isinstance(entry, dict):
            raise ValueError(f"runs.{name}: expected a mapping, got {entry!r}")
        unknown = set(entry) - _GROUP_KEYS
        if unknown:
            raise ValueError(f"runs.{name}: unknown keys {sorted(unknown)} (known: "
                             f"{sorted(_GROUP_KEYS)})")
        for key in ("recipe", "folder", "command"):
            if not entry.get(key):
                raise ValueError(f"runs.{name}: missing '{key}'")
        if entry["recipe"] not in METRICS:
            raise ValueError(f"runs.{name}.recipe: {entry['recipe']!r} is not one of "
                             f"{sorted(METRICS)}")
        seeds = tuple(entry.get("seeds") or [None])
        fill = [{} if s is None else {"seed": s} for s in seeds]
        try:
            folders = tuple(entry["folder"].format(**f) for f in fill)
            commands = tuple(entry["command"].format(**f) for f in fill)
            evaluations = tuple(entry["evaluate"].format(**f) for f in fill
                                ) if entry.get("evaluate") else ()
        except (KeyError, IndexError) as err:
            raise ValueError(f"runs.{name}: folder/command use {{{err.args[0]}}}, which "
                             "'seeds' does not give") from err
        if len(set(folders)) != len(folders):
            raise ValueError(f"runs.{name}: several seeds share one folder {folders[0]!r} "
                             "(put {seed} in 'folder')")
        files = entry.get("file", "eval/eval.csv")
        files = (files,) if isinstance(files, str) else tuple(files or ())
        if not files or not all(isinstance(f, str) and f for f in files):
            raise ValueError(f"runs.{name}.file: expected a path or a list of paths, got "
                             f"{entry.get('file')!r}")
        return cls(name, entry["recipe"], folders, seeds, commands, files, entry.get("note"),
                   entry["folder"], entry["command"], evaluations, entry.get("evaluate") or "")

    @property
    def metric(self) -> str:
        return METRICS[self.recipe]

    @property
    def file(self) -> str:
        """The evaluation table's name, as the report states it (``a or b`` for a list)."""
        return " or ".join(self.files)

    def table(self, folder: Path) -> Path | None:
        """The evaluation table of a run folder: the first of `files` that it holds (a list
        serves runs of one group evaluated differently, e.g. a checkpoint trained before an
        option re-evaluated with it into its own file, later ones evaluated by training)."""
        return next((folder / f for f in self.files if (folder / f).is_file()), None)


def load_manifest(path: Path) -> tuple[dict[str, RunGroup], list[dict]]:
    """The run groups by name and the tables of a manifest; each error names its entry."""
    if not path.is_file():
        raise FileNotFoundError(f"paper_comparison.py: no manifest {path}")
    data = yaml.safe_load(path.read_text()) or {}
    for key in ("runs", "tables"):
        if key not in data:
            raise ValueError(f"{path}: missing '{key}'")
    groups = {name: RunGroup.from_entry(name, entry) for name, entry in data["runs"].items()}
    for i, table in enumerate(data["tables"]):
        where = f"{path}: tables[{i}] ({table.get('title', 'untitled')})"
        kind = table.get("kind", "sweep")
        if kind not in _TABLE_KEYS:
            raise ValueError(f"{where}: kind {kind!r} is not sweep, efficiency or epoch_time")
        missing = [k for k in _TABLE_KEYS[kind] if k not in table]
        if missing:
            raise ValueError(f"{where}: missing {missing} (a {kind} table needs "
                             f"{', '.join(_TABLE_KEYS[kind])})")
        if table.get("paper_claim") and not isinstance(
                getattr(paper, table["paper_claim"], None), str):
            raise ValueError(f"{where}: paper_claim {table['paper_claim']!r} is not a text "
                             "of recipes/paper.py")
        slots = list(table.get("columns", {})) if kind == "sweep" else ["runs"]
        for row in table.get("rows", []):
            for slot in slots:
                if row.get(slot) is not None and row[slot] not in groups:
                    raise ValueError(f"{where}: row {row.get('policy')!r} names run group "
                                     f"{row[slot]!r} ({slot}), which 'runs' does not define")
            if row.get("paper"):
                _paper_ref(row["paper"], where)
    return groups, data["tables"]


def _paper_ref(ref: str, where: str = "") -> tuple[paper.PaperTable, str]:
    """``"<table> <row>"`` -> the `recipes.paper` table and row key (checked)."""
    name, _, row = str(ref).partition(" ")
    if name not in paper.TABLES:
        raise ValueError(f"{where}: paper table {name!r} is not one of {sorted(paper.TABLES)}")
    if row not in paper.TABLES[name].rows:
        raise ValueError(f"{where}: paper table {name!r} has no row {row!r}")
    return paper.TABLES[name], row


# ----- the runs --------------------------------------------------------------------------------
@dataclass
class RunState:
    """One run folder as found: whether it exists, its rows, the commands behind it.

    Example:
        >>> RunState("runs/a", 0, False, "train.py seed=0").describe()
        '`runs/a` (seed 0): not run; training: `train.py seed=0`'
    """

    folder: str
    seed: int | None
    exists: bool
    command: str
    command_file: str | None = None
    rows: list[dict] | None = None
    eval_command: str | None = None
    status: str = NOT_RUN
    evaluate: str | None = None
    record: str | None = None
    transcribed: str | None = None
    table_path: Path | None = None

    def describe(self) -> str:
        where = f"`{self.folder}`" + ("" if self.seed is None else f" (seed {self.seed})")
        status = {NOT_RUN: "not run", NO_EVAL: "exists, no evaluation yet"}.get(
            self.status, "evaluated" + (f" by `{self.eval_command}`" if self.eval_command
                                        else ""))
        source = f" (from `{self.command_file}`)" if self.command_file else ""
        command = "`, then `".join(self.command.splitlines())
        text = f"{where}: {status}; training{source}: `{command}`"
        if self.record:
            text += f"; read from its record `{self.record}`"
            if self.transcribed:
                text += f" ({TRANSCRIBED}{self.transcribed})"
        if self.evaluate and self.status != "evaluated":
            text += f"; evaluation: `{self.evaluate}`"
        return text


def _comments(path: Path) -> list[str]:
    """The ``#`` lines heading a table (``#`` and surrounding blanks stripped)."""
    out = []
    with open(path) as f:
        for line in f:
            if not line.startswith("#"):
                break
            out.append(line[1:].strip())
    return out


def _shown_path(path: Path) -> str:
    try:
        return str(path.resolve().relative_to(ROOT))
    except ValueError:
        return str(path)


def read_run(root: Path, group: RunGroup, index: int, records: Path | None = None) -> RunState:
    """The state of ``group``'s ``index``-th folder under ``root``; a folder that is absent is
    read from its record under ``records`` (`record_runs`) when there is one."""
    folder = group.folders[index]
    path = root / folder
    state = RunState(folder, group.seeds[index], path.is_dir(), group.commands[index],
                     evaluate=group.evaluations[index] if group.evaluations else None)
    recorded = group.table(records / folder) if records is not None else None
    if not state.exists and recorded is not None:
        path = records / folder
        state.exists = True
        state.record = _shown_path(recorded)
    # one command per line: a resumed run's file adds the resuming command below the first
    for cmd_file, shown in ((path.with_name(path.name + ".cmd"), f"{folder}.cmd"),
                            (path / COMMAND_FILE, f"{folder}/{COMMAND_FILE}")):
        if cmd_file.is_file():
            state.command = "\n".join(" ".join(line.split()) for line in
                                      cmd_file.read_text().splitlines() if line.strip())
            state.command_file = shown
            break
    if not state.exists:
        return state
    table = group.table(path)
    if table is None:
        state.table_path = path / group.files[0]
        state.status = NO_EVAL
        return state
    state.table_path = table
    state.rows = read_table(table)
    comments = _comments(table)
    state.eval_command = comments[0] if comments else None
    state.transcribed = next((c[len(TRANSCRIBED):] for c in comments[1:]
                              if c.startswith(TRANSCRIBED)), None)
    state.status = "evaluated"
    return state


def read_group(root: Path, group: RunGroup, records: Path | None = None) -> list[RunState]:
    return [read_run(root, group, i, records) for i in range(len(group.folders))]


def _copy_atomic(src: Path, dst: Path) -> None:
    dst.parent.mkdir(parents=True, exist_ok=True)
    tmp = dst.with_name(f".{dst.name}.tmp{os.getpid()}")
    try:
        shutil.copyfile(src, tmp)
        os.replace(tmp, dst)
    finally:
        tmp.unlink(missing_ok=True)


def record_runs(groups: dict[str, RunGroup], root: Path, records: Path) -> list[Path]:
    """Copy each evaluated run folder's evaluation table (the group's ``file``), its
    ``config.yaml`` (the settings it was trained with), its ``command.txt`` (the command lines
    that trained it) and its ``<folder>.cmd`` to the same paths under ``records``; returns the
    records written.

    Only those files are written, each replaced atomically; nothing else under ``records`` is
    touched, so the records of runs that are absent stay as they are.
    """
    written = []
    for group in groups.values():
        for folder in group.folders:
            path = root / folder
            table = group.table(path)
            if table is None:  # absent, or not evaluated yet
                continue
            rel_table = table.relative_to(path)
            for src, rel in ((table, Path(folder) / rel_table),
                             (path / "config.yaml", Path(folder) / "config.yaml"),
                             (path / COMMAND_FILE, Path(folder) / COMMAND_FILE),
                             (path.with_name(path.name + ".cmd"), Path(f"{folder}.cmd"))):
                dst = records / rel
                if src.is_file() and dst not in written:
                    _copy_atomic(src, dst)
                    written.append(dst)
    return written


#: A run folder written to this recently may still be training: `todo` comments its job out.
RECENT_MINUTES = 15


def _needs(command: str, folder: str) -> bool:
    """Whether ``command`` reads something of run folder ``folder`` (a teacher's checkpoint).

    Example:
        >>> [_needs(c, "runs/t1") for c in ("x teacher=runs/t1/best.pt", "x t='./runs/t1'",
        ...                                 "x teacher=runs/t10/best.pt", "x runs/t1x")]
        [True, True, False, False]
    """
    pattern = rf"(?<![\w./-])(?:\./)?{re.escape(folder)}(?=[/\s'\"]|$)"
    return re.search(pattern, command) is not None


def _minutes_since_written(folder: Path, now: float) -> float:
    """Minutes since anything under ``folder`` was last written."""
    newest = max((p.stat().st_mtime for p in folder.rglob("*") if p.is_file()),
                 default=folder.stat().st_mtime)
    return (now - newest) / 60


def todo(groups: dict[str, RunGroup], root: Path, records: Path | None = None,
         now: float | None = None) -> list[str]:
    """The jobs that the report still lacks, one shell line each, to run from the repository
    root:

    - a run not run: its training command (then its evaluation command, when the group has
      one); a command that does not name its folder is a ``#`` line (its run would not be
      found);
    - a run folder without its evaluation: the same with ``resume=<folder>``, which continues
      it from its ``last.pt`` (a ``#`` line without one); a folder written to in the last
      `RECENT_MINUTES` minutes may still be training, so its line is a ``#`` line too;
    - a run that another job reads (a Consistency Policy student's teacher) but whose folder
      is absent, kept only as a record: trained again, since records keep no checkpoints.

    A folder that several groups name is one job (the first group's). A job whose command reads
    another job's folder comes after it.

    Example:
        >>> g = RunGroup.from_entry("t", {"recipe": "pusht", "folder": "runs/t{seed}",
        ...                               "seeds": [0], "command": "train.py out=runs/t{seed}"})
        >>> s = RunGroup.from_entry("s", {"recipe": "pusht", "folder": "runs/s{seed}", "seeds": [0],
        ...                               "command": "cp.py teacher=runs/t{seed}/best.pt "
        ...                                          "out=runs/s{seed}"})
        >>> todo({"s": s, "t": g}, Path("/nonexistent"))
        ['train.py out=runs/t0', 'cp.py teacher=runs/t0/best.pt out=runs/s0']
    """
    now = time.time() if now is None else now
    found: dict[str, tuple[RunGroup, int, RunState]] = {}
    for group in groups.values():
        for i, state in enumerate(read_group(root, group, records)):
            found.setdefault(state.folder, (group, i, state))

    def then_evaluate(state: RunState) -> str:
        return f" && {state.evaluate}" if state.evaluate else ""

    jobs: dict[str, str] = {}
    for folder, (group, i, state) in found.items():
        if state.status == NOT_RUN and not _needs(group.commands[i], folder):
            jobs[folder] = (f"# {folder}: its command does not name the folder, so its run would "
                            f"not be found; give it out_dir={folder}: {group.commands[i]}")
        elif state.status == NOT_RUN:
            jobs[folder] = group.commands[i] + then_evaluate(state)
        elif state.status == NO_EVAL and (root / folder / "last.pt").is_file():
            # continue it (a finished run resumes at its end, then evaluates)
            line = f"{group.commands[i]} resume={folder}" + then_evaluate(state)
            minutes = _minutes_since_written(root / folder, now)
            if minutes < RECENT_MINUTES:
                line = (f"# {folder} was written to {minutes:.0f} min ago and may still be "
                        f"training; once it has stopped: {line}")
            jobs[folder] = line
        elif state.status == NO_EVAL:
            jobs[folder] = (f"# {folder} exists without its {group.file} or a last.pt to "
                            f"resume: move it aside, then: {group.commands[i]}")
    # a pending job that reads a folder kept only as a record needs that run trained again
    notes: dict[str, str] = {}
    grown = True
    while grown:
        grown = False
        for folder, line in list(jobs.items()):
            for other, (group, i, state) in found.items():
                if other not in jobs and not (root / other).is_dir() and _needs(line, other):
                    jobs[other] = group.commands[i] + then_evaluate(state)
                    notes[other] = (f"  # again: {other} is kept only as a record, and "
                                    f"{folder} reads it")
                    grown = True
    ordered: list[str] = []
    placed: set[str] = set()

    def place(folder: str, chain: tuple[str, ...]) -> None:
        # depth first: what a job reads is placed right before it
        if folder in placed:
            return
        if folder in chain:
            raise ValueError("paper_comparison.py: the commands of "
                             + ", ".join(chain[chain.index(folder):]) + " read each other's "
                             "folders")
        for other in jobs:
            if other != folder and _needs(jobs[folder], other):
                place(other, (*chain, folder))
        placed.add(folder)
        ordered.append(jobs[folder] + notes.get(folder, ""))

    for folder in jobs:
        place(folder, ())
    return ordered


# ----- cells -----------------------------------------------------------------------------------
def mean_spread(values: list[float], planned: int, digits: int = 3) -> str:
    """``mean ± sample std (n runs)``; one value alone as it is; ``(m of n runs)`` when fewer
    runs than planned gave it.

    Example:
        >>> mean_spread([0.8, 0.9], 3)
        '0.850 ± 0.071 (2 of 3 runs)'
    """
    text = f"{statistics.fmean(values):.{digits}f}"
    if len(values) > 1:
        text += f" ± {statistics.stdev(values):.{digits}f}"
    if len(values) < planned:
        text += f" ({len(values)} of {planned} runs)"
    elif len(values) > 1:
        text += f" ({len(values)} runs)"
    return text


def _matches(row: dict, nfe: int, t_end: float) -> bool:
    return int(row["nfe"]) == int(nfe) and math.isclose(float(row["t_end"]), float(t_end))


def _reached(row: dict) -> float | None:
    value = row.get("t_reached")
    return None if value in (None, "") else float(value)


def sweep_cell(states: list[RunState], metric: str, nfe: int, t_end: float
               ) -> tuple[str, list[float]]:
    """The cell of one group at (NFE, T asked) and the end times its runs reached."""
    values, reached = [], []
    for state in states:
        for row in state.rows or []:
            if _matches(row, nfe, t_end):
                if metric not in row:
                    raise ValueError(f"{state.folder}: its evaluation table has no "
                                     f"'{metric}' column")
                values.append(float(row[metric]))
                if _reached(row) is not None:
                    reached.append(_reached(row))
                break
    if values:
        return mean_spread(values, len(states)), reached
    if any(s.rows is not None for s in states):
        return NOT_AT_SETTING, reached
    if any(s.exists for s in states):
        return NO_EVAL, reached
    return NOT_RUN, reached


def _t_text(reached: list[float]) -> str:
    got = sorted({round(t, 2) for t in reached})
    return " / ".join(f"{t:.2f}" for t in got) if got else "-"


# ----- tables ----------------------------------------------------------------------------------
@dataclass
class Footnotes:
    """The commands under a table: one numbered entry per run group.

    Example:
        >>> notes = Footnotes()
        >>> g = RunGroup.from_entry("a", {"recipe": "pusht", "folder": "runs/a",
        ...                               "command": "train.py"})
        >>> notes.ref(g, "SRFMP, tuned", [RunState("runs/a", None, False, "train.py")])
        '[1]'
        >>> notes.lines[0]
        '- [1] SRFMP, tuned (`a`)'
    """

    groups: dict[str, int] = field(default_factory=dict)
    lines: list[str] = field(default_factory=list)

    def ref(self, group: RunGroup, label: str, states: list[RunState]) -> str:
        if group.name not in self.groups:
            self.groups[group.name] = len(self.groups) + 1
            self.lines.append(f"- [{self.groups[group.name]}] {label} (`{group.name}`)"
                              + (f": {group.note}" if group.note else ""))
            pending = [s for s in states if not s.exists and s.command_file is None]
            shown = [s for s in states if s not in pending] if len(pending) > 1 else states
            self.lines += [f"  - {s.describe()}" for s in shown]
            if len(pending) > 1:  # the seeds not run yet: one line, the manifest's template
                seeds = ", ".join(str(s.seed) for s in pending)
                self.lines.append(f"  - `{group.folder_template}` for seeds {seeds}: not run; "
                                  f"training: `{group.command_template}`")
                if group.evaluations:
                    self.lines[-1] += f"; evaluation: `{group.evaluate_template}`"
        return f"[{self.groups[group.name]}]"


def _head(table: dict) -> list[str]:
    lines = [f"## {table['title']}", "", f"Paper's claim: {table['claim']}", ""]
    if table.get("note"):
        lines += [table["note"], ""]
    return lines


def sweep_table(table: dict, groups: dict[str, RunGroup], root: Path,
                records: Path | None = None) -> list[str]:
    """Rows: each policy at each (NFE, T asked); columns: T reached, the paper, our groups."""
    slots = table.get("columns") or {}
    notes = Footnotes()
    states = {name: read_group(root, groups[name], records) for row in table["rows"]
              for name in (row.get(s) for s in slots) if name}
    header = ["policy", "NFE", "T asked", "T reached", "paper", *slots.values()]
    lines = _head(table)
    if table.get("paper_claim"):
        lines += [f"The paper's side: {getattr(paper, table['paper_claim'])}.", ""]
    lines += ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    sources: dict[str, list[str]] = {}
    for row in table["rows"]:
        ref = _paper_ref(row["paper"]) if row.get("paper") else None
        if ref:
            sources.setdefault(f'"{ref[0].caption}" ({ref[0].observations})', []).append(
                row["policy"])
        for nfe, t_end in row.get("settings") or table["settings"]:
            cells, reached = [], []
            for slot, header_text in slots.items():
                name = row.get(slot)
                if not name:
                    cells.append("-")
                    continue
                text, got = sweep_cell(states[name], groups[name].metric, nfe, t_end)
                reached += got
                label = f"{row['policy']}, {header_text}"
                cells.append(f"{text} {notes.ref(groups[name], label, states[name])}")
            figure = ref[0].cell(ref[1], nfe, t_end) if ref else "-"
            lines.append(f"| {row['policy']} | {nfe} | {t_end:g} | {_t_text(reached)} | "
                         f"{figure} | " + " | ".join(cells) + " |")
    for caption, policies in sources.items():
        lines += ["", f"Paper column: table {caption}, for {'; '.join(policies)}."]
    return lines + ["", "Runs and commands:", "", *notes.lines, ""]


def _efficiency_rows(state: RunState, path: Path) -> list[dict]:
    missing = [c for c in EFFICIENCY_COLUMNS if c not in (state.rows[0] if state.rows else {})]
    if state.rows and missing:
        raise ValueError(f"{path}: missing columns {missing} (expected "
                         f"{', '.join(EFFICIENCY_COLUMNS)})")
    return state.rows or []


def efficiency_table(table: dict, groups: dict[str, RunGroup], root: Path,
                     records: Path | None = None) -> list[str]:
    """Rows: task and algorithm; columns: success at each snapshot epoch at the table's NFE."""
    nfe, epochs = int(table["nfe"]), [int(e) for e in table["epochs"]]
    t_end = float(table.get("t_end", 1.0))
    notes = Footnotes()
    header = ["policy", "NFE", "T reached", "paper (its text)", "paper at epoch 50 (its NFE table)",
              *(f"epoch {e}" for e in epochs)]
    lines = _head(table) + [f"Success at NFE {nfe}, T {t_end:g} asked, of the snapshot at each "
                            "epoch, from each run's `efficiency.csv`.", "",
                            "| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for row in table["rows"]:
        group = groups[row["runs"]]
        states = read_group(root, group, records)
        by_epoch: dict[int, list[float]] = {e: [] for e in epochs}
        reached = []
        for state in states:
            for r in _efficiency_rows(state, state.table_path):
                if (r["task"], r["algo"]) != (row["task"], row["algo"]):
                    raise ValueError(f"{state.table_path}: a row of "
                                     f"{r['task']}/{r['algo']}, but the manifest row is "
                                     f"{row['task']}/{row['algo']}")
                if (int(r["nfe"]) == nfe and int(r["epoch"]) in by_epoch
                        and math.isclose(float(r.get("t_end") or 1.0), t_end)):
                    by_epoch[int(r["epoch"])].append(float(r["success"]))
                    if _reached(r) is not None:
                        reached.append(_reached(r))
        ref = notes.ref(group, row["policy"], states)
        cells = []
        for e in epochs:
            if by_epoch[e]:
                cells.append(f"{mean_spread(by_epoch[e], len(states))} {ref}")
            elif any(s.rows is not None for s in states):
                cells.append(f"{NOT_AT_SETTING} {ref}")
            elif any(s.exists for s in states):
                cells.append(f"{NO_EVAL} {ref}")
            else:
                cells.append(f"{NOT_RUN} {ref}")
        claim = paper.EFFICIENCY_CLAIMS.get((row["task"], row["algo"]), "-")
        at_50 = (paper.ROBOMIMIC_STATE.cell(f"{row['task']}/{row['algo']}", nfe, t_end)
                 if (row["task"], row["algo"]) in paper.FIFTY_EPOCH_ROWS else "-")
        lines.append(f"| {row['policy']} | {nfe} | {_t_text(reached)} | {claim} | {at_50} | "
                     + " | ".join(cells) + " |")
    caption, _ = paper.EFFICIENCY_FIGURE
    return lines + ["", f'Paper column: figure "{caption}" (state), as its text describes it. '
                    f'Paper at epoch 50: table "{paper.ROBOMIMIC_STATE.caption}" at the same NFE '
                    "and T, whose RFMP and SRFMP rows are its 50-epoch models; its DP rows are "
                    "trained 300 epochs, so none is given for DDIM.",
                    "", "Runs and commands:", "", *notes.lines, ""]


def read_epoch_times(path: Path) -> dict[str, tuple[str, str]]:
    """``{algorithm: (s/epoch, ratio to DDIM)}`` from the epoch-time benchmark's markdown."""
    lines = [line for line in path.read_text().splitlines() if line.startswith("|")]
    for i, line in enumerate(lines):
        cells = [c.strip() for c in line.strip("|").split("|")]
        if cells and cells[0] == "algorithm" and "s/epoch" in cells:
            at, ratio = cells.index("s/epoch"), cells.index("vs DDIM")
            out = {}
            for body in lines[i + 2:]:
                values = [c.strip() for c in body.strip("|").split("|")]
                if len(values) != len(cells):
                    break
                out[values[0]] = (values[at], values[ratio])
            return out
    raise ValueError(f"{path}: no table with 'algorithm', 's/epoch' and 'vs DDIM' columns")


def epoch_time_table(table: dict, root: Path) -> list[str]:
    """The paper's training time per epoch (GPU, images) beside the benchmark's (ours)."""
    source = root / table["source"]
    ours = read_epoch_times(source) if source.is_file() else {}
    header = ["algorithm", "paper: Lift s/epoch", "paper: Square s/epoch",
              "paper: vs DP (Lift / Square)", "ours: s/epoch", "ours: vs DDIM"]
    lines = _head(table) + ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    tasks = ("Lift", "NutAssemblySquare")
    for algo, name in (("rfmp", "RFMP"), ("srfmp", "SRFMP"), ("ddim", "DP (DDIM)"),
                       ("cp", "CP"), ("cp+teacher", "CP + its teacher's epoch")):
        if algo == "cp+teacher":  # the paper's CP and DP rows added (its "three times")
            got = [(paper.TRAIN_TIME[(t, "cp")][0] + paper.TRAIN_TIME[(t, "ddim")][0], None)
                   for t in tasks]
        else:
            got = [paper.TRAIN_TIME[(t, algo)] for t in tasks]
        cells = [f"{m:.2f}" + ("" if s is None else f" ± {s:.2f}") for m, s in got]
        ratio = " / ".join(f"{m / paper.TRAIN_TIME[(t, 'ddim')][0]:.2f}x"
                           for (m, _), t in zip(got, tasks, strict=True))
        mine = ours.get(algo, (NOT_RUN, NOT_RUN) if not source.is_file() else ("-", "-"))
        lines.append(f"| {name} | {' | '.join(cells)} | {ratio} | {mine[0]} | {mine[1]} |")
    caption, _ = paper.TRAIN_TIME_TABLE
    status = f"read from `{table['source']}`" if source.is_file() else (
        f"`{table['source']}` does not exist yet")
    return lines + ["", f'Paper columns: table "{caption}" (images, one NVIDIA RTX 4060 Ti); '
                    "its CP + teacher row adds its CP and DP rows. Ours: Push-T state, small "
                    f"UNet, CPU ({status}); command: `{table['command']}`.", ""]


# ----- the report ------------------------------------------------------------------------------
def build(manifest: Path = MANIFEST, root: Path = ROOT, command: str = "",
          records: Path | None = None) -> str:
    """The markdown of every table of ``manifest``, run folders read under ``root`` (an absent
    folder from its record under ``records``, when given)."""
    groups, tables = load_manifest(manifest)
    source = f"the run folders named in `{_shown_path(manifest)}`"
    if records is not None:
        source += (f" (a folder that is absent: its record under `{_shown_path(records)}`, "
                   "the folder's evaluation table and command kept in git)")
    lines = ["# The paper's claims beside ours", "",
             f"Generated by `{command}` from {source}.", "",
             "Each row is one policy at one NFE and end time T asked for; `T reached` is where "
             "our runs' solver stopped (SRFMP's first step ends at 1 / lambda_x = 0.4, each "
             "refinement step is at most 0.4 long), `-` while no run is evaluated. Figures: "
             "Push-T's score (mean maximum coverage over 50 seeds), robosuite's and Franka "
             "Kitchen's (all four subtasks) success rate over 50 seeds. Several training runs "
             "give their mean ± sample standard deviation (n runs); one run gives its value "
             "alone. `not run`: the run folder does not exist;"
             f" `{NO_EVAL}`: the folder exists without its evaluation; "
             f"`{NOT_AT_SETTING}`: its evaluation skipped that NFE / T. [k] points to the runs "
             "and the training command under each table (a folder's `<folder>.cmd`, or else "
             "its `command.txt`, when present, is the command that made it).", ""]
    for table in tables:
        kind = table.get("kind", "sweep")
        if kind == "sweep":
            lines += sweep_table(table, groups, root, records)
        elif kind == "efficiency":
            lines += efficiency_table(table, groups, root, records)
        else:
            lines += epoch_time_table(table, root)
    return "\n".join(lines).rstrip() + "\n"


def main(argv: list[str] | None = None) -> str:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--manifest", type=Path, default=MANIFEST,
                        help="runs and tables (default recipes/paper_comparison.yaml)")
    parser.add_argument("--root", type=Path, default=ROOT,
                        help="where the manifest's run folders are (default the repository)")
    parser.add_argument("--records", type=Path, default=RECORDS,
                        help="where run folders' records are kept and read when a folder is "
                             "absent (default results/records)")
    parser.add_argument("--no-records", action="store_true",
                        help="read only the run folders")
    parser.add_argument("--record", action="store_true",
                        help="first copy every evaluated run folder's evaluation table, "
                             "config.yaml, command.txt and .cmd into --records")
    parser.add_argument("--out", type=Path, default=None, help="write the markdown here too")
    parser.add_argument("--todo", action="store_true",
                        help="print instead the jobs the report still lacks, one shell line "
                             "each (training, then evaluation; a stopped run resumed; a run "
                             "that may still be training commented out), teachers before "
                             "their students")
    args = parser.parse_args(argv)
    if args.record and args.no_records:
        parser.error("--record and --no-records exclude each other")
    if args.todo and (args.record or args.out):
        parser.error("--todo prints the missing jobs only (without --record and --out)")
    argv = sys.argv[1:] if argv is None else argv
    command = " ".join(["python recipes/paper_comparison.py", *argv])
    records = None if args.no_records else args.records
    if args.todo:
        groups, _ = load_manifest(args.manifest)
        lines = todo(groups, args.root, records)
        text = "\n".join(lines) + "\n" if lines else ""
        sys.stdout.write(text)
        print(f"{len(lines)} jobs; run each from the repository root", file=sys.stderr)
        return text
    if args.record:
        groups, _ = load_manifest(args.manifest)
        for path in record_runs(groups, args.root, records):
            print(f"recorded {_shown_path(path)}", file=sys.stderr)
    text = build(args.manifest, args.root, command, records)
    sys.stdout.write(text)
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(text)
    return text


if __name__ == "__main__":
    main()
