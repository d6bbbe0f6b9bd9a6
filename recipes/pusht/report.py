"""Collect Push-T runs into one results file (``results/pusht.md``).

    python recipes/pusht/report.py runs/pusht/srfmp_state_euclidean runs/pusht/rfmp_... \\
        --out results/pusht.md

For every run folder (written by ``train.py``; evaluated by its final sweep or ``eval.py``):
the training command that reproduces it (from its stored config), the training budget actually
used (steps, minutes, best validation step), the evaluation table with its command, and a
side-by-side summary of all runs at every NFE and end time T. Runs whose settings differ only in
``seed`` also get a table of their mean over training seeds (Diffusion Policy reports its Push-T
scores over three training seeds), each run's own score beside it.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import yaml

from recipes import paper
from recipes.common import upgrade_config
from rfmp_rl.eval import read_table
from rfmp_rl.solvers import SolverConfig

TASK_KEYS = ("algo", "obs", "space", "model.prior_sphere", "model.unet_preset",
             "model.down_dims", "model.horizon", "model.action_steps", "model.obs_horizon",
             "loss.time_max", "loss.t0_fraction", "seed", "threads")
DEFAULTS = Path(__file__).with_name("config.yaml")
_NFE_TABLE = f'"{paper.PUSHT_NFE.caption}" at T = 1'
_TIME_TABLE = '"Influence of Integration Time" at NFE 3, T 1.2 and NFE 4, T 1.6'  # as printed
_SPHERE_TABLE = f'"{paper.SPHERE_PRIORS.caption}"'
_SPHERE_TIME_TABLE = '"Influence of Integration Time" at NFE 3, T 1 and 1.2 and NFE 4, T 1.6'


def _figures(*rows: dict) -> dict:
    """``{(NFE, T): "figure"}`` as the paper prints it; where two of its tables give the same
    setting different figures, both (``"0.851 / 0.862"``)."""
    out: dict = {}
    for row in rows:
        for setting, value in row.items():
            text = f"{value:g}"
            out[setting] = text if setting not in out or out[setting] == text else (
                f"{out[setting]} / {text}")
    return out


def _euclidean(algo: str) -> dict:
    return _figures(paper.PUSHT_NFE.rows[algo], paper.PUSHT_TIME.rows[f"euclidean/{algo}"])


def _sphere(key: str) -> dict:
    return _figures(paper.SPHERE_PRIORS.rows[key])


#: The paper's Push-T scores (image observations, 50 seeds) by (space, algo, sphere prior), each
#: ``(row label, {(NFE, T asked): figure})`` (`recipes.paper`). Its two Euclidean tables disagree
#: on SRFMP at NFE 3, T = 1 (0.851 in the NFE table, 0.862 in the integration-time table): both
#: are given. Its Sphere Push-T integration-time figures state no prior (prior ``None``: shown
#: for every sphere run of the algorithm).
PAPER_ROWS = {
    ("euclidean", "srfmp", None): (f"SRFMP, from images (tables {_NFE_TABLE}, {_TIME_TABLE})",
                                   _euclidean("srfmp")),
    ("euclidean", "rfmp", None): (f"RFMP, from images (tables {_NFE_TABLE}, {_TIME_TABLE})",
                                  _euclidean("rfmp")),
    ("euclidean", "ddim", None): (f"DP, from images (table {_NFE_TABLE})",
                                  _figures(paper.PUSHT_NFE.rows["ddim"])),
    ("sphere", "srfmp", "uniform"): (f"SRFMP (uniform prior), from images (table {_SPHERE_TABLE})",
                                     _sphere("srfmp/uniform")),
    ("sphere", "srfmp", "wrapped"): (f"SRFMP (Gaussian prior), from images (table {_SPHERE_TABLE})",
                                     _sphere("srfmp/wrapped")),
    ("sphere", "rfmp", "uniform"): (f"RFMP (uniform prior), from images (table {_SPHERE_TABLE})",
                                    _sphere("rfmp/uniform")),
    ("sphere", "rfmp", "wrapped"): (f"RFMP (Gaussian prior), from images (table {_SPHERE_TABLE})",
                                    _sphere("rfmp/wrapped")),
    ("sphere", "srfmp", None): (
        f"SRFMP, prior not stated, from images (table {_SPHERE_TIME_TABLE})",
        _figures(paper.PUSHT_TIME.rows["sphere/srfmp"])),
    ("sphere", "rfmp", None): (
        f"RFMP, prior not stated, from images (table {_SPHERE_TIME_TABLE})",
        _figures(paper.PUSHT_TIME.rows["sphere/rfmp"])),
    ("sphere", "ddim", None): (f"DP, Euclidean Gaussian, from images (table {_SPHERE_TABLE})",
                               _sphere("ddim/euclidean")),
}
NOT_TRAINING = ("out_dir", "checkpoint", "defaults", "hydra")  # not part of what a run learned


def _leaves(tree: dict, prefix: str = "") -> dict:
    """Flatten a nested config into ``{"optim.lr": 0.001, ...}``."""
    out = {}
    for key, value in tree.items():
        if isinstance(value, dict):
            out.update(_leaves(value, f"{prefix}{key}."))
        else:
            out[f"{prefix}{key}"] = value
    return out


def _override(key: str, value) -> str:
    text = f"{key}={yaml.safe_dump(value, default_flow_style=True).strip()}"
    text = text.removesuffix("\n...").replace(" ", "").replace("'", "")
    return f"'{text}'" if any(c in text for c in "[]{}") else text


def run_device(run: Path, cfg: dict) -> str:
    """The device the run trained on (``runtime.json``; older runs: the config's ``device``)."""
    info = run / "runtime.json"
    device = (json.loads(info.read_text()).get("device") if info.is_file()
              else cfg.get("device")) or "cpu"
    return "CPU" if str(device) == "cpu" else str(device)


def processes(run: Path) -> int:
    """How many processes trained the run (``runtime.json``; older runs: ``last.pt``; 1)."""
    info = run / "runtime.json"
    if info.is_file():
        return int(json.loads(info.read_text()).get("world_size", 1))
    if (run / "last.pt").is_file():
        import torch

        state = torch.load(run / "last.pt", map_location="cpu", weights_only=True)
        return int(state.get("training_state", {}).get("world_size", 1))
    return 1


def train_command(cfg: dict, defaults: dict | None = None, nproc: int = 1) -> str:
    """The training command that reproduces a run: ``algo obs space`` and every other setting
    that differs from the recipe's ``config.yaml`` (batch size, evaluation grid, ...); a run of
    several processes starts with its ``torchrun`` launch (the settings of earlier versions in
    today's names, `upgrade_config`)."""
    cfg = upgrade_config(cfg)
    if defaults is None:
        defaults = yaml.safe_load(DEFAULTS.read_text())
    base = _leaves({k: v for k, v in defaults.items() if k not in NOT_TRAINING})
    mine = _leaves({k: v for k, v in cfg.items() if k not in NOT_TRAINING})
    keys = [k for k in ("algo", "obs", "space") if k in mine]
    keys += [k for k in mine if k not in keys and (k not in base or mine[k] != base[k])]
    launch = (".venv/bin/python" if nproc == 1 else
              f"OMP_NUM_THREADS=1 .venv/bin/torchrun --standalone --nproc_per_node={nproc}")
    return f"{launch} recipes/pusht/train.py " + " ".join(_override(k, mine[k]) for k in keys)


def _name(cfg: dict) -> str:
    """A run's row label: what it learned and how, without its seed."""
    model, loss = cfg.get("model", {}), cfg.get("loss", {})
    name = f"{cfg['algo']} {cfg['obs']} {cfg['space']}" + (
        f" ({model.get('prior_sphere', 'uniform')} prior)"
        if cfg["space"] == "sphere" and cfg["algo"] != "ddim" else "")
    if cfg["algo"] == "srfmp" and float(loss.get("time_max", 1.0)) != 1.0:
        name += f", trained on t in [0, {loss['time_max']:g}]"
    if float(loss.get("t0_fraction", 0.0)):
        name += f", {loss['t0_fraction']:g} of training times at t = 0"
    if not model.get("prior_repeat", True):
        name += ", independent prior per chunk step"
    if cfg["train"].get("select_by") == "rollout":
        name += ", best.pt by rollout score"
    return name + f", {cfg['train']['max_minutes']:g} min cap"


def _paper_keys(cfg: dict) -> set:
    """The `PAPER_ROWS` keys that stand beside a run: its space, algorithm and sphere prior, and
    the paper's rows of that space and algorithm that state no prior."""
    prior = (cfg.get("model", {}).get("prior_sphere", "uniform")
             if cfg["space"] == "sphere" and cfg["algo"] != "ddim" else None)
    return {(cfg["space"], cfg["algo"], prior), (cfg["space"], cfg["algo"], None)}


def _selection(cfg: dict) -> str:
    """The setting of the rollout-selection score: ``NFE 1, T=1`` where the solver reaches the T
    asked, else ``NFE 1, T 1 asked, T 0.40 reached`` (SRFMP's first step ends at 1 /
    lambda_x)."""
    nfe, t_end = int(cfg["select"]["nfe"]), float(cfg["select"]["t_end"])
    reached = SolverConfig(nfe=nfe, t_end=t_end).resolve(cfg["algo"]).reached(
        float(cfg.get("loss", {}).get("lambda_x", 2.5)))
    if abs(reached - t_end) < 1e-6:
        return f"NFE {nfe}, T={t_end:g}"
    return f"NFE {nfe}, T {t_end:g} asked, T {reached:.2f} reached"


def _paper_rows(keys: set, settings: list[tuple[int, float]]) -> list[str]:
    """The `PAPER_ROWS` of ``keys`` as rows of a table with a column per setting."""
    return [f"| paper, {label} | " + " | ".join(figures.get(s, "-") for s in settings) + " |"
            for key, (label, figures) in PAPER_ROWS.items() if key in keys]


def _read(path: Path, what: str) -> str:
    if not path.is_file():
        raise FileNotFoundError(f"report.py: {path} is missing ({what})")
    return path.read_text()


def _reached(reached: dict, names: list[str], setting: tuple[int, float]) -> str:
    """`` (T 0.40 reached)`` when the runs' solver stopped at another end time than the one
    asked for (several values when the runs differ); empty when it reached it or the run's table
    has no ``t_reached`` column."""
    nfe, t_end = setting
    got = sorted({reached[(n, nfe, t_end)] for n in names if (n, nfe, t_end) in reached})
    if not got or all(abs(t - t_end) < 1e-6 for t in got):
        return ""
    return " (T " + " / ".join(f"{t:.2f}" for t in got) + " reached)"


def main(argv: list[str] | None = None) -> str:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("runs", nargs="+", type=Path)
    parser.add_argument("--out", type=Path, default=None)
    parser.add_argument("--notes", type=Path, default=None, help="markdown appended verbatim")
    parser.add_argument("--also", type=Path, nargs="*", default=[],
                        help="further evaluation folders (eval.py outputs) appended as tables")
    args = parser.parse_args(argv)
    argv = sys.argv[1:] if argv is None else argv
    runs = []
    for run in args.runs:
        cfg = upgrade_config(yaml.safe_load(_read(run / "config.yaml",
                                                  "the run's configuration")))
        runs.append((run, cfg, _name(cfg)))
    names = [name for _, _, name in runs]
    defaults = yaml.safe_load(DEFAULTS.read_text())
    sections, summary, groups, reached, group_keys = [], {}, {}, {}, {}
    paper_keys = set().union(*(_paper_keys(cfg) for _, cfg, _ in runs))
    for run, cfg, name in runs:
        history = json.loads(_read(run / "history.json", "the run's validation curve"))
        by_rollout = cfg["train"].get("select_by") == "rollout"
        best = (max(history, key=lambda h: h["rollout"]) if by_rollout
                else min(history, key=lambda h: h["val"]))
        last = history[-1]
        if by_rollout:
            chosen = (f"best validation rollout score {best['rollout']:.3f} (mean max coverage "
                      f"over seeds {cfg['select']['seed_start']}-"
                      f"{cfg['select']['seed_start'] + cfg['select']['seeds'] - 1}, "
                      f"{_selection(cfg)})")
        else:
            chosen = f"best validation loss {best['val']:.4f}"
        _read(run / "eval" / "eval.csv", "eval.py's table")
        rows = read_table(run / "eval" / "eval.csv")
        group = train_command({k: v for k, v in cfg.items() if k != "seed"}, defaults)
        if names.count(name) > 1:  # one label, several runs: their seeds, else their folders
            name += f", seed {cfg['seed']}"
            if name in summary:
                name += f" ({run.name})"
        scores = {(int(r["nfe"]), float(r["t_end"])): float(r["score"]) for r in rows}
        reached.update({(name, int(r["nfe"]), float(r["t_end"])): float(r["t_reached"])
                        for r in rows if r.get("t_reached") not in (None, "")})
        summary[name] = scores
        groups.setdefault(group, []).append((run.name, cfg["seed"], scores, name))
        group_keys.setdefault(group, set()).update(_paper_keys(cfg))
        nproc = processes(run)
        device = run_device(run, cfg)
        where = (f"on {device}" if nproc == 1 else
                 f"on {device} by {nproc} processes (DDP; global batch "
                 f"{nproc * cfg['train']['batch_size']})")
        sections += [
            f"## {name}",
            "",
            f"Training: `{train_command(cfg, defaults, nproc)}` — {last['step']} steps in "
            f"{last['minutes']:.1f} min {where} ({chosen} at step {best['step']}, "
            f"{best['minutes']:.1f} min; that checkpoint is evaluated).",
            "",
            "Task settings: " + ", ".join(f"{k}={_leaves(cfg)[k]}" for k in TASK_KEYS
                                          if k in _leaves(cfg)),
            "",
            _read(run / "eval" / "eval.md", "eval.py's table").replace("## ", "### ", 1),
        ]
    settings = sorted({s for v in summary.values() for s in v}, key=lambda s: (s[1], s[0]))
    columns = " | ".join(f"NFE {n}, T={t:g} asked" for n, t in settings) + " |"
    head = ["# Push-T results", "",
            "Generated by `python recipes/pusht/report.py " + " ".join(argv) + "`.", "",
            "Score = mean over the evaluation seeds of the maximum goal coverage within 500 steps "
            "(early stop at 95%), the paper's protocol. Columns name the NFE and the end time T "
            "asked for; a cell whose solver stopped at another T names the T it reached "
            "(SRFMP's first step ends at 1 / lambda_x).", "",
            "| policy | " + columns,
            "|---|" + "---|" * len(settings)]
    for name, scores in summary.items():
        head.append(f"| {name} | " + " | ".join(
            f"{scores[s]:.3f}{_reached(reached, [name], s)}" if s in scores else "-"
            for s in settings) + " |")
    head += _paper_rows(paper_keys, settings)
    seeded = {k: g for k, g in groups.items() if len({seed for _, seed, *_ in g}) > 1}
    if seeded:
        head += ["", "Across training seeds (runs whose settings differ only in `seed`): the mean "
                 "of the runs' scores, then each run's score in the order of the runs column.",
                 "", "| runs (seed) | " + columns, "|---|" + "---|" * len(settings)]
        for group in seeded.values():
            cells = []
            for s in settings:
                got = [scores[s] for _, _, scores, _ in group if s in scores]
                cells.append("-" if len(got) < len(group) else f"{sum(got) / len(got):.3f} ("
                             + ", ".join(f"{g:.3f}" for g in got) + ")"
                             + _reached(reached, [n for *_, n in group], s))
            head.append("| " + ", ".join(f"{folder} ({seed})" for folder, seed, *_ in group)
                        + " | " + " | ".join(cells) + " |")
        head += _paper_rows(set().union(*(group_keys[k] for k in seeded)), settings)
    text = "\n".join(head + [""] + sections)
    if args.notes:
        text += "\n" + args.notes.read_text()
    if args.also:
        text += "\n## Further evaluations\n"
        for folder in args.also:
            text += "\n" + _read(folder / "eval.md", "eval.py's table").replace("## ", "### ", 1)
    print(text)
    if args.out:
        args.out.write_text(text)
    return text


if __name__ == "__main__":
    main()
