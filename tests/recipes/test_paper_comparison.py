"""recipes/paper_comparison.py: every cell is read from a run folder (mean and spread over
training seeds, ``not run`` where no folder exists), every row names its NFE, the T asked and
the T reached, and every run's command stands under its table; recipes/paper.py feeds the
recipes' own paper columns."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
import yaml
from recipe_loader import compose, load_script

from recipes import paper
from recipes import paper_comparison as pc
from rfmp_rl.eval import Column, write_tables

PUSHT_CMD = ".venv/bin/python recipes/pusht/train.py algo=srfmp seed={seed} out_dir=runs/s{seed}"


def _eval_csv(folder: Path, rows: list[tuple], metric: str = "score",
              command: str = "python recipes/pusht/eval.py checkpoint=x/best.pt") -> None:
    """``rows``: (nfe, t_end, t_reached, value)."""
    (folder / "eval").mkdir(parents=True)
    lines = [f"# {command}", f"algo,nfe,t_end,t_reached,{metric}"]
    lines += [f"srfmp,{n},{t},{r},{v}" for n, t, r, v in rows]
    (folder / "eval" / "eval.csv").write_text("\n".join(lines) + "\n")


def _manifest(tmp_path: Path, runs: dict, tables: list[dict]) -> Path:
    path = tmp_path / "manifest.yaml"
    path.write_text(yaml.safe_dump({"runs": runs, "tables": tables}, sort_keys=False))
    return path


def _sweep(rows: list[dict], settings=((1, 1.0), (3, 1.0)), columns=None) -> dict:
    return {"title": "Push-T NFE sweep", "claim": "SRFMP is best at NFE 1.",
            "settings": [list(s) for s in settings],
            "columns": columns or {"paper_settings": "ours, paper settings",
                                   "tuned": "ours, tuned"},
            "rows": rows}


def _line(text: str, start: str) -> list[str]:
    return [line for line in text.splitlines() if line.startswith(start)]


@pytest.fixture
def two_of_three(tmp_path):
    """Seeds 0 and 1 of a three-seed group evaluated (SRFMP: NFE 1 stops at T 0.4)."""
    root = tmp_path / "repo"
    _eval_csv(root / "runs" / "s0", [(1, 1.0, 0.4, 0.8), (3, 1.0, 1.0, 0.7)])
    _eval_csv(root / "runs" / "s1", [(1, 1.0, 0.4, 0.9), (3, 1.0, 1.0, 0.9)])
    runs = {"tuned": {"recipe": "pusht", "folder": "runs/s{seed}", "seeds": [0, 1, 2],
                      "command": PUSHT_CMD},
            "paper_runs": {"recipe": "pusht", "folder": "runs/p{seed}", "seeds": [0, 1],
                           "command": "train.py lr=1e-4 seed={seed}"}}
    table = _sweep([{"policy": "SRFMP", "paper": "pusht_nfe srfmp",
                     "paper_settings": "paper_runs", "tuned": "tuned"}])
    return _manifest(tmp_path, runs, [table]), root


def test_cells_give_mean_and_spread_over_the_seeds_that_ran(two_of_three):
    manifest, root = two_of_three
    text = pc.build(manifest, root, "python recipes/paper_comparison.py")
    rows = _line(text, "| SRFMP |")
    # policy | NFE | T asked | T reached | paper | ours, paper settings | ours, tuned
    assert rows[0] == ("| SRFMP | 1 | 1 | 0.40 | 0.875 | not run [1] "
                       "| 0.850 ± 0.071 (2 of 3 runs) [2] |")
    assert rows[1] == ("| SRFMP | 3 | 1 | 1.00 | 0.851 | not run [1] "
                       "| 0.800 ± 0.141 (2 of 3 runs) [2] |")
    assert "| policy | NFE | T asked | T reached | paper | ours, paper settings | ours, tuned |" \
        in text


def test_every_run_of_a_row_carries_its_command(two_of_three):
    manifest, root = two_of_three
    (root / "runs" / "s1.cmd").write_text("OMP_NUM_THREADS=1 .venv/bin/python recipes/pusht/"
                                          "train.py algo=srfmp seed=1 lr=1e-3\n")
    text = pc.build(manifest, root, "python recipes/paper_comparison.py")
    s0 = _line(text, "  - `runs/s0` (seed 0)")[0]
    assert "evaluated by `python recipes/pusht/eval.py checkpoint=x/best.pt`" in s0
    assert s0.endswith("training: `.venv/bin/python recipes/pusht/train.py algo=srfmp seed=0 "
                       "out_dir=runs/s0`")
    s1 = _line(text, "  - `runs/s1` (seed 1)")[0]  # the .cmd beside the folder wins
    assert s1.endswith("training (from `runs/s1.cmd`): `OMP_NUM_THREADS=1 .venv/bin/python "
                       "recipes/pusht/train.py algo=srfmp seed=1 lr=1e-3`")
    # without a .cmd, the command.txt that train.py writes into the folder
    (root / "runs" / "s0" / "command.txt").write_text(
        "OMP_NUM_THREADS=1 .venv/bin/python recipes/pusht/train.py seed=0 out_dir=runs/s0\n")
    text = pc.build(manifest, root, "python recipes/paper_comparison.py")
    assert _line(text, "  - `runs/s0` (seed 0)")[0].endswith(
        "training (from `runs/s0/command.txt`): `OMP_NUM_THREADS=1 .venv/bin/python "
        "recipes/pusht/train.py seed=0 out_dir=runs/s0`")
    # a resumed run's file holds its commands one per line, each quoted on its own
    (root / "runs" / "s1.cmd").write_text("train.py seed=1 train.max_minutes=60\n"
                                          "train.py resume=runs/s1 train.max_minutes=600\n")
    text = pc.build(manifest, root, "python recipes/paper_comparison.py")
    s1 = _line(text, "  - `runs/s1` (seed 1)")[0]
    assert s1.endswith("training (from `runs/s1.cmd`): `train.py seed=1 train.max_minutes=60`, "
                       "then `train.py resume=runs/s1 train.max_minutes=600`")
    assert _line(text, "  - `runs/s2` (seed 2)") == [
        "  - `runs/s2` (seed 2): not run; training: `.venv/bin/python recipes/pusht/train.py "
        "algo=srfmp seed=2 out_dir=runs/s2`"]
    # seeds not run yet share one line with the manifest's command
    assert _line(text, "  - `runs/p{seed}`") == [
        "  - `runs/p{seed}` for seeds 0, 1: not run; training: `train.py lr=1e-4 seed={seed}`"]
    assert _line(text, "- [1] ")[0] == "- [1] SRFMP, ours, paper settings (`paper_runs`)"


def test_folders_without_evaluation_and_skipped_settings_say_so(tmp_path):
    root = tmp_path / "repo"
    (root / "runs" / "training").mkdir(parents=True)  # a run still training: no eval/ yet
    _eval_csv(root / "runs" / "partial", [(1, 1.0, 1.0, 0.5)], metric="success")
    runs = {"training": {"recipe": "pusht", "folder": "runs/training", "command": "train.py"},
            "partial": {"recipe": "robosuite", "folder": "runs/partial", "command": "train.py"}}
    table = _sweep([{"policy": "Lift, SRFMP", "paper": "robomimic_state Lift/srfmp",
                     "paper_settings": "training", "tuned": "partial"}])
    text = pc.build(_manifest(tmp_path, runs, [table]), root, "cmd")
    rows = _line(text, "| Lift, SRFMP |")
    assert rows[0] == ("| Lift, SRFMP | 1 | 1 | 1.00 | 1.000 ± 0.000 | no evaluation yet [1] "
                       "| 0.500 [2] |")
    assert rows[1] == ("| Lift, SRFMP | 3 | 1 | - | 0.992 ± 0.010 | no evaluation yet [1] "
                       "| not evaluated at this setting [2] |")
    assert "`runs/training`: exists, no evaluation yet; training: `train.py`" in text


def test_a_row_without_a_group_for_a_column_and_without_paper_figure(tmp_path):
    runs = {"a": {"recipe": "pusht", "folder": "runs/a", "command": "train.py"}}
    table = _sweep([{"policy": "CP", "paper": None, "ours": "a"}], settings=[(1, 1.0)],
                   columns={"paper_settings": "ours, paper settings", "ours": "ours"})
    text = pc.build(_manifest(tmp_path, runs, [table]), tmp_path, "cmd")
    assert _line(text, "| CP |") == ["| CP | 1 | 1 | - | - | - | not run [1] |"]


def test_the_report_command_heads_the_written_file(two_of_three, tmp_path):
    manifest, root = two_of_three
    out = tmp_path / "results" / "paper_comparison.md"
    argv = ["--manifest", str(manifest), "--root", str(root), "--out", str(out)]
    pc.main(argv)
    lines = out.read_text().splitlines()
    assert lines[0] == "# The paper's claims beside ours"
    assert lines[2].startswith("Generated by `python recipes/paper_comparison.py "
                               + " ".join(argv) + "`")


def test_records_keep_the_report_without_the_run_folders(two_of_three, tmp_path):
    manifest, root = two_of_three
    (root / "runs" / "s1.cmd").write_text("train.py seed=1 lr=1e-3\n")
    (root / "runs" / "s0" / "best.pt").write_bytes(b"weights")  # never recorded
    (root / "runs" / "s0" / "config.yaml").write_text("seed: 0\n")
    (root / "runs" / "s2").mkdir()  # still training: nothing of it is recorded
    (root / "runs" / "s2" / "config.yaml").write_text("seed: 2\n")
    (root / "runs" / "s2.cmd").write_text("train.py seed=2\n")
    records = tmp_path / "records"
    keep = records / "runs" / "other" / "eval" / "eval.csv"  # a record of another run
    keep.parent.mkdir(parents=True)
    keep.write_text("# kept\n")
    written = pc.record_runs(pc.load_manifest(manifest)[0], root, records)
    assert sorted(p.relative_to(records).as_posix() for p in written) == [
        "runs/s0/config.yaml", "runs/s0/eval/eval.csv", "runs/s1.cmd", "runs/s1/eval/eval.csv"]
    assert keep.read_text() == "# kept\n"
    assert not (records / "runs" / "s0" / "best.pt").exists()
    assert not list(records.rglob("*.tmp*"))
    live = pc.build(manifest, root, "cmd", records)
    # the run folders gone: the same cells, read from the records
    empty = tmp_path / "clone"
    empty.mkdir()
    kept = pc.build(manifest, empty, "cmd", records)
    assert _line(kept, "| SRFMP |") == _line(live, "| SRFMP |")
    s1 = _line(kept, "  - `runs/s1` (seed 1)")[0]
    assert "training (from `runs/s1.cmd`): `train.py seed=1 lr=1e-3`" in s1
    assert s1.endswith(f"read from its record `{records / 'runs/s1/eval/eval.csv'}`")
    assert "read from its record" not in live  # a folder that exists is read, not its record
    # without records the same clone reads "not run"
    assert _line(pc.build(manifest, empty, "cmd"), "| SRFMP |")[0].endswith(
        "| not run [1] | not run [2] |")


def test_a_transcribed_record_names_its_source(two_of_three, tmp_path):
    manifest, _ = two_of_three
    records = tmp_path / "records"
    _eval_csv(records / "runs" / "s0", [(1, 1.0, 0.4, 0.61)])
    table = records / "runs" / "s0" / "eval" / "eval.csv"
    lines = table.read_text().splitlines()
    table.write_text("\n".join([lines[0], "# transcribed from results/pusht.md at commit "
                                 "abc1234: the run folder was not kept", *lines[1:]]) + "\n")
    text = pc.build(manifest, tmp_path / "clone", "cmd", records)
    assert _line(text, "| SRFMP | 1 |")[0].endswith("| 0.610 (1 of 3 runs) [2] |")
    s0 = _line(text, "  - `runs/s0` (seed 0)")[0]
    assert "evaluated by `python recipes/pusht/eval.py checkpoint=x/best.pt`" in s0
    assert s0.endswith("(transcribed from results/pusht.md at commit abc1234: the run folder "
                       "was not kept)")


def test_a_list_of_files_reads_the_first_one_each_folder_holds(tmp_path):
    """A checkpoint re-evaluated into its own file beside runs whose training evaluates."""
    root, records = tmp_path / "repo", tmp_path / "records"
    _eval_csv(root / "runs" / "s0", [(1, 1.0, 0.4, 0.1), (3, 1.0, 1.0, 0.2)])  # superseded
    again = root / "runs" / "s0" / "again"
    again.mkdir()
    (again / "eval.csv").write_text("# eval.py tau_max=trained\nalgo,nfe,t_end,t_reached,score\n"
                                    "srfmp,3,1.0,1.0,0.9\n")
    _eval_csv(root / "runs" / "s1", [(1, 1.0, 0.4, 0.5), (3, 1.0, 1.0, 0.7)])
    runs = {"g": {"recipe": "pusht", "folder": "runs/s{seed}", "seeds": [0, 1, 2],
                  "command": PUSHT_CMD, "file": ["again/eval.csv", "eval/eval.csv"]}}
    manifest = _manifest(tmp_path, runs, [_sweep([{"policy": "SRFMP", "paper": None,
                                                   "ours": "g"}], columns={"ours": "ours"})])
    text = pc.build(manifest, root, "cmd")
    assert _line(text, "| SRFMP |") == [
        "| SRFMP | 1 | 1 | 0.40 | - | 0.500 (1 of 3 runs) [1] |",
        "| SRFMP | 3 | 1 | 1.00 | - | 0.800 ± 0.141 (2 of 3 runs) [1] |"]
    assert "evaluated by `eval.py tau_max=trained`" in _line(text, "  - `runs/s0` (seed 0)")[0]
    written = pc.record_runs(pc.load_manifest(manifest)[0], root, records)
    assert sorted(p.relative_to(records).as_posix() for p in written) == [
        "runs/s0/again/eval.csv", "runs/s1/eval/eval.csv"]
    assert _line(pc.build(manifest, tmp_path / "clone", "cmd", records), "| SRFMP |") == \
        _line(text, "| SRFMP |")
    (root / "runs" / "s2").mkdir()
    assert any("runs/s2 exists without its again/eval.csv or eval/eval.csv" in line
               for line in pc.todo(pc.load_manifest(manifest)[0], root))
    with pytest.raises(ValueError, match=r"runs.g.file: expected a path or a list of paths"):
        pc.load_manifest(_manifest(tmp_path, {"g": {**runs["g"], "file": []}}, []))


def test_main_records_then_reports(two_of_three, tmp_path):
    manifest, root = two_of_three
    records, out = tmp_path / "records", tmp_path / "report.md"
    pc.main(["--manifest", str(manifest), "--root", str(root), "--records", str(records),
             "--record", "--out", str(out)])
    assert (records / "runs" / "s0" / "eval" / "eval.csv").read_text() == (
        root / "runs" / "s0" / "eval" / "eval.csv").read_text()
    assert not (records / "runs" / "s0" / "command.txt").exists()  # the folder has none
    (root / "runs" / "s0" / "command.txt").write_text("train.py seed=0\n")
    pc.main(["--manifest", str(manifest), "--root", str(root), "--records", str(records),
             "--record"])
    assert (records / "runs" / "s0" / "command.txt").read_text() == "train.py seed=0\n"
    assert "its record under" in out.read_text().splitlines()[2]
    with pytest.raises(SystemExit):
        pc.main(["--manifest", str(manifest), "--record", "--no-records"])



def test_todo_lists_the_missing_jobs_teachers_first(tmp_path, capsys):
    root = tmp_path / "repo"
    _eval_csv(root / "runs" / "t0", [(1, 1.0, 1.0, 0.5)])           # teacher seed 0: done
    (root / "runs" / "e0").mkdir(parents=True)                      # trained, not evaluated
    (root / "runs" / "e0" / "last.pt").write_bytes(b"")
    (root / "runs" / "p0").mkdir(parents=True)                      # nothing to resume
    runs = {"student": {"recipe": "pusht", "folder": "runs/s{seed}", "seeds": [0, 1],
                        "command": "train.py algo=cp teacher=runs/t{seed}/best.pt "
                                   "out_dir=runs/s{seed}"},
            "teacher": {"recipe": "pusht", "folder": "runs/t{seed}", "seeds": [0, 1],
                        "command": "train.py algo=ddim out_dir=runs/t{seed}"},
            "eff": {"recipe": "robosuite", "file": "efficiency.csv", "folder": "runs/e{seed}",
                    "seeds": [0, 1], "command": "train.py out_dir=runs/e{seed}",
                    "evaluate": "efficiency.py runs/e{seed}"},
            "plain": {"recipe": "pusht", "folder": "runs/p{seed}", "seeds": [0],
                      "command": "train.py out_dir=runs/p{seed}"},
            "same_folder": {"recipe": "pusht", "folder": "runs/t{seed}", "seeds": [1],
                            "command": "train.py algo=ddim out_dir=runs/t{seed}"},
            "unnamed": {"recipe": "pusht", "folder": "runs/u", "command": "train.py seed=3"}}
    table = _sweep([{"policy": "SRFMP", "paper": "pusht_nfe srfmp", "tuned": "teacher"}],
                   columns={"tuned": "ours, tuned"})
    manifest = _manifest(tmp_path, runs, [table])
    groups, _ = pc.load_manifest(manifest)
    later = (root / "runs" / "e0" / "last.pt").stat().st_mtime + 3600
    jobs = pc.todo(groups, root, now=later)
    assert jobs == [
        "train.py algo=cp teacher=runs/t0/best.pt out_dir=runs/s0",  # its teacher is done
        "train.py algo=ddim out_dir=runs/t1",       # before its student; one job for 2 groups
        "train.py algo=cp teacher=runs/t1/best.pt out_dir=runs/s1",
        "train.py out_dir=runs/e0 resume=runs/e0 && efficiency.py runs/e0",  # continued
        "train.py out_dir=runs/e1 && efficiency.py runs/e1",
        "# runs/p0 exists without its eval/eval.csv or a last.pt to resume: move it aside, "
        "then: train.py out_dir=runs/p0",
        "# runs/u: its command does not name the folder, so its run would not be found; give "
        "it out_dir=runs/u: train.py seed=3"]
    # a folder written to a minute ago may still be training: its job is commented out
    soon = pc.todo(groups, root, now=later - 3600 + 60)
    assert soon[3] == ("# runs/e0 was written to 1 min ago and may still be training; once it "
                       "has stopped: train.py out_dir=runs/e0 resume=runs/e0 && efficiency.py "
                       "runs/e0")
    # a record counts as done, but a teacher kept only as a record is trained again
    records = tmp_path / "records"
    _eval_csv(records / "runs" / "s1", [(1, 1.0, 1.0, 0.5)])
    _eval_csv(records / "runs" / "t1", [(1, 1.0, 1.0, 0.5)])
    assert not any("runs/s1" in j or "out_dir=runs/t1" in j
                   for j in pc.todo(groups, root, records, now=later))
    shutil.rmtree(records / "runs" / "s1")
    again = pc.todo(groups, root, records, now=later)
    assert again[:3] == [
        "train.py algo=cp teacher=runs/t0/best.pt out_dir=runs/s0",
        "train.py algo=ddim out_dir=runs/t1  # again: runs/t1 is kept only as a record, and "
        "runs/s1 reads it",
        "train.py algo=cp teacher=runs/t1/best.pt out_dir=runs/s1"]
    # a dependency is a folder named as a path, not a prefix of another name
    assert not pc._needs("train.py teacher=runs/t10/best.pt", "runs/t1")
    assert pc._needs("train.py teacher='./runs/t1/best.pt'", "runs/t1")
    assert pc._needs('train.py teacher="runs/t1"', "runs/t1")
    text = pc.main(["--manifest", str(manifest), "--root", str(root), "--no-records", "--todo"])
    assert len(text.splitlines()) == len(jobs) and capsys.readouterr().out == text
    with pytest.raises(SystemExit):
        pc.main(["--manifest", str(manifest), "--todo", "--record"])
    cyclic = {"a": {"recipe": "pusht", "folder": "runs/a", "command": "x runs/b/best.pt runs/a"},
              "b": {"recipe": "pusht", "folder": "runs/b", "command": "x runs/a/best.pt runs/b"}}
    table["rows"][0]["tuned"] = "a"
    groups, _ = pc.load_manifest(_manifest(tmp_path, cyclic, [table]))
    with pytest.raises(ValueError, match="runs/a, runs/b"):
        pc.todo(groups, root)


def _efficiency(folder: Path, seed: int, successes: dict[int, float], task="Lift",
                algo="srfmp") -> None:
    folder.mkdir(parents=True)
    lines = ["task,algo,seed,epoch,nfe,t_end,t_reached,success"]
    for epoch, s in successes.items():
        lines += [f"{task},{algo},{seed},{epoch},3,1.0,1.0,{s}",
                  f"{task},{algo},{seed},{epoch},1,1.0,0.4,0.0",  # other NFE, other T: not read
                  f"{task},{algo},{seed},{epoch},3,1.6,1.6,0.0"]
    (folder / "efficiency.csv").write_text("\n".join(lines) + "\n")


def _efficiency_manifest(tmp_path: Path) -> Path:
    runs = {"eff": {"recipe": "robosuite", "file": "efficiency.csv", "folder": "runs/e{seed}",
                    "seeds": [0, 1, 2], "command": "train.py train.epochs=50 seed={seed}",
                    "evaluate": "efficiency.py runs/e{seed}"}}
    table = {"title": "Training efficiency", "kind": "efficiency", "claim": "fast", "nfe": 3,
             "epochs": [10, 20, 30],
             "rows": [{"task": "Lift", "algo": "srfmp", "policy": "Lift, SRFMP", "runs": "eff"},
                      {"task": "Lift", "algo": "ddim", "policy": "Lift, DDIM", "runs": "eff_dp"},
                      {"task": "ToolHang", "algo": "srfmp", "policy": "Tool Hang, SRFMP",
                       "runs": "eff_dp"}]}
    runs["eff_dp"] = {**runs["eff"], "folder": "runs/d{seed}", "seeds": [0]}
    return _manifest(tmp_path, runs, [table])


def test_efficiency_table_averages_the_seeds_at_each_epoch(tmp_path):
    root = tmp_path / "repo"
    _efficiency(root / "runs" / "e0", 0, {10: 0.5, 20: 1.0})
    _efficiency(root / "runs" / "e1", 1, {10: 0.7, 20: 1.0})
    (root / "runs" / "e2").mkdir()  # still training: no efficiency.csv yet
    text = pc.build(_efficiency_manifest(tmp_path), root, "cmd")
    # the paper at epoch 50: its NFE table's 50-epoch flows at NFE 3 (Lift SRFMP 0.992 ± 0.010);
    # none for DP, whose rows there are trained 300 epochs
    assert _line(text, "| Lift, SRFMP |") == [
        "| Lift, SRFMP | 3 | 1.00 | high success after 20 epochs | 0.992 ± 0.010 | 0.600 ± 0.141 "
        "(2 of 3 runs) [1] | 1.000 ± 0.000 (2 of 3 runs) [1] | not evaluated at this setting [1] |"]
    assert _line(text, "| Lift, DDIM |") == [
        "| Lift, DDIM | 3 | - | success still low after 50 epochs | - | not run [2] | "
        "not run [2] | not run [2] |"]
    # Tool Hang's SRFMP row in the NFE table is a 100-epoch model: no epoch-50 figure
    assert _line(text, "| Tool Hang, SRFMP |") == [
        "| Tool Hang, SRFMP | 3 | - | - | - | not run [2] | not run [2] | not run [2] |"]
    assert _line(text, "  - `runs/e2` (seed 2)") == [
        "  - `runs/e2` (seed 2): exists, no evaluation yet; training: `train.py train.epochs=50 "
        "seed=2`; evaluation: `efficiency.py runs/e2`"]
    assert _line(text, "  - `runs/e0` (seed 0)")[0].endswith(
        "evaluated; training: `train.py train.epochs=50 seed=0`")


def test_efficiency_files_are_checked(tmp_path):
    root = tmp_path / "repo"
    _efficiency(root / "runs" / "e0", 0, {10: 0.5}, task="PickPlaceCan")
    with pytest.raises(ValueError, match=r"e0/efficiency.csv: a row of PickPlaceCan/srfmp"):
        pc.build(_efficiency_manifest(tmp_path), root, "cmd")
    (root / "runs" / "e0" / "efficiency.csv").write_text("task,algo,epoch,success\n"
                                                         "Lift,srfmp,10,0.5\n")
    with pytest.raises(ValueError, match=r"missing columns \['seed', 'nfe'\]"):
        pc.build(_efficiency_manifest(tmp_path), root, "cmd")


def test_epoch_time_table_reads_the_benchmark_or_says_not_run(tmp_path):
    table = {"title": "Training time per epoch", "kind": "epoch_time", "claim": "CP is 2x",
             "source": "results/epoch_time.md", "command": "epoch_time.py --out x"}
    manifest = _manifest(tmp_path, {}, [table])
    text = pc.build(manifest, tmp_path, "cmd")
    assert _line(text, "| CP |") == [
        "| CP | 31.44 ± 0.27 | 102.86 ± 0.61 | 1.96x / 1.93x | not run | not run |"]
    (tmp_path / "results").mkdir()
    (tmp_path / "results" / "epoch_time.md").write_text(
        "# t\n\n| algorithm | parameters | s/step (median) | steps/epoch | s/epoch | vs DDIM |\n"
        "|---|---|---|---|---|---|\n| ddim | 4M | 0.5 | 96 | 46.32 | 1.00x |\n"
        "| cp | 4M | 0.8 | 96 | 75.77 | 1.64x |\n\nRows:\n")
    text = pc.build(manifest, tmp_path, "cmd")
    assert _line(text, "| CP |")[0].endswith("| 75.77 | 1.64x |")
    assert _line(text, "| RFMP |")[0].endswith("| - | - |")  # not in that benchmark run


def test_manifest_errors_name_the_entry(tmp_path):
    runs = {"a": {"recipe": "pusht", "folder": "runs/a", "command": "train.py"}}
    with pytest.raises(ValueError, match="names run group 'b'"):
        pc.load_manifest(_manifest(tmp_path, runs, [_sweep([{"policy": "x", "tuned": "b"}])]))
    with pytest.raises(ValueError, match="paper table 'pusht_nfe' has no row 'cp'"):
        pc.load_manifest(_manifest(tmp_path, runs, [_sweep([{"policy": "x", "paper":
                                                             "pusht_nfe cp"}])]))
    bad = {"a": {"recipe": "pusht", "folder": "runs/a", "seeds": [0, 1], "command": "t"}}
    with pytest.raises(ValueError, match="several seeds share one folder"):
        pc.load_manifest(_manifest(tmp_path, bad, []))
    with pytest.raises(ValueError, match=r"missing \['settings'\]"):
        table = _sweep([])
        del table["settings"]
        pc.load_manifest(_manifest(tmp_path, runs, [table]))
    with pytest.raises(ValueError, match=r"runs.a: missing 'command'"):
        pc.load_manifest(_manifest(tmp_path, {"a": {"recipe": "pusht", "folder": "x"}}, []))


def test_the_shipped_manifest_covers_every_claim_and_references_resolve():
    groups, tables = pc.load_manifest(pc.MANIFEST)
    titles = " / ".join(t["title"] for t in tables)
    for claim in ("Push-T NFE sweep", "Integration time", "Sphere Push-T priors",
                  "robomimic NFE sweep", "Franka Kitchen NFE sweep", "Training efficiency",
                  "Consistency Policy", "Orientation geometry"):
        assert claim in titles
    time_table = next(t for t in tables if t["title"].startswith("Integration time"))
    assert time_table["settings"] == [[3, 1.0], [3, 1.2], [4, 1.6]]  # the paper's own pairs
    assert all("{seed}" in g.command_template for g in groups.values()
               if len(g.seeds) > 1)


def test_paper_module_gives_both_push_t_tables_to_the_recipes():
    assert paper.pusht_euclidean("srfmp") == {
        (1, 1.0): 0.875, (3, 1.0): 0.851, (5, 1.0): 0.837, (10, 1.0): 0.856,
        (3, 1.2): 0.851, (4, 1.6): 0.829}
    assert paper.pusht_euclidean("rfmp")[(4, 1.6)] == 0.191
    assert paper.PUSHT_TIME.figure("euclidean/srfmp", 3, 1.0) == 0.862
    assert paper.robomimic_state("NutAssemblySquare", "rfmp")[(3, 1.0)] == 0.920
    assert paper.ROBOMIMIC_STATE.cell("ToolHang/srfmp", 1, 1.0) == "0.240 ± 0.028"
    with pytest.raises(KeyError, match="no row 'x'"):
        paper.PUSHT_NFE.figure("x", 1, 1.0)


def test_a_fresh_pusht_eval_prints_the_papers_figures_at_t_1_2_and_1_6(tmp_path):
    utils = load_script("pusht", "utils")
    cfg = compose("pusht", ["algo=rfmp"])
    task = utils.eval_task(cfg)
    rows = [{"algo": "rfmp", "nfe": n, "t_end": t, "t_reached": t, "score": 0.5,
             "score_std": 0.1} for n, t in ((3, 1.0), (3, 1.2), (4, 1.6))]
    md = write_tables(rows, tmp_path, title="t", command="c",
                      columns=[Column("score", "score", paper=True)], labels=["algo"],
                      paper=task.paper, time_table=cfg.eval.time_table).read_text()
    assert "| paper | 0.855 | 0.492 | 0.191 |" in md
    robosuite = load_script("robosuite", "utils")
    assert robosuite.PAPER[("Lift", "ddim")][(1, 1.0)] == 0.008

