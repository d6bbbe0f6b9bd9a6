"""recipes/pusht/report.py: the results file is rebuilt from the runs' own files, and each run's
training command reproduces every setting that differs from the recipe's config."""

from __future__ import annotations

import copy
import json
from pathlib import Path

import pytest
import yaml
from recipe_loader import load_script

ROOT = Path(__file__).resolve().parents[2]
DEFAULTS = yaml.safe_load((ROOT / "recipes" / "pusht" / "config.yaml").read_text())


@pytest.fixture(scope="module")
def report():
    return load_script("pusht", "report")


def _run(folder: Path, scores: dict[tuple[int, float], float], **changes) -> Path:
    cfg = copy.deepcopy(DEFAULTS)
    for key, value in changes.items():
        *parents, leaf = key.split("__")
        node = cfg
        for parent in parents:
            node = node[parent]
        node[leaf] = value
    cfg["out_dir"] = str(folder)
    (folder / "eval").mkdir(parents=True)
    (folder / "config.yaml").write_text(yaml.safe_dump(cfg))
    (folder / "history.json").write_text(json.dumps(
        [{"step": 100, "minutes": 1.0, "train": 1.0, "val": 0.3},
         {"step": 200, "minutes": 2.5, "train": 0.5, "val": 0.4}]))
    rows = ["algo,nfe,t_end,score"] + [f"{cfg['algo']},{n},{t},{s}" for (n, t), s in
                                       scores.items()]
    (folder / "eval" / "eval.csv").write_text("\n".join(rows) + "\n")
    (folder / "eval" / "eval.md").write_text("## Push-T eval\n\n| table |\n")
    return folder


def test_command_lists_exactly_the_settings_that_differ_from_the_recipe(report):
    cfg = copy.deepcopy(DEFAULTS)
    cfg.update(obs="image", out_dir="runs/x")
    cfg["loss"].update(t0_fraction=0.3, time_max=2.0)
    cfg["train"]["batch_size"] = 64
    cfg["eval"]["nfes"] = [1, 3]
    cfg["eval"]["time_table"] = []
    command = report.train_command(cfg)
    words = command.split()
    assert words[:2] == [".venv/bin/python", "recipes/pusht/train.py"]
    assert words[2:5] == ["algo=srfmp", "obs=image", "space=euclidean"]
    assert set(words[5:]) == {"loss.t0_fraction=0.3", "loss.time_max=2.0", "train.batch_size=64",
                              "'eval.nfes=[1,3]'", "'eval.time_table=[]'"}


def test_report_collects_runs_into_one_table_with_their_commands(report, tmp_path):
    a = _run(tmp_path / "a", {(1, 1.0): 0.9, (3, 1.0): 0.8}, loss__t0_fraction=0.3)
    b = _run(tmp_path / "b", {(1, 1.0): 0.1}, algo="ddim", train__batch_size=64)
    notes = tmp_path / "notes.md"
    notes.write_text("## Notes\nkept verbatim\n")
    out = tmp_path / "out.md"
    text = report.main([str(a), str(b), "--notes", str(notes), "--out", str(out)])
    assert out.read_text() == text
    rows = [line for line in text.splitlines() if line.startswith("| srfmp") or
            line.startswith("| ddim")]
    assert rows[0].endswith("| 0.900 | 0.800 |") and "0.3 of training times at t = 0" in rows[0]
    assert rows[1].endswith("| 0.100 | - |")
    assert "train.py algo=ddim obs=state space=euclidean train.batch_size=64`" in text
    assert "best validation loss 0.3000 at step 100" in text and "200 steps in 2.5 min" in text
    assert text.endswith("## Notes\nkept verbatim\n")


def test_a_missing_run_file_is_named(report, tmp_path):
    run = _run(tmp_path / "a", {(1, 1.0): 0.5})
    (run / "eval" / "eval.csv").unlink()
    with pytest.raises(FileNotFoundError, match=r"eval\.csv is missing"):
        report.main([str(run)])


def test_a_rollout_selected_run_names_its_selection_score_and_seeds(report, tmp_path):
    run = _run(tmp_path / "a", {(1, 1.0): 0.5}, train__select_by="rollout")
    history = json.loads((run / "history.json").read_text())
    history[0]["rollout"], history[1]["rollout"] = 0.61, 0.72  # the later, higher one is kept
    (run / "history.json").write_text(json.dumps(history))
    text = report.main([str(run)])
    # SRFMP's one selection step stops at 1 / lambda_x: the T asked and the T reached are named
    assert ("best validation rollout score 0.720 (mean max coverage over seeds 200000-200019, "
            "NFE 1, T 1 asked, T 0.40 reached) at step 200, 2.5 min" in text)
    assert "train.select_by=rollout" in text


def test_a_selection_setting_whose_t_is_reached_names_it_once(report, tmp_path):
    run = _run(tmp_path / "a", {(3, 1.0): 0.5}, algo="rfmp", train__select_by="rollout",
               select__nfe=3)
    history = json.loads((run / "history.json").read_text())
    history[0]["rollout"], history[1]["rollout"] = 0.61, 0.52
    (run / "history.json").write_text(json.dumps(history))
    assert "seeds 200000-200019, NFE 3, T=1) at step 100" in report.main([str(run)])


def test_runs_with_the_same_settings_keep_their_own_rows(report, tmp_path):
    a = _run(tmp_path / "first", {(1, 1.0): 0.9})
    b = _run(tmp_path / "second", {(1, 1.0): 0.2})
    text = report.main([str(a), str(b)])
    rows = [line for line in text.splitlines() if line.startswith("| srfmp")]
    assert rows[0].endswith("cap, seed 0 | 0.900 |")
    assert rows[1].endswith("cap, seed 0 (second) | 0.200 |")
    assert "Across training seeds" not in text  # one seed: nothing to average


def test_training_seeds_of_one_setting_are_averaged_and_others_kept_apart(report, tmp_path):
    a = _run(tmp_path / "s0", {(1, 1.0): 0.84, (3, 1.0): 0.8}, seed=0)
    b = _run(tmp_path / "s1", {(1, 1.0): 0.90, (3, 1.0): 0.7}, seed=1)
    c = _run(tmp_path / "s2", {(1, 1.0): 0.87}, seed=2)  # no NFE 3 row: no mean there
    other = _run(tmp_path / "lr", {(1, 1.0): 0.1}, seed=1, optim__lr=1e-3)  # another setting
    text = report.main([str(p) for p in (a, b, c, other)])
    summary = [line for line in text.splitlines() if line.startswith("| srfmp")]
    assert summary[0].endswith("cap, seed 0 | 0.840 | 0.800 |")
    assert summary[1].endswith("cap, seed 1 | 0.900 | 0.700 |")
    assert summary[3].endswith("cap, seed 1 (lr) | 0.100 | - |")
    seeded = [line for line in text.splitlines() if line.startswith("| s0 (0)")]
    assert seeded == ["| s0 (0), s1 (1), s2 (2) | 0.870 (0.840, 0.900, 0.870) | - |"]
    assert "lr (1)" not in text


def test_runs_of_earlier_versions_are_reported_in_todays_names(report, tmp_path):
    run = _run(tmp_path / "old", {(1, 1.0): 0.4}, algo="ddim")
    cfg = yaml.safe_load((run / "config.yaml").read_text())
    flat = {k: v for k, v in cfg.items() if k not in ("model", "loss")}
    flat.update(algo="dp", horizon=8, t0_fraction=0.0, preset="small", prior="uniform")
    (run / "config.yaml").write_text(yaml.safe_dump(flat))
    text = report.main([str(run)])
    assert "train.py algo=ddim obs=state space=euclidean model.horizon=8`" in text
    assert "| ddim state euclidean" in text


def test_a_cell_names_the_end_time_its_solver_reached(report, tmp_path):
    a = _run(tmp_path / "s0", {(1, 1.0): 0.84, (3, 1.0): 0.8}, seed=0)
    b = _run(tmp_path / "s1", {(1, 1.0): 0.90, (3, 1.0): 0.7}, seed=1)
    for run in (a, b):  # SRFMP's one step stops at 1 / lambda_x = 0.4; three steps reach T = 1
        (run / "eval" / "eval.csv").write_text(
            "algo,nfe,t_end,t_reached,score\nsrfmp,1,1.0,0.4,0.5\nsrfmp,3,1.0,1.0,0.6\n")
    text = report.main([str(a), str(b)])
    assert "| policy | NFE 1, T=1 asked | NFE 3, T=1 asked |" in text
    summary = [line for line in text.splitlines() if line.startswith("| srfmp")]
    assert summary[0].endswith("cap, seed 0 | 0.500 (T 0.40 reached) | 0.600 |")
    seeded = [line for line in text.splitlines() if line.startswith("| s0 (0)")]
    assert seeded == ["| s0 (0), s1 (1) | 0.500 (0.500, 0.500) (T 0.40 reached) "
                      "| 0.600 (0.600, 0.600) |"]


def test_the_papers_figures_stand_under_the_runs_at_its_settings(report, tmp_path):
    a = _run(tmp_path / "a", {(1, 1.0): 0.9, (3, 1.2): 0.8, (2, 1.0): 0.7})
    text = report.main([str(a)])
    paper = [line for line in text.splitlines() if line.startswith("| paper, ")]
    assert len(paper) == 1 and paper[0].startswith("| paper, SRFMP, from images (tables ")
    assert paper[0].endswith("| 0.875 | - | 0.851 |")  # NFE 2 is not in the paper's tables


def test_the_papers_figures_stand_under_the_mean_over_training_seeds(report, tmp_path):
    runs = [_run(tmp_path / f"s{seed}", {(1, 1.0): 0.8 + seed / 100, (4, 1.6): 0.7}, seed=seed)
            for seed in (0, 1)]
    lines = report.main([str(r) for r in runs]).splitlines()
    start = lines.index(next(line for line in lines if line.startswith("Across training seeds")))
    seeded = lines[start:lines.index("", start + 2)]
    assert seeded[-2].startswith("| s0 (0), s1 (1) | 0.805 (0.800, 0.810)")
    assert seeded[-1].startswith("| paper, SRFMP, from images (tables ")
    assert seeded[-1].endswith("| 0.875 | 0.829 |")


def test_sphere_runs_get_the_integration_time_figures_that_state_no_prior(report, tmp_path):
    a = _run(tmp_path / "a", {(1, 1.0): 0.7, (3, 1.0): 0.8, (3, 1.2): 0.8, (4, 1.6): 0.8},
             space="sphere", model__prior_sphere="wrapped")
    paper = [line for line in report.main([str(a)]).splitlines()
             if line.startswith("| paper, ")]
    assert len(paper) == 2
    assert paper[0].startswith("| paper, SRFMP (Gaussian prior), from images (table ")
    assert paper[0].endswith("| 0.707 | 0.706 | - | - |")
    assert paper[1].startswith("| paper, SRFMP, prior not stated, from images (table "
                               '"Influence of Integration Time"')
    assert paper[1].endswith("| - | 0.727 | 0.736 | 0.685 |")
