"""recipes/robosuite/summary.py: the per-run success table, read from the runs' own files."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import yaml
from recipe_loader import load_script


@pytest.fixture(scope="module")
def summary():
    return load_script("robosuite", "summary")


def _run(folder: Path, algo: str, success: dict[int, float], t0: float = 0.0) -> Path:
    (folder / "eval").mkdir(parents=True)
    cfg = {"task": "Lift", "algo": algo, "obs": "state", "action_space": "delta",
           "geometry": "riemannian", "t0_fraction": t0, "optim": {"lr": 1e-3}}
    (folder / "config.yaml").write_text(yaml.safe_dump(cfg))
    (folder / "history.json").write_text(json.dumps(
        [{"step": 500, "minutes": 4.0, "train": 1.0, "val": 0.5},
         {"step": 900, "minutes": 7.2, "train": 0.5, "val": 0.25}]))
    rows = ["task,algo,action_space,nfe,t_end,success"]
    rows += [f"Lift,{algo},delta,{n},1.0,{s}" for n, s in success.items()]
    rows.append(f"Lift,{algo},delta,1,1.6,0.0")  # other end times are not in the table
    (folder / "eval" / "eval.csv").write_text("\n".join(rows) + "\n")
    return folder


def test_table_has_one_row_per_run_and_every_nfe(summary, tmp_path):
    a = _run(tmp_path / "a", "dp", {1: 0.0, 3: 0.96})
    b = _run(tmp_path / "b", "srfmp", {1: 0.98, 2: 1.0}, t0=0.3)
    out = tmp_path / "table.md"
    summary.main([str(a), str(b), "--out", str(out)])
    lines = [line for line in out.read_text().splitlines() if line.startswith("| Lift")]
    # ours / the paper's (its state-based robomimic table) at the same NFE
    assert lines[0].split(" | ")[1:8] == ["DDIM", "state", "delta", "0.00 / 0.008", "-",
                                          "0.96 / 0.948", "900 steps, 7 min, lr 0.001"]
    assert lines[1].split(" | ")[1:8] == ["SRFMP", "state", "delta", "0.98 / 1.000",
                                          "1.00 / 0.992", "-",
                                          "900 steps, 7 min, lr 0.001, t0_fraction 0.3"]
    assert "Command: `python recipes/robosuite/summary.py" in out.read_text()


def test_missing_file_names_it(summary, tmp_path):
    run = _run(tmp_path / "a", "rfmp", {1: 0.5})
    (run / "history.json").unlink()
    with pytest.raises(FileNotFoundError, match="history.json"):
        summary.main([str(run)])


def test_a_cell_names_the_end_time_its_solver_reached(summary, tmp_path):
    run = _run(tmp_path / "a", "srfmp", {})
    (run / "eval" / "eval.csv").write_text(  # SRFMP: one step ends at 0.4, two at 0.8
        "task,algo,action_space,nfe,t_end,t_reached,success\n"
        "Lift,srfmp,delta,1,1.0,0.4,0.98\nLift,srfmp,delta,2,1.0,0.8,1.0\n"
        "Lift,srfmp,delta,3,1.0,1.0,1.0\n")
    text = summary.summary([run])
    assert "| NFE 1, T=1 asked | NFE 2, T=1 asked | NFE 3, T=1 asked |" in text
    row = next(line for line in text.splitlines() if line.startswith("| Lift"))
    assert row.split(" | ")[4:7] == ["0.98 / 1.000 (T 0.40 reached)",
                                     "1.00 / 0.992 (T 0.80 reached)", "1.00 / 0.992"]


def test_a_setting_the_paper_does_not_report_shows_ours_alone(summary, tmp_path):
    run = _run(tmp_path / "a", "srfmp", {1: 0.5})
    cfg = yaml.safe_load((run / "config.yaml").read_text())
    (run / "config.yaml").write_text(yaml.safe_dump({**cfg, "task": "TwoArmTransport"}))
    row = next(line for line in summary.summary([run]).splitlines()
               if line.startswith("| TwoArmTransport"))
    assert row.split(" | ")[4] == "0.50"
