"""recipes/pusht/utils.py: the paper's Push-T figures beside a run's evaluation table, for every
space, algorithm and sphere prior the paper reports, and none (nor a note about them) where it
reports none."""

from __future__ import annotations

import pytest
from recipe_loader import compose, load_script

from rfmp_rl.eval import Column, write_tables


@pytest.fixture(scope="module")
def utils():
    return load_script("pusht", "utils")


def _time_table(task, cfg, tmp_path) -> str:
    """The evaluation table of a sweep at the paper's integration-time pairs."""
    rows = [{"algo": cfg.algo, "nfe": n, "t_end": t, "t_reached": t, "score": 0.5}
            for n, t in ((1, 1.0), (3, 1.0), (3, 1.2), (4, 1.6))]
    return write_tables(rows, tmp_path, title="t", command="c",
                        columns=[Column("score", "score", paper=True)], labels=["algo"],
                        paper=task.paper, time_table=cfg.eval.time_table,
                        time_paper=task.time_paper, notes=task.notes).read_text()


def test_euclidean_srfmp_gives_both_tables_figures_at_nfe_3_t_1(utils, tmp_path):
    cfg = compose("pusht", ["algo=srfmp"])
    md = _time_table(utils.eval_task(cfg), cfg, tmp_path)
    assert "| srfmp | 3 | 1.2 | 1.20 | 0.500 | 0.851 |" in md
    assert "| srfmp | 4 | 1.6 | 1.60 | 0.500 | 0.829 |" in md
    # the NFE table's 0.851 and the integration-time table's 0.862 at NFE 3, T 1
    assert "| paper | 0.851 / 0.862 | 0.851 | 0.829 |" in md
    assert "paper: the paper's Euclidean Push-T score at that setting" in md


@pytest.mark.parametrize("prior, nfe1, time_row", [
    ("uniform", "0.772", "| paper | 0.736 / 0.727 | 0.736 | 0.685 |"),
    ("wrapped", "0.707", "| paper | 0.706 / 0.727 | 0.736 | 0.685 |"),
])
def test_sphere_runs_get_the_prior_table_row_of_their_prior(utils, tmp_path, prior, nfe1,
                                                             time_row):
    cfg = compose("pusht", ["algo=srfmp", "space=sphere", f"model.prior_sphere={prior}"])
    task = utils.eval_task(cfg)
    md = _time_table(task, cfg, tmp_path)
    assert f"| srfmp | 1 | 1 | 1.00 | 0.500 | {nfe1} |" in md and time_row in md
    row = {"uniform": "SRFMP sphere uniform", "wrapped": "SRFMP sphere Gaussian"}[prior]
    assert f'row "{row}"' in task.notes[0] and "it states no prior" in task.notes[0]


def test_sphere_ddim_is_set_beside_dps_euclidean_gaussian(utils):
    task = utils.eval_task(compose("pusht", ["algo=ddim", "space=sphere"]))
    assert task.paper == {(1, 1.0): 0.227, (3, 1.0): 0.796, (5, 1.0): 0.813, (10, 1.0): 0.885}
    assert 'row "DP euclidean Gaussian"' in task.notes[0]


def test_consistency_policy_has_no_paper_figure_and_no_note_about_one(utils, tmp_path):
    cfg = compose("pusht", ["algo=cp"])
    task = utils.eval_task(cfg)
    assert task.paper == {} and task.time_paper == {} and task.notes == []
    assert "paper" not in _time_table(task, cfg, tmp_path)
