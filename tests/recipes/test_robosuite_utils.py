"""recipes/robosuite/utils.py: the paper's state-based robomimic figures beside a run's table, and
no note about them where the paper reports none (state-based Transport, Consistency Policy)."""

from __future__ import annotations

import pytest
from recipe_loader import compose, load_recipe


@pytest.fixture(scope="module")
def utils():
    for mods in load_recipe("robosuite"):
        yield mods["utils"]


def test_a_reported_setting_gets_the_paper_column_and_its_note(utils):
    task = utils.eval_task(compose("robosuite", ["task=Lift", "algo=ddim"]))
    assert task.paper[(1, 1.0)] == 0.008
    assert task.notes[0].startswith("paper: the paper's success rate at that setting")


@pytest.mark.parametrize("overrides", [["task=TwoArmTransport"], ["task=Lift", "algo=cp"]])
def test_an_unreported_setting_has_no_paper_column_and_no_note_about_one(utils, overrides):
    task = utils.eval_task(compose("robosuite", overrides))
    assert task.paper == {} and task.notes == []
