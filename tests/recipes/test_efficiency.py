"""recipes/robosuite/efficiency.py: the training plan of the efficiency figure, the evaluation
of a run's epoch snapshots with its cache, and the table and plot over training seeds."""

from __future__ import annotations

import os
import shlex
import shutil
from pathlib import Path

import pytest
import yaml
from recipe_loader import compose, load_recipe, load_script

from rfmp_rl.training import TrainConfig

os.environ.setdefault("MUJOCO_GL", "egl")


@pytest.fixture(scope="module")
def efficiency():
    return load_script("robosuite", "efficiency")


def test_plan_lists_every_task_algorithm_and_seed(efficiency, capsys):
    assert efficiency.main(["--plan"]) == []
    lines = capsys.readouterr().out.strip().splitlines()
    assert len(lines) == 27
    outs = set()
    for i, line in enumerate(lines):
        words = shlex.split(line)
        assert words[:2] == ["OMP_NUM_THREADS=1", "MUJOCO_GL=egl"]
        overrides = words[words.index("recipes/robosuite/train.py") + 1:]
        if i % 4:  # every override a setting of the recipe (every fourth line, all tasks, composed)
            settings = dict(o.split("=", 1) for o in overrides)
            outs.add((settings["task"], settings["algo"], int(settings["seed"])))
            continue
        cfg = compose("robosuite", overrides)
        train = TrainConfig.from_config(cfg.train)
        assert (train.epochs, train.snapshot_every_epochs) == (50, 10)
        assert train.max_minutes == float("inf") and cfg.optim.lr == 1e-4
        assert cfg.eval.final_eval is False and cfg.threads == 1
        assert train.batch_size == (512 if cfg.task == "NutAssemblySquare" else 256)
        assert cfg.out_dir == (f"runs/robosuite/eff_{efficiency.SHORT[cfg.task]}_{cfg.algo}_"
                               f"seed{cfg.seed}")
        outs.add((cfg.task, cfg.algo, cfg.seed))
    assert outs == {(t, a, s) for t in ("Lift", "PickPlaceCan", "NutAssemblySquare")
                    for a in ("rfmp", "srfmp", "ddim") for s in (0, 1, 2)}


# ----- the table and the plot from the runs' caches --------------------------------------------
def _fake_run(folder: Path, task: str, algo: str, seed: int, success: dict[int, float],
              nfe: int = 3) -> Path:
    folder.mkdir(parents=True)
    cfg = {"task": task, "algo": algo, "seed": seed, "optim": {"lr": 1e-4}, "obs": "state",
           "action_space": "delta", "model": {"unet_preset": "small"},
           "train": {"batch_size": 256, "epochs": 50, "snapshot_every_epochs": 10}}
    (folder / "config.yaml").write_text(yaml.safe_dump(cfg))
    lines = [",".join(["task", "algo", "seed", "epoch", "step", "nfe", "t_end", "t_reached",
                       "success", "episodes", "eval_seeds"])]
    lines += [f"{task},{algo},{seed},{e},{e * 40},{nfe},1.0,1.0,{s},50,100000-100049"
              for e, s in success.items()]
    (folder / "efficiency.csv").write_text("\n".join(lines) + "\n")
    return folder


def test_table_and_plot_give_the_mean_and_spread_over_training_seeds(efficiency, tmp_path):
    runs = [_fake_run(tmp_path / "l_s0", "Lift", "srfmp", 0, {10: 0.5, 20: 0.9}),
            _fake_run(tmp_path / "l_s1", "Lift", "srfmp", 1, {10: 0.7, 20: 1.0}),
            _fake_run(tmp_path / "l_d0", "Lift", "ddim", 0, {10: 0.0, 20: 0.2}),
            _fake_run(tmp_path / "l_d1", "Lift", "ddim", 1, {10: 0.1}),
            _fake_run(tmp_path / "s_r0", "NutAssemblySquare", "rfmp", 0, {10: 0.3, 20: 0.6}),
            # another NFE in the cache is not in this table
            _fake_run(tmp_path / "x", "Lift", "rfmp", 0, {10: 1.0}, nfe=1)]
    out = tmp_path / "results" / "efficiency.md"
    rows = efficiency.main([*map(str, runs), "--no-eval", "--out", str(out)])
    assert len(rows) == 9
    text = out.read_text()
    assert text.startswith("Command: `python recipes/robosuite/efficiency.py ")
    body = {line.split(" | ")[0] + " " + line.split(" | ")[1]: line.split(" | ")[2:]
            for line in text.splitlines() if line.startswith("| Lift") or
            line.startswith("| NutAssembly")}
    # SRFMP before DDIM (the paper's order), Lift before Square; std is the sample std
    assert list(body) == ["| Lift SRFMP", "| Lift DDIM", "| NutAssemblySquare RFMP"]
    assert body["| Lift SRFMP"] == ["3, 1.00", "0, 1", "0.60 ± 0.14", "0.95 ± 0.07 |"]
    assert body["| Lift DDIM"] == ["3, 1.00", "0, 1", "0.05 ± 0.07", "0.20 (n=1) |"]
    assert body["| NutAssemblySquare RFMP"] == ["3, 1.00", "0", "0.30", "0.60 |"]
    assert "| epoch 10 | epoch 20 |" in text and "![success against epochs](efficiency.png)" in text
    assert ("| `" + str(runs[0]) + "` | Lift | SRFMP | 0 | state, delta | small | 0.0001 | 256 | "
            "10, 20 | 40 |") in text
    png = out.with_suffix(".png")
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 5000


def test_the_plot_names_how_many_training_seeds_each_line_has(efficiency, tmp_path,
                                                              monkeypatch):
    from matplotlib.axes import Axes

    labels = []
    plot = Axes.plot

    def spy(ax, *args, **kwargs):
        labels.append(kwargs.get("label"))
        return plot(ax, *args, **kwargs)

    monkeypatch.setattr(Axes, "plot", spy)
    rows = [{"task": t, "algo": a, "seed": s, "epoch": 10, "success": 0.5, "t_reached": 1.0}
            for t, a, seeds in (("Lift", "srfmp", (0, 1, 2)), ("PickPlaceCan", "srfmp", (0,)),
                                ("PickPlaceCan", "ddim", (0, 1))) for s in seeds]
    efficiency.plot(rows, tmp_path / "p.png")
    # the lines in panel order, Lift first
    assert labels == ["SRFMP (n=3)", "SRFMP (n=1)", "DDIM (n=2)"]


def test_a_run_given_twice_or_without_snapshots_is_named(efficiency, tmp_path):
    run = _fake_run(tmp_path / "a", "Lift", "rfmp", 0, {10: 0.5})
    with pytest.raises(ValueError, match="two results for Lift rfmp seed 0 epoch 10"):
        efficiency.main([str(run), str(run), "--no-eval"])
    plain = tmp_path / "plain"
    plain.mkdir()
    (plain / "config.yaml").write_text(yaml.safe_dump({"task": "Lift", "algo": "rfmp",
                                                       "seed": 0, "train": {"steps": 5}}))
    with pytest.raises(ValueError, match="trained without train.snapshot_every_epochs"):
        efficiency.main([str(plain), "--no-eval"])
    with pytest.raises(FileNotFoundError, match="no config.yaml"):
        efficiency.main([str(tmp_path), "--no-eval"])


def test_an_absent_run_is_read_from_its_record(efficiency, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    here = _fake_run(tmp_path / "runs" / "l_s0", "Lift", "srfmp", 0, {10: 0.5})
    records = tmp_path / "records"
    _fake_run(records / "runs" / "l_s1", "Lift", "srfmp", 1, {10: 0.7})
    _fake_run(records / "runs" / "l_s0", "Lift", "srfmp", 0, {10: 0.0})  # the folder wins
    out = tmp_path / "eff.md"
    argv = ["runs/l_s0", "runs/l_s1", "--no-eval", "--records", str(records), "--out", str(out)]
    rows = efficiency.main(argv)
    assert sorted((r["seed"], r["success"]) for r in rows) == [(0, 0.5), (1, 0.7)]
    text = out.read_text()
    assert "| `runs/l_s0` | Lift |" in text
    assert "| `runs/l_s1` (record: `records/runs/l_s1`) | Lift |" in text  # cwd-relative
    assert here.is_dir()
    # a record is only read with --no-eval (it has no snapshots), and an unknown run is named
    with pytest.raises(SystemExit):
        efficiency.main(["runs/l_s1", "--records", str(records)])
    with pytest.raises(SystemExit):
        efficiency.main(["runs/l_s2", "--no-eval", "--records", str(records)])
    # a record without the run's config.yaml cannot say how it was trained: not read
    (records / "runs" / "l_s1" / "config.yaml").unlink()
    with pytest.raises(SystemExit):
        efficiency.main(["runs/l_s1", "--no-eval", "--records", str(records)])


# ----- a tiny run: snapshots evaluated once each -----------------------------------------------
@pytest.fixture
def recipe():
    yield from load_recipe("robosuite")


TINY = ["task=Lift", "algo=rfmp", "data.demos=2", "data.val_episodes=1", "data.max_episodes=1",
        "train.batch_size=32", "train.epochs=2", "train.snapshot_every_epochs=1",
        "train.val_every=1000", "train.val_batches=1", "optim.warmup_steps=1",
        "eval.final_eval=false", "model.down_dims=[16,32]", "threads=1", "logger.backend=none"]


def test_snapshots_are_evaluated_once_and_cached(recipe, efficiency, tmp_path, monkeypatch):
    run = recipe["train"].train(compose("robosuite", [
        *TINY, f"out_dir={tmp_path / 'run'}", f"data.path={tmp_path / 'lift.hdf5'}"]))
    assert sorted(efficiency.snapshots(run)) == [1, 2]
    calls = []
    evaluate = efficiency.evaluate_snapshot

    def counted(path, *args, **kw):
        calls.append(Path(path).name)
        return evaluate(path, *args, **kw)

    monkeypatch.setattr(efficiency, "evaluate_snapshot", counted)
    settings = ["--seeds", "2", "--seed-start", "500", "--set", "eval.max_steps=6"]
    rows = efficiency.main([str(run), *settings])
    assert calls == ["epoch_001.pt", "epoch_002.pt"]
    assert [(r["epoch"], r["nfe"], r["episodes"], r["eval_seeds"]) for r in rows] == [
        (1, 3, 2, "500-501"), (2, 3, 2, "500-501")]
    per_epoch = rows[0]["step"]
    assert per_epoch >= 1 and rows[1]["step"] == 2 * per_epoch
    assert all(r["task"] == "Lift" and r["algo"] == "rfmp" and r["seed"] == 0 for r in rows)
    assert all(0.0 <= r["success"] <= 1.0 and r["t_reached"] == 1.0 for r in rows)
    cached = (run / "efficiency.csv").read_text()
    # again: nothing new to evaluate
    assert efficiency.main([str(run), *settings]) == rows and len(calls) == 2
    assert (run / "efficiency.csv").read_text() == cached

    # a new snapshot alone is evaluated (here by a stand-in: the caching is what is tested)
    def stand_in(path, nfe, seeds, seed_start, overrides=()):
        calls.append(Path(path).name)
        return {"step": 3 * per_epoch, "nfe": nfe, "t_end": 1.0, "t_reached": 1.0,
                "success": 0.5, "episodes": seeds, "eval_seeds": f"{seed_start}-"
                f"{seed_start + seeds - 1}"}

    monkeypatch.setattr(efficiency, "evaluate_snapshot", stand_in)
    shutil.copy(run / "snapshots" / "epoch_002.pt", run / "snapshots" / "epoch_003.pt")
    rows = efficiency.main([str(run), *settings])
    assert calls[2:] == ["epoch_003.pt"] and [r["epoch"] for r in rows] == [1, 2, 3]
    assert (run / "efficiency.csv").read_text().startswith(cached)
    # other evaluation settings are other results, kept beside the cached ones
    assert len(efficiency.main([str(run), "--seeds", "3", "--set", "eval.max_steps=6"])) == 3
    assert calls[3:] == ["epoch_001.pt", "epoch_002.pt", "epoch_003.pt"]
    assert len(efficiency.read_cache(run / "efficiency.csv")) == 6
