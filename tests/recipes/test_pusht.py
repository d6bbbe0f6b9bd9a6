"""Smoke tests of the Push-T recipes on the real zarr: every variant (algo x obs x space) trains
a few steps, keeps a checkpoint and evaluates 2 seeds; eval.py re-evaluates a checkpoint."""

from __future__ import annotations

import json
import math
import os
import re
from pathlib import Path

import pytest
import torch
from recipe_loader import PUSHT_TINY, compose, load_recipe, pusht_marks

from rfmp_rl.checkpoint import load_checkpoint
from rfmp_rl.eval import read_table

ROOT = Path(__file__).resolve().parents[2]
RECIPE = ROOT / "recipes" / "pusht"
pytestmark = pusht_marks()


@pytest.fixture(scope="module")
def recipe():
    yield from load_recipe("pusht")


def _cfg(overrides):
    return compose("pusht", overrides)


TINY = PUSHT_TINY


def _rows(path: Path) -> list[dict]:
    return read_table(path)


@pytest.mark.parametrize("obs", ["state", "image"])
@pytest.mark.parametrize("space", ["euclidean", "sphere"])
@pytest.mark.parametrize("algo", ["rfmp", "srfmp", "ddim"])
def test_every_variant_trains_and_evaluates(recipe, tmp_path, algo, obs, space):
    cfg = _cfg([f"algo={algo}", f"obs={obs}", f"space={space}", f"out_dir={tmp_path}", *TINY])
    run = recipe["train"].train(cfg)
    for name in ("best.pt", "last.pt", "config.yaml", "history.json", "eval/eval.csv",
                 "eval/eval.md", "eval/eval.png"):
        assert (run / name).is_file() and (run / name).stat().st_size > 0, name
    assert list(run.glob("logs/**/*.csv")), "the CSV logger wrote nothing"
    (row,) = _rows(run / "eval" / "eval.csv")
    assert row["algo"] == algo and row["nfe"] == "1" and row["seeds"] == "100000-100001"
    assert 0.0 <= float(row["score"]) <= 1.0 and 0.0 <= float(row["success"]) <= 1.0
    assert int(row["env_steps"]) > 0 and math.isfinite(float(row["jerk"]))
    if space == "sphere" and algo != "ddim":
        assert float(row["manifold_err"]) <= 1e-5
    if space == "sphere" and algo == "ddim":  # projected after sampling, as the paper does
        assert float(row["manifold_err"]) <= 1e-5
    unit = "S^2 coords/s^3" if space == "sphere" else "px/s^3"  # jerk in the actions' units
    assert f"jerk ({unit})" in (run / "eval" / "eval.md").read_text()


def test_eval_script_reevaluates_a_checkpoint_with_its_own_seed_range(recipe, tmp_path):
    run = recipe["train"].train(_cfg(["algo=srfmp", f"out_dir={tmp_path / 'run'}", *TINY,
                                      "eval.final_eval=false"]))
    cfg = _cfg([f"checkpoint={run / 'best.pt'}", "eval.seeds=3", "eval.seed_start=7",
                "eval.nfes=[1,2]", "eval.t_ends=[1.0,1.6]", "eval.time_table=[[3,1.0]]",
                "eval.max_steps=10", f"eval.out={tmp_path / 'ev'}", "threads=1"])
    rows = recipe["eval"].evaluate_checkpoint(cfg)
    assert [(r["nfe"], r["t_end"]) for r in rows] == [(1, 1.0), (2, 1.0), (1, 1.6), (2, 1.6),
                                                      (3, 1.0)]
    assert all(r["seeds"] == "7-9" for r in rows)
    text = (tmp_path / "ev" / "eval.md").read_text()
    assert text.startswith("Command: `python recipes/pusht/eval.py")
    # every cell names its NFE and the end time reached: SRFMP's NFE 1 stops at 1 / lambda_x
    assert "| srfmp | 1 | 1.6 | 0.40 |" in text
    assert "Integration time" in text and "| NFE 3, T 1.00 |" in text
    csv_text = (tmp_path / "ev" / "eval.csv").read_text()
    assert csv_text.startswith("# python recipes/pusht/eval.py")


def test_a_checkpoint_of_an_earlier_version_evaluates_as_before(recipe, tmp_path):
    # earlier versions stored flat settings (horizon, t0_fraction, ...) and algo: dp
    run = recipe["train"].train(_cfg(["algo=ddim", f"out_dir={tmp_path / 'run'}", *TINY,
                                      "eval.final_eval=false"]))
    payload = torch.load(run / "best.pt", weights_only=False)
    config = payload["config"]
    flat = {**{k: v for k, v in config.items() if k not in ("model", "loss")},
            **config["model"], **config["loss"], "algo": "dp"}
    flat["preset"], flat["prior"] = flat.pop("unet_preset"), flat.pop("prior_sphere")
    del flat["time_sampling"]
    old = tmp_path / "old.pt"
    torch.save({**payload, "config": flat}, old)
    common = ["eval.seeds=2", "eval.nfes=[1]", "eval.max_steps=10", "threads=1"]
    (a,) = recipe["eval"].evaluate_checkpoint(_cfg([f"checkpoint={run / 'best.pt'}", *common,
                                                    f"eval.out={tmp_path / 'new'}"]))
    (b,) = recipe["eval"].evaluate_checkpoint(_cfg([f"checkpoint={old}", *common,
                                                    f"eval.out={tmp_path / 'old'}"]))
    assert a["algo"] == b["algo"] == "ddim"
    for key in ("seed", "score", "jerk", "success"):
        assert b["per_seed"][key] == a["per_seed"][key], key
    assert b["score"] == a["score"] and b["jerk"] == a["jerk"]


def test_algo_dp_names_its_new_name(recipe):
    with pytest.raises(ValueError, match="algo=dp is now algo=ddim"):
        recipe["utils"].check_config(_cfg(["algo=dp"]))


def test_eval_script_names_a_missing_checkpoint(recipe, tmp_path):
    with pytest.raises(SystemExit, match="no such checkpoint"):
        recipe["eval"].evaluate_checkpoint(_cfg([f"checkpoint={tmp_path / 'nope.pt'}"]))


def test_rollout_selection_keeps_the_checkpoint_with_the_best_selection_score(recipe, tmp_path):
    # Diffusion Policy keeps checkpoints by rollout score; ours rolls the EMA policy out on
    # seeds disjoint from the evaluation ones at every validation.
    cfg = _cfg(["algo=srfmp", f"out_dir={tmp_path}", *TINY, "train.steps=3",
                "train.select_by=rollout", "select.seeds=2", "select.seed_start=5",
                "eval.final_eval=false"])
    run = recipe["train"].train(cfg)
    history = json.loads((run / "history.json").read_text())
    assert [h["step"] for h in history] == [1, 2, 3]
    assert all(0.0 <= h["rollout"] <= 1.0 for h in history)
    best = max(history, key=lambda h: h["rollout"])  # the first of equal scores
    extra = torch.load(run / "best.pt", weights_only=False)["extra"]
    assert extra["step"] == best["step"] and extra["rollout_score"] == best["rollout"]
    logged = next(run.glob("logs/**/rollout_score.csv")).read_text().split()  # "step,value"
    assert [float(line.split(",")[1]) for line in logged] == pytest.approx(
        [h["rollout"] for h in history])
    # the same seeds and settings score the saved EMA weights the same again
    model, _ = load_checkpoint(run / "best.pt", use_ema=True)
    again = recipe["utils"].selection_score(cfg)(model.eval())
    assert again == pytest.approx(best["rollout"], abs=1e-6)


def test_rollout_selection_seeds_must_not_overlap_the_evaluation_seeds(recipe):
    cfg = _cfg(["train.select_by=rollout", "select.seed_start=100040"])
    with pytest.raises(ValueError, match=r"100040-100059.*overlap.*100000-100049"):
        recipe["utils"].check_config(cfg)
    with pytest.raises(ValueError, match="train.select_by"):
        recipe["utils"].check_config(_cfg(["train.select_by=loss"]))


def test_parallel_evaluation_matches_serial(recipe, tmp_path):
    # eval.workers=2: two ParallelEnv workers (3 seeds, one padding seed dropped); prior noise
    # per episode from its seed, so the scores equal the serial evaluation's.
    run = recipe["train"].train(_cfg(["algo=srfmp", f"out_dir={tmp_path / 'run'}", *TINY,
                                      "eval.final_eval=false"]))
    common = [f"checkpoint={run / 'best.pt'}", "eval.seeds=3", "eval.nfes=[1]",
              "eval.t_ends=[1.0]", "eval.time_table=[]", "eval.max_steps=16", "threads=1"]
    (a,) = recipe["eval"].evaluate_checkpoint(_cfg([*common, f"eval.out={tmp_path / 's'}"]))
    (b,) = recipe["eval"].evaluate_checkpoint(_cfg([*common, "eval.workers=2",
                                                    f"eval.out={tmp_path / 'p'}"]))
    assert b["seeds"] == a["seeds"] == "100000-100002" and b["env_steps"] == a["env_steps"]
    for key in ("score", "score_std", "jerk"):
        assert b[key] == pytest.approx(a[key], rel=1e-5), key


# ----- resume and runtime settings -------------------------------------------------------------
def _files(folder: Path) -> dict:
    return {p: p.read_bytes() for p in folder.rglob("*") if p.is_file()}


def test_resume_continues_the_run_in_place_from_its_own_config(recipe, tmp_path):
    run = recipe["train"].train(_cfg(["algo=rfmp", f"out_dir={tmp_path / 'run'}", *TINY,
                                      "eval.final_eval=false", "train.checkpoint_every=1"]))
    # only the overrides given now apply on top of the run's config.yaml (algo=rfmp is kept)
    again = recipe["train"].train(_cfg([f"resume={run}", "train.steps=4"]),
                                  overrides=[f"resume={run}", "train.steps=4"])
    assert again == run
    payload = torch.load(run / "last.pt", weights_only=False)
    assert payload["algorithm"] == "rfmp" and payload["training_state"]["step"] == 4
    history = json.loads((run / "history.json").read_text())
    assert [h["step"] for h in history] == [1, 2, 3, 4]
    logged = next(run.glob("logs/**/val/loss.csv")).read_text().split()
    assert [int(line.split(",")[0]) for line in logged] == [1, 2, 3, 4]


def test_a_refused_resume_names_the_setting_and_leaves_the_run_untouched(recipe, tmp_path):
    run = recipe["train"].train(_cfg(["algo=srfmp", f"out_dir={tmp_path / 'run'}", *TINY,
                                      "eval.final_eval=false"]))
    before = _files(run)
    for override, message in (("algo=rfmp", "algo='rfmp' \\(the run has 'srfmp'\\)"),
                              ("space=sphere", "space='sphere'"),
                              ("model.horizon=8", "model.horizon=8")):
        with pytest.raises(ValueError, match=message):
            recipe["train"].train(_cfg([f"resume={run}", override]),
                                  overrides=[f"resume={run}", override])
    with pytest.raises(ValueError, match="has no last.pt"):
        recipe["train"].train(_cfg([f"resume={tmp_path}"]), overrides=[f"resume={tmp_path}"])
    with pytest.raises(ValueError, match="no training state"):
        recipe["train"].train(_cfg([f"resume={run / 'best.pt'}"]),
                              overrides=[f"resume={run / 'best.pt'}"])
    with pytest.raises(ValueError, match="'~logger' removes a setting"):
        recipe["train"].train(_cfg([f"resume={run}"]), overrides=[f"resume={run}", "~logger"])
    with pytest.raises(ValueError, match="already holds a run .*resume="):  # no silent restart
        recipe["train"].train(_cfg(["algo=srfmp", f"out_dir={run}", *TINY]))
    from rfmp_rl.training.resume import resume_checkpoint

    with pytest.raises(ValueError, match="a run of recipe 'pusht', not 'robosuite'"):
        resume_checkpoint(run, "robosuite")
    assert _files(run) == before


@pytest.mark.parametrize("override,message", [
    ("device=tpu", "device='tpu'"),
    ("precision=fp8", "precision='fp8'"),
    ("logger.backend=mlflow", "logger.backend='mlflow'"),
    ("eval.workers=0", "eval.workers"),
])
def test_bad_runtime_settings_stop_at_start(recipe, tmp_path, override, message):
    with pytest.raises(ValueError, match=message):
        recipe["train"].train(_cfg([override, f"out_dir={tmp_path / 'run'}", *TINY]))
    assert not (tmp_path / "run").exists()


@pytest.mark.skipif(torch.cuda.is_available(), reason="checks the refusal on a machine without "
                    "CUDA")
@pytest.mark.parametrize("override,message", [
    ("device=cuda", "device=cuda: CUDA was requested"),
    ("precision=fp16", "precision=fp16 needs a CUDA device"),
])
def test_cuda_settings_without_cuda_stop_at_start(recipe, tmp_path, override, message):
    with pytest.raises(ValueError, match=message):
        recipe["train"].train(_cfg([override, "device=cpu" if "fp16" in override else "seed=0",
                                    f"out_dir={tmp_path / 'run'}", *TINY]))
    assert not (tmp_path / "run").exists()


def test_torchrun_sigterm_saves_last_pt_and_the_run_resumes(tmp_path):
    # two gloo ranks; SIGTERM to torchrun (as a cluster pre-empts a job) reaches both ranks,
    # which agree on the step, write last.pt and exit 143; resume= finishes the run
    import signal
    import subprocess
    import sys
    import time

    run = tmp_path / "run"
    args = [a for a in TINY if not a.startswith(("train.steps", "train.val_every"))]
    torchrun = Path(sys.executable).parent / "torchrun"
    cmd = [str(torchrun), "--standalone", "--nproc_per_node=2", str(RECIPE / "train.py"),
           *args, "train.steps=100000", "train.val_every=100000", "train.checkpoint_every=100000",
           "eval.final_eval=false", f"out_dir={run}", "device=cpu"]
    env = {k: v for k, v in os.environ.items() if k not in ("MUJOCO_GL", "CUDA_VISIBLE_DEVICES")}
    env["OMP_NUM_THREADS"] = "1"
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True, cwd=ROOT)
    deadline = time.time() + 240
    loss_csv = None
    while time.time() < deadline and loss_csv is None:
        time.sleep(1)
        found = list(run.glob("logs/**/train/loss.csv"))
        if found and len(found[0].read_text().split()) >= 5:
            loss_csv = found[0]
    assert loss_csv is not None, "the run logged nothing within 4 minutes"
    proc.send_signal(signal.SIGTERM)
    out, _ = proc.communicate(timeout=120)
    assert "SIGTERM: stopped at step" in out, out[-3000:]
    assert proc.returncode != 0
    state = torch.load(run / "last.pt", weights_only=False)["training_state"]
    step = state["step"]
    assert step >= 5 and state["world_size"] == 2 and len(state["rng"]) == 2
    cmd = [str(torchrun), "--standalone", "--nproc_per_node=2", str(RECIPE / "train.py"),
           f"resume={run}", f"train.steps={step + 3}"]
    done = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
    assert torch.load(run / "last.pt", weights_only=False)["training_state"]["step"] == step + 3
    # the run keeps both command lines, each runnable from the repository root
    first, resumed = (run / "command.txt").read_text().splitlines()
    assert re.match(r"OMP_NUM_THREADS=1 \S*torchrun --standalone --nproc_per_node=2 "
                    r"recipes/pusht/train.py ", first) and f"out_dir={run}" in first, first
    assert resumed.endswith(f"recipes/pusht/train.py resume={run} train.steps={step + 3}")
