"""recipes/robosuite/utils.py: the paper's state-based robomimic figures beside a run's table, and
no note about them where the paper reports none (state-based Transport, Consistency Policy); the
demonstration file that train.py reads is the one experts.py writes, and experts.py never
replaces a file it was not told to."""

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


@pytest.mark.parametrize("obs", ["state", "image"])
def test_experts_write_the_file_that_training_reads(utils, obs):
    import experts  # recipes/robosuite, on the path while `utils` lives

    cfg = compose("robosuite", ["task=MugFlip", "action_space=abs_pose", f"obs={obs}"])
    path = experts.default_demo_path("MugFlip", "abs_pose", images=obs == "image")
    assert utils.data_path(cfg) == path
    assert path.name == {"state": "mugflip_abs_pose.hdf5",
                         "image": "mugflip_abs_pose_images.hdf5"}[obs]


def test_experts_refuse_to_replace_an_existing_file(utils, tmp_path):
    import experts

    demos = tmp_path / "mine.hdf5"
    demos.write_bytes(b"a user's demonstrations")
    with pytest.raises(SystemExit, match=f"{demos} exists; give another --out, or --overwrite"):
        experts.main(["--task", "Lift", "--n", "1", "--out", str(demos)])
    assert demos.read_bytes() == b"a user's demonstrations"


def test_the_recipes_own_file_must_hold_the_demos_asked_for(utils, tmp_path, monkeypatch):
    # a file written earlier with another data.demos is not trained on silently; data.path
    # (a user's file) is read whatever it holds
    import experts
    import torch
    from tensordict import TensorDict

    from rfmp_rl.data import write_robomimic

    path = tmp_path / "lift_delta.hdf5"
    episode = TensorDict({"obs": {"robot0_eef_pos": torch.zeros(3, 3)}, "action": torch.zeros(3, 7),
                          "reward": torch.zeros(3), "done": torch.zeros(3)}, [3])
    write_robomimic(path, [episode] * 3, env_args={"env_name": "Lift", "env_type": 1,
                                                   "env_kwargs": {}})
    monkeypatch.setattr(experts, "default_demo_path", lambda *args, **kwargs: path)
    with pytest.raises(ValueError, match=f"{path} holds 3 demonstrations and data.demos=200: "
                                         "pass data.demos=3"):
        utils.ensure_demos(compose("robosuite", ["task=Lift"]))
    assert utils.ensure_demos(compose("robosuite", ["task=Lift", "data.demos=3"])) == path
    assert utils.ensure_demos(compose("robosuite", ["task=Lift", f"data.path={path}"])) == path
