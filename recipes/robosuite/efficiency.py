"""Training efficiency on robosuite: success rate against training epochs, the paper's figure
"Success rate ... on Robomimic tasks with state-based observations at different checkpoints"
(Lift, Can, Square checked every 10 epochs of a 50-epoch run at NFE 3; mean and standard
deviation over training seeds), for RFMP, SRFMP and DDIM.

    python recipes/robosuite/efficiency.py --plan          # the 27 training commands
    python recipes/robosuite/efficiency.py runs/robosuite/eff_* --out results/efficiency.md

Each run folder is a ``train.py`` run with ``train.snapshot_every_epochs`` (its
``snapshots/epoch_010.pt``, ...). Every snapshot is evaluated as ``eval.py`` evaluates a
checkpoint (its EMA weights, the task settings stored in it, the recipe's evaluation settings):
NFE 3 at T = 1 over 50 seeds from 100000 by default. Each result is kept in
``<run>/efficiency.csv`` (task, algo, seed, epoch, step, nfe, t_end, t_reached, success,
episodes, eval_seeds), so a later call evaluates only the snapshots not yet there (a run still
training gets its new snapshots evaluated). ``--out`` writes the table (per task, algorithm and
epoch: mean success over the training seeds +- their standard deviation) with this command on its
first line, and beside it a PNG (one panel per task, one line per algorithm, the spread shaded).
"""

from __future__ import annotations

import argparse
import csv
import math
import os
import re
import shlex
import statistics
import sys
import textwrap
from collections.abc import Sequence
from pathlib import Path

import yaml

from recipes.common import upgrade_config

HERE = Path(__file__).resolve().parent
TASKS = ("Lift", "PickPlaceCan", "NutAssemblySquare")
SHORT = {"Lift": "lift", "PickPlaceCan": "can", "NutAssemblySquare": "square"}
ALGOS = ("rfmp", "srfmp", "ddim")
NAMES = {"rfmp": "RFMP", "srfmp": "SRFMP", "ddim": "DDIM", "cp": "CP"}
TRAIN_SEEDS = (0, 1, 2)
#: The paper's table of hyperparameters: batch 256 for Lift and Can, 512 for Square; 50 epochs.
PAPER_BATCH = {"Lift": 256, "PickPlaceCan": 256, "NutAssemblySquare": 512}
EPOCHS, SNAPSHOT_EVERY = 50, 10
COLUMNS = ("task", "algo", "seed", "epoch", "step", "nfe", "t_end", "t_reached", "success",
           "episodes", "eval_seeds")
CACHE = "efficiency.csv"
#: What the paper says of its figure (the figure's values are not printed in the paper).
PAPER_CLAIM = ("For the easier tasks (Lift and Can), both RFMP and SRFMP achieve high "
               "performance after just 20 training epochs, while the success rate of DP remains "
               "low after 50 epochs. This trend persists in the harder tasks (Square and Tool "
               "Hang), with RFMP and SRFMP reaching high success rates significantly faster than "
               "DP.")
_SNAPSHOT = re.compile(r"epoch_(\d+)\.pt")


# ----- the training runs -----------------------------------------------------------------------
def plan(tasks: Sequence[str] = TASKS, algos: Sequence[str] = ALGOS,
         seeds: Sequence[int] = TRAIN_SEEDS, root: str = "runs/robosuite") -> list[str]:
    """The training commands of the figure: every task x algorithm x seed, the paper's settings
    (AdamW lr 1e-4, t ~ U[0, 1], 50 epochs at the paper's batch), a snapshot every 10 epochs,
    no wall-clock cap and no final NFE sweep (the snapshots are what is evaluated)."""
    lines = []
    for task in tasks:
        for algo in algos:
            for seed in seeds:
                out = f"{root}/eff_{SHORT[task]}_{algo}_seed{seed}"
                lines.append(
                    "OMP_NUM_THREADS=1 MUJOCO_GL=egl .venv/bin/python recipes/robosuite/train.py "
                    f"task={task} algo={algo} seed={seed} threads=1 optim.lr=1e-4 "
                    f"train.batch_size={PAPER_BATCH[task]} train.epochs={EPOCHS} "
                    f"train.snapshot_every_epochs={SNAPSHOT_EVERY} train.max_minutes=null "
                    f"eval.final_eval=false out_dir={out}")
    return lines


def run_info(run: Path) -> dict:
    """``{task, algo, seed, lr, batch_size, obs, actions, unet}`` of a run folder (its
    ``config.yaml``)."""
    path = run / "config.yaml"
    if not path.is_file():
        raise FileNotFoundError(f"run {run}: no config.yaml (not a train.py run folder)")
    cfg = upgrade_config(yaml.safe_load(path.read_text()))
    if not (cfg.get("train") or {}).get("snapshot_every_epochs"):
        raise ValueError(f"run {run}: trained without train.snapshot_every_epochs, so it keeps "
                         "no epoch snapshots")
    actions = cfg.get("action_space", "-")
    if actions == "abs_pose":
        actions += f"/{cfg.get('geometry', '-')}"
    return {"task": cfg["task"], "algo": cfg["algo"], "seed": int(cfg["seed"]),
            "lr": float(cfg["optim"]["lr"]), "batch_size": int(cfg["train"]["batch_size"]),
            "obs": cfg.get("obs", "-"), "actions": actions,
            "unet": (cfg.get("model") or {}).get("unet_preset", "-")}


def snapshots(run: Path) -> dict[int, Path]:
    """``{epoch: path}`` of a run's snapshots, in epoch order."""
    found = {int(m.group(1)): p for p in (run / "snapshots").glob("epoch_*.pt")
             if (m := _SNAPSHOT.fullmatch(p.name))}
    return dict(sorted(found.items()))


# ----- evaluation and its cache ----------------------------------------------------------------
def read_cache(path: Path) -> list[dict]:
    """The rows of an ``efficiency.csv`` (numbers as numbers); [] when there is none."""
    if not path.is_file():
        return []
    with open(path, newline="") as f:
        rows = list(csv.DictReader(f))
    missing = [c for c in COLUMNS if rows and c not in rows[0]]
    if missing:
        raise ValueError(f"{path}: not an efficiency table (no column {missing[0]!r})")
    ints, floats = ("seed", "epoch", "step", "nfe", "episodes"), ("t_end", "t_reached", "success")
    return [{**r, **{k: int(r[k]) for k in ints}, **{k: float(r[k]) for k in floats}}
            for r in rows]


def write_cache(path: Path, rows: list[dict]) -> None:
    """Write ``efficiency.csv`` atomically (a temporary file renamed over it)."""
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    with open(tmp, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=COLUMNS)
        writer.writeheader()
        for row in sorted(rows, key=lambda r: (r["epoch"], r["nfe"], r["t_end"])):
            writer.writerow({k: row[k] for k in COLUMNS})
    os.replace(tmp, path)


def _seed_range(start: int, seeds: int) -> str:
    return f"{start}-{start + seeds - 1}"


def evaluate_snapshot(path: Path, nfe: int, seeds: int, seed_start: int,
                      overrides: Sequence[str] = ()) -> dict:
    """One snapshot at (NFE, T = 1) over ``seeds`` seeds from ``seed_start``, as ``eval.py``
    runs it (``overrides``: further ``eval.*`` / runtime settings of the recipe's config)."""
    from hydra import compose, initialize_config_dir
    from utils import check_config, eval_task  # recipes/robosuite/utils.py

    from recipes.common import load_for_eval, run_sweep

    with initialize_config_dir(config_dir=str(HERE), version_base="1.3"):
        cfg = compose("config", overrides=[
            f"checkpoint={path}", f"eval.nfes=[{int(nfe)}]", "eval.t_ends=[1.0]",
            "eval.time_table=[]", f"eval.seeds={int(seeds)}", f"eval.seed_start={int(seed_start)}",
            *overrides])
    model, task_cfg, extra, _ = load_for_eval(cfg, check_config)
    (row,) = run_sweep(model, task_cfg, eval_task(task_cfg))
    return {"step": int(extra.get("step", -1)), "nfe": int(row["nfe"]),
            "t_end": float(row["t_end"]), "t_reached": float(row["t_reached"]),
            "success": float(row["success"]), "episodes": len(row["per_seed"]["seed"]),
            "eval_seeds": row["seeds"]}


def evaluate_run(run: Path, nfe: int = 3, seeds: int = 50, seed_start: int = 100000,
                 overrides: Sequence[str] = (), log=print) -> list[dict]:
    """Every snapshot of ``run`` not yet in its ``efficiency.csv`` at these settings, evaluated
    and added to it (written after each one); returns the run's rows at these settings."""
    info = run_info(run)
    cache = run / CACHE
    rows = read_cache(cache)
    spec = (int(nfe), 1.0, _seed_range(seed_start, seeds))

    def key(r: dict) -> tuple:
        return r["nfe"], r["t_end"], r["eval_seeds"]

    done = {r["epoch"] for r in rows if key(r) == spec}
    found = snapshots(run)
    if not found:
        log(f"{run}: no snapshots yet")
    for epoch, path in found.items():
        if epoch in done:
            continue
        result = evaluate_snapshot(path, nfe, seeds, seed_start, overrides)
        rows.append({"task": info["task"], "algo": info["algo"], "seed": info["seed"],
                     "epoch": epoch, **result})
        write_cache(cache, rows)
        log(f"{run}: epoch {epoch}: success {result['success']:.2f} "
            f"({result['episodes']} episodes, NFE {nfe}, T {result['t_reached']:.2f} reached)")
    return [r for r in rows if key(r) == spec]


# ----- the table and the plot ------------------------------------------------------------------
def aggregate(rows: Sequence[dict]) -> dict[tuple[str, str], dict[int, dict]]:
    """``{(task, algo): {epoch: {mean, std, n, seeds, t_reached}}}`` over the training seeds
    (std: the sample standard deviation, NaN for one seed)."""
    cells: dict[tuple[str, str], dict[int, dict[int, dict]]] = {}
    for r in rows:
        per_seed = cells.setdefault((r["task"], r["algo"]), {}).setdefault(r["epoch"], {})
        if r["seed"] in per_seed:
            raise ValueError(f"two results for {r['task']} {r['algo']} seed {r['seed']} epoch "
                             f"{r['epoch']}: give each training run once")
        per_seed[r["seed"]] = r
    out = {}
    for group, epochs in cells.items():
        out[group] = {}
        for epoch, per_seed in sorted(epochs.items()):
            values = [per_seed[s]["success"] for s in sorted(per_seed)]
            out[group][epoch] = {
                "mean": statistics.fmean(values),
                "std": statistics.stdev(values) if len(values) > 1 else math.nan,
                "n": len(values), "seeds": sorted(per_seed),
                "t_reached": sorted({per_seed[s]["t_reached"] for s in per_seed})}
    return out


def _order(group: tuple[str, str]) -> tuple:
    task, algo = group
    return (TASKS.index(task) if task in TASKS else len(TASKS), task,
            ALGOS.index(algo) if algo in ALGOS else len(ALGOS), algo)


def table(rows: Sequence[dict]) -> str:
    """The markdown table: one row per task x algorithm, one column per epoch, each cell the
    mean success over the training seeds +- their standard deviation (``(n=k)`` where fewer
    seeds than the row's are in)."""
    stats = aggregate(rows)
    epochs = sorted({e for cells in stats.values() for e in cells})
    nfes = sorted({r["nfe"] for r in rows})
    head = ["task", "algo", "NFE, T reached", "training seeds",
            *(f"epoch {e}" for e in epochs)]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for group in sorted(stats, key=_order):
        cells = stats[group]
        seeds = sorted({s for c in cells.values() for s in c["seeds"]})
        reached = sorted({t for c in cells.values() for t in c["t_reached"]})
        row = [group[0], NAMES.get(group[1], group[1]),
               f"{'/'.join(map(str, nfes))}, {'/'.join(f'{t:.2f}' for t in reached)}",
               ", ".join(map(str, seeds))]
        for epoch in epochs:
            c = cells.get(epoch)
            if c is None:
                row.append("-")
                continue
            cell = f"{c['mean']:.2f}" + ("" if math.isnan(c["std"]) else f" ± {c['std']:.2f}")
            if c["n"] < len(seeds):
                cell += f" (n={c['n']})"
            row.append(cell)
        lines.append("| " + " | ".join(row) + " |")
    return "\n".join(lines) + "\n"


def plot(rows: Sequence[dict], path: Path, title: str = "") -> Path:
    """One panel per task, one line per algorithm (mean over training seeds), the mean +- one
    standard deviation shaded; success in [0, 1] against epochs."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    stats = aggregate(rows)
    tasks = sorted({t for t, _ in stats}, key=lambda t: _order((t, "")))
    width = max(3.6 * len(tasks), 5.0)
    fig, axes = plt.subplots(1, len(tasks), figsize=(width, 3.4), squeeze=False, sharey=True)
    for ax, task in zip(axes[0], tasks, strict=True):
        for group in sorted((g for g in stats if g[0] == task), key=_order):
            cells = stats[group]
            x = sorted(cells)
            mean = [cells[e]["mean"] for e in x]
            std = [0.0 if math.isnan(cells[e]["std"]) else cells[e]["std"] for e in x]
            (line,) = ax.plot(x, mean, "o-", label=NAMES.get(group[1], group[1]))
            ax.fill_between(x, [max(0.0, m - s) for m, s in zip(mean, std, strict=True)],
                            [min(1.0, m + s) for m, s in zip(mean, std, strict=True)],
                            color=line.get_color(), alpha=0.2)
        ax.set(title=task, xlabel="training epochs", ylim=(-0.02, 1.02),
               xticks=sorted({e for g in stats if g[0] == task for e in stats[g]}))
        ax.grid(alpha=0.3)
    axes[0][0].set_ylabel("success rate")
    axes[0][-1].legend(loc="best", fontsize=8)
    if title:
        # about 15 characters of 9-point text per inch: wrapped, the title fits one panel
        fig.suptitle(textwrap.fill(title, width=int(15 * width)), fontsize=9)
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def report(rows: Sequence[dict], runs: Sequence[Path], out: Path, command: str) -> Path:
    """``out`` (markdown: the command, the table, the runs) and ``out`` with ``.png``."""
    if not rows:
        raise ValueError("no evaluated snapshots to report (the runs have no snapshots yet)")
    nfes = sorted({r["nfe"] for r in rows})
    episodes = sorted({r["episodes"] for r in rows})
    spans = sorted({r["eval_seeds"] for r in rows})
    what = (f"success at NFE {'/'.join(map(str, nfes))} (T = 1 asked) over "
            f"{'/'.join(map(str, episodes))} seeds ({', '.join(spans)})")
    png = plot(rows, out.with_suffix(".png"),
               title=f"{what}; mean ± std over training seeds")
    infos = [(run, run_info(run)) for run in runs]
    run_lines = ["| run | task | algo | seed | obs, actions | UNet | lr | batch | epochs evaluated "
                 "| steps per epoch |", "|---|---|---|---|---|---|---|---|---|---|"]
    for run, info in infos:
        mine = sorted((r for r in rows if (r["task"], r["algo"], r["seed"])
                       == (info["task"], info["algo"], info["seed"])), key=lambda r: r["epoch"])
        per_epoch = sorted({r["step"] // r["epoch"] for r in mine if r["epoch"] > 0})
        run_lines.append(
            f"| `{run}` | {info['task']} | {NAMES.get(info['algo'], info['algo'])} | "
            f"{info['seed']} | {info['obs']}, {info['actions']} | {info['unet']} | "
            f"{info['lr']:g} | {info['batch_size']} | "
            f"{', '.join(str(r['epoch']) for r in mine) or '-'} | "
            f"{', '.join(map(str, per_epoch)) or '-'} |")
    text = "\n".join([
        f"Command: `{command}`",
        "",
        "# Training efficiency: success rate against training epochs",
        "",
        f"Each cell: {what} of the EMA weights a run held as that epoch ended, the mean over "
        "the training seeds ± their standard deviation (a cell with fewer seeds than its row "
        "names them: `(n=2)`). One epoch is one pass over the training windows at the global "
        "batch. The column NFE, T reached gives the solver's budget and the end time it reached.",
        "",
        table(rows),
        f"![success against epochs]({png.name})",
        "",
        "The paper's figure gives no values in its text; what the paper says of it: "
        f"\"{PAPER_CLAIM}\" The paper's runs: robomimic's 200 proficient-human demonstrations "
        "and a UNet of 6.6e7 parameters; these runs: the recipe's scripted-expert "
        "demonstrations and the UNet preset in the Runs table.",
        "",
        "## Runs",
        "",
        *run_lines,
        "",
    ])
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(text)
    return out


# ----- command line ----------------------------------------------------------------------------
def main(argv: list[str] | None = None) -> list[dict]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="*", type=Path, help="training run folders")
    parser.add_argument("--plan", action="store_true",
                        help="print the training commands of the figure and exit")
    parser.add_argument("--out", type=Path, default=None,
                        help="markdown table to write (the plot goes beside it, .png)")
    parser.add_argument("--nfe", type=int, default=3, help="NFE of the evaluation (paper: 3)")
    parser.add_argument("--seeds", type=int, default=50, help="evaluation episodes per snapshot")
    parser.add_argument("--seed-start", type=int, default=100000, help="first evaluation seed")
    parser.add_argument("--threads", type=int, default=1, help="torch threads of the policy")
    parser.add_argument("--set", nargs="*", default=[], metavar="KEY=VALUE",
                        help="further settings of the recipe's config for the evaluation "
                             "(e.g. eval.workers=2 eval.num_envs=25)")
    parser.add_argument("--no-eval", action="store_true",
                        help="evaluate nothing: the table from the runs' efficiency.csv only")
    args = parser.parse_args(argv)
    if args.plan:
        print("\n".join(plan()))
        return []
    if not args.runs:
        parser.error("give the run folders (or --plan)")
    for run in args.runs:
        if not run.is_dir():
            parser.error(f"no such run folder: {run}")
    if args.nfe < 1 or args.seeds < 1:
        parser.error("--nfe and --seeds must be >= 1")
    rows = []
    for run in args.runs:
        if args.no_eval:
            run_info(run)
            spec = (args.nfe, 1.0, _seed_range(args.seed_start, args.seeds))
            rows += [r for r in read_cache(run / CACHE)
                     if (r["nfe"], r["t_end"], r["eval_seeds"]) == spec]
        else:
            rows += evaluate_run(run, args.nfe, args.seeds, args.seed_start,
                                 [f"threads={args.threads}", *args.set])
    if args.out:
        command = "python recipes/robosuite/efficiency.py " + " ".join(
            shlex.quote(a) for a in (argv if argv is not None else sys.argv[1:]))
        path = report(rows, args.runs, args.out, command)
        print(path.read_text())
    else:
        sys.stdout.write(table(rows))
    return rows


if __name__ == "__main__":
    main()
