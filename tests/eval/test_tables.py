"""The table writer: the command on the first line, every row naming its NFE, the T asked for
and the T reached, the paper's figures beside ours, the CSV round trip, and the plot."""

from __future__ import annotations

import math

import pytest

from rfmp_rl.eval import Column, plot_sweep, read_table, setting_label, write_tables

COMMAND = "python recipes/pusht/eval.py checkpoint=run/best.pt eval.nfes=[1,3]"


def _row(nfe, t_end, t_reached, score, err=float("nan")):
    return {"algo": "srfmp", "nfe": nfe, "t_end": t_end, "t_reached": t_reached,
            "score": score, "err": err, "env_steps": 100, "seconds": 2.0, "seeds": "0-1",
            "per_seed": {"seed": [0, 1], "score": [score, score]}}


ROWS = [_row(1, 1.0, 0.4, 0.75), _row(3, 1.0, 1.0, 0.8125), _row(1, 1.6, 0.4, 0.75),
        _row(4, 1.6, 1.6, 0.5, 1e-7)]
COLUMNS = [Column("score", "score", paper=True), Column("err", "on-S^2 err", "{:.1e}")]


def test_markdown_opens_with_the_command_and_names_every_setting(tmp_path):
    md = write_tables(ROWS, tmp_path / "out", title="Push-T", command=COMMAND, columns=COLUMNS,
                      labels=["algo"], paper={(3, 1.0): 0.851, (1, 1.0): 0.875},
                      time_table=[[1, 1.6], [4, 1.6]], notes=["a note"])
    lines = md.read_text().splitlines()
    assert lines[0] == f"Command: `{COMMAND}`" and lines[2] == "## Push-T"
    assert lines[4] == "| algo | NFE | T | T reached | score | paper | on-S^2 err |"
    # asked for T = 1.6, the solver stopped at 0.4: both are in the row
    assert lines[6] == "| srfmp | 1 | 1 | 0.40 | 0.750 | 0.875 | - |"
    assert lines[7] == "| srfmp | 3 | 1 | 1.00 | 0.812 | 0.851 | - |"
    assert lines[8] == "| srfmp | 1 | 1.6 | 0.40 | 0.750 | - | - |"
    assert lines[9] == "| srfmp | 4 | 1.6 | 1.60 | 0.500 | - | 1.0e-07 |"
    assert "a note" in lines
    # the side-by-side table: each header cell names the NFE and the T reached (and the T asked
    # for where the solver stopped elsewhere)
    header = next(line for line in lines if line.startswith("| | NFE"))
    assert header == "| | NFE 1, T 0.40 (asked 1.6) | NFE 4, T 1.60 |"
    assert "| srfmp | 0.750 | 0.500 |" in lines
    assert not any(line.startswith("| paper |") for line in lines)  # the paper has neither


def test_csv_round_trip_with_the_command_and_the_paper_column(tmp_path):
    write_tables(ROWS, tmp_path, title="t", command=COMMAND, columns=COLUMNS,
                 paper={(1, 1.0): 0.875})
    text = (tmp_path / "eval.csv").read_text().splitlines()
    assert text[0] == f"# {COMMAND}"
    assert text[1] == "algo,nfe,t_end,t_reached,score,paper,err,env_steps,seconds,seeds"
    rows = read_table(tmp_path / "eval.csv")
    assert [(r["nfe"], r["t_end"], r["t_reached"], r["paper"]) for r in rows] == [
        ("1", "1.0", "0.4", "0.875"), ("3", "1.0", "1.0", ""), ("1", "1.6", "0.4", ""),
        ("4", "1.6", "1.6", "")]
    assert float(rows[1]["score"]) == 0.8125 and math.isnan(float(rows[0]["err"]))
    assert "per_seed" not in rows[0]


def test_without_paper_figures_there_is_no_paper_column(tmp_path):
    md = write_tables(ROWS[:1], tmp_path, title="t", command=COMMAND, columns=COLUMNS)
    assert "paper" not in md.read_text() and "paper" not in (tmp_path / "eval.csv").read_text()


def test_the_paper_row_of_the_time_table(tmp_path):
    md = write_tables(ROWS, tmp_path, title="t", command=COMMAND, columns=COLUMNS,
                      paper={(4, 1.6): 0.781}, time_table=[[3, 1.0], [4, 1.6]])
    lines = md.read_text().splitlines()
    assert "| | NFE 3, T 1.00 | NFE 4, T 1.60 |" in lines
    assert "| measured | 0.812 | 0.500 |" in lines and "| paper | - | 0.781 |" in lines


def test_bad_input_is_named(tmp_path):
    with pytest.raises(ValueError, match="no rows"):
        write_tables([], tmp_path, title="t", command=COMMAND, columns=COLUMNS)
    with pytest.raises(ValueError, match="no column is marked paper=True"):
        write_tables(ROWS, tmp_path, title="t", command=COMMAND,
                     columns=[Column("score", "score")], paper={(1, 1.0): 0.5})


def test_setting_label_names_the_time_reached():
    assert setting_label({"nfe": 3, "t_end": 1.2, "t_reached": 1.2}) == "NFE 3, T 1.20"
    assert setting_label({"nfe": 1, "t_end": 1.6, "t_reached": 0.4}) == "NFE 1, T 0.40 (asked 1.6)"


def test_plot_is_written(tmp_path):
    path = plot_sweep(ROWS, tmp_path / "eval.png", "score", ylim=(0, 1), title="t")
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and path.stat().st_size > 5000


def test_the_time_tables_paper_row_gives_both_figures_where_the_tables_differ(tmp_path):
    md = write_tables(ROWS, tmp_path, title="t", command=COMMAND, columns=COLUMNS,
                      paper={(3, 1.0): 0.851, (4, 1.6): 0.829},
                      time_paper={(3, 1.0): 0.862, (4, 1.6): 0.829},
                      time_table=[[1, 1.6], [3, 1.0], [4, 1.6]])
    lines = md.read_text().splitlines()
    assert "| 3 | 1 | 1.00 | 0.812 | 0.851 | - |" in lines  # the main table: `paper` only
    assert "| paper | - | 0.851 / 0.862 | 0.829 |" in lines
