"""Smoke tests of the kitchen recipe: a tiny expert dataset (Minari layout), a few training
steps of each algorithm on R3 x S3 x R2 and a 2-seed evaluation with per-subtask rates; eval.py
re-evaluates a checkpoint."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import pytest
from recipe_loader import compose, load_recipe

from rfmp_rl.eval import read_table

pytest.importorskip("gymnasium_robotics")
pytest.importorskip("minari")

ROOT = Path(__file__).resolve().parents[2]
pytestmark = pytest.mark.slow

TINY = [
    "data.val_episodes=1", "train.steps=2", "train.val_every=1", "train.val_batches=1",
    "train.batch_size=4", "train.log_every=1", "optim.warmup_steps=1", "eval.seeds=2",
    "eval.nfes=[1]", "eval.max_steps=10", "model.down_dims=[16,32]", "model.horizon=16",
    "model.action_steps=8", "threads=1",
]


@pytest.fixture(scope="module")
def recipe():
    yield from load_recipe("kitchen")


@pytest.fixture(scope="module")
def dataset(recipe, tmp_path_factory):
    """Two copies of one expert episode, written as the recipe's expert would."""
    sys.path.insert(0, str(ROOT / "recipes" / "kitchen"))
    try:
        import experts
    finally:
        sys.path.remove(str(ROOT / "recipes" / "kitchen"))
    from rfmp_rl.envs.kitchen import KitchenInstance

    inst = KitchenInstance()
    rec = experts.run_expert_episode(inst, experts.KitchenExpert(), 0)
    inst.close()
    rec["seed"] = 0
    path = tmp_path_factory.mktemp("kitchen") / "kitchen-expert-v0"
    experts.write_minari_kitchen(path, [rec, rec])
    return path


@pytest.mark.parametrize("algo", ["srfmp", "rfmp", "ddim"])
def test_trains_and_evaluates(recipe, dataset, tmp_path, algo):
    cfg = compose("kitchen", [f"algo={algo}", f"out_dir={tmp_path}", f"data.path={dataset}",
                              *TINY])
    run = recipe["train"].train(cfg)
    for name in ("best.pt", "last.pt", "config.yaml", "history.json", "eval/eval.csv",
                 "eval/eval.md"):
        assert (run / name).is_file() and (run / name).stat().st_size > 0, name
    (row,) = read_table(run / "eval" / "eval.csv")
    assert row["task"] == "kitchen" and row["algo"] == algo and row["seeds"] == "100000-100001"
    for key in ("success", "microwave", "kettle", "light_switch", "slide_cabinet"):
        assert 0.0 <= float(row[key]) <= 1.0, key
    assert int(row["env_steps"]) > 0 and math.isfinite(float(row["jerk"]))
    assert float(row["quat_norm_err"]) <= 1e-5  # every executed quaternion on S^3
    model_cfg = recipe["utils"].make_model_config(cfg)
    assert model_cfg.obs_dim == 66 and model_cfg.action_manifold == "R3 x S3 x R2"
    paper = {"srfmp": "1.000", "rfmp": "0.040", "ddim": "0.000"}[algo]  # its NFE-1 figure
    assert f"| {paper} |" in (run / "eval" / "eval.md").read_text()


def test_paper_settings_in_the_config():
    cfg = compose("kitchen", [])
    assert cfg.model.horizon == 216 and cfg.model.action_steps == 108  # 216 x 9 = 1944-D
    assert cfg.model.obs_horizon == 2 and cfg.model.prior_sphere == "wrapped"
    assert list(cfg.eval.nfes) == [1, 2, 3, 5, 10] and cfg.eval.seeds == 50


def test_eval_script(recipe, dataset, tmp_path):
    cfg = compose("kitchen", [f"out_dir={tmp_path / 'run'}", "eval.final_eval=false",
                              f"data.path={dataset}", *TINY])
    run = recipe["train"].train(cfg)
    rows = recipe["eval"].evaluate_checkpoint(compose("kitchen", [
        f"checkpoint={run / 'best.pt'}", "eval.seeds=2", "eval.seed_start=500",
        "eval.nfes=[1,2]", "eval.max_steps=6", f"eval.out={tmp_path / 'ev'}", "threads=1"]))
    assert [r["nfe"] for r in rows] == [1, 2] and all(r["seeds"] == "500-501" for r in rows)
    assert all(len(r["per_seed"]["kettle"]) == 2 for r in rows)


def test_missing_dataset_without_generation_names_the_folder(recipe, tmp_path):
    cfg = compose("kitchen", [f"data.path={tmp_path / 'none'}", "data.generate=false",
                              f"out_dir={tmp_path / 'run'}", *TINY])
    with pytest.raises(FileNotFoundError, match="none"):
        recipe["train"].train(cfg)


def test_the_recipes_own_dataset_must_hold_the_demos_asked_for(recipe, dataset, tmp_path,
                                                              monkeypatch):
    # the expert's dataset at its default place (data/kitchen/kitchen-expert-v0) holds two
    # episodes: data.demos=100 is refused, not trained on two; data.path is read as it is
    import shutil

    utils = recipe["utils"]
    default = tmp_path / "data" / "kitchen" / "kitchen-expert-v0"
    shutil.copytree(dataset, default)
    monkeypatch.setattr(utils, "ROOT", tmp_path)
    with pytest.raises(ValueError, match=f"{default} holds 2 demonstrations and data.demos=100"):
        utils.ensure_demos(compose("kitchen", []))
    assert utils.ensure_demos(compose("kitchen", ["data.demos=2"])) == default
    assert utils.ensure_demos(compose("kitchen", [f"data.path={dataset}"])) == dataset
