"""The README main job: its training samples, and a smoke run with tiny overrides (all outputs
exist and hold numbers)."""

from __future__ import annotations

import importlib.util
import json
import math
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from omegaconf import OmegaConf

ROOT = Path(__file__).resolve().parents[2]


def load_quickstart():
    spec = importlib.util.spec_from_file_location("quickstart", ROOT / "recipes" / "quickstart.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_quickstart_samples_come_from_the_store_with_hold_steps_and_shape_ids():
    qs = load_quickstart()
    cfg = OmegaConf.create({"shapes": ["LShape", "Sine"], "downsample": 25, "hold_steps": 3,
                            "horizon": 4, "batch_size": 512, "seed": 0})
    demos = qs.load_shapes(cfg)  # {shape: (7, 40, 3)}
    store = qs.make_store(cfg)
    assert store.num_episodes == 14 and len(store) == 14 * (40 + 3)
    batch = qs.make_replay_buffer(store, cfg).sample()
    assert batch["observation"].shape == (512, 2, 5) and batch["action"].shape == (512, 4, 3)
    for i in range(0, 512, 37):
        ref = int(batch["index"][i, 1])
        episode, step = divmod(ref, 43)
        demo = demos[cfg.shapes[episode // 7]][episode % 7]  # (40, 3)
        held = torch.cat([demo, demo[-1:].expand(3, -1)])  # the goal held 3 more steps
        # window [x_{r-1}, x_r] (the first step repeats x_0) with the shape's one-hot id
        torch.testing.assert_close(batch["observation"][i, :, :3],
                                   held[[max(step - 1, 0), step]])
        assert batch["observation"][i, :, 3:].tolist() == [[1.0 * (episode < 7),
                                                            1.0 * (episode >= 7)]] * 2
        # the chunk: the next T_p points, the last repeated past the episode end (padded)
        nxt = torch.cat([held[1:], held[-1:]])
        chunk = [min(step + k, 42) for k in range(4)]
        torch.testing.assert_close(batch["action"][i], nxt[chunk])
        assert batch["action_is_pad"][i].tolist() == [step + k > 42 for k in range(4)]


def test_claim_checks_test_srfmp_over_t_only_where_its_schedule_reaches_two_ts():
    qs = load_quickstart()
    cfg = OmegaConf.create({"nfes": [1, 5], "t_ends": [1.0, 1.6], "shapes": ["LShape"],
                            "goal_threshold": 0.05})
    reached = {("srfmp", 1): (0.4, 0.4), ("srfmp", 5): (1.0, 1.6), ("rfmp", 1): (1.0, 1.6),
               ("rfmp", 5): (1.0, 1.6)}
    dtw = {("srfmp", 1): (0.0339, 0.0339), ("srfmp", 5): (0.0219, 0.0217),
           ("rfmp", 1): (0.0634, 1.3150), ("rfmp", 5): (0.0260, 0.1325)}
    results = {(a, n, t): {"dtw": dtw[(a, n)][i], "t_reached": reached[(a, n)][i],
                           "on_manifold": 1e-7, "per_seed": {"final": [0.01]}}
               for (a, n) in dtw for i, t in enumerate(cfg.t_ends)}
    checks = qs.claim_checks(results, torch.tensor([0]), cfg)
    # NFE 1: SRFMP's two rollouts both stop at T 0.40; a ratio of 1 would test nothing
    assert checks[0] == ("- NFE=1: SRFMP stops at T 0.40 for every T asked, so there is no "
                         "T 1.6 vs T 1 test at this NFE; RFMP DTW T 1.60 / T 1.00 reached = "
                         "20.741 (grows: True)")
    assert checks[1].startswith("- NFE=5: SRFMP DTW T=1.6/T=1 (T 1.60 / 1.00 reached) = 0.991 "
                                "(within 10%: True); RFMP = 5.096")
    assert "LASA" in qs.PAPER_LINE and "diverges from the target distribution" in qs.PAPER_LINE


@pytest.mark.slow
def test_quickstart_runs_end_to_end_with_tiny_overrides(tmp_path):
    out = tmp_path / "run"
    cmd = [
        sys.executable, str(ROOT / "recipes" / "quickstart.py"),
        "steps=30", "batch_size=32", "shapes=[LShape,Sine]", "downsample=25",
        "down_dims=[16,32]", "nfes=[1,2]", "t_ends=[1.0,1.6]", "extra_steps=5",
        "max_step=0.3", f"out_dir={out}",
    ]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=600, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert f"Everything is in {out}" in proc.stdout
    for name in ("rfmp.pt", "srfmp.pt", "srfmp_nfe1.onnx", "flows_t0_t1_t1.5.png",
                 "rollouts.png", "summary.md", "results.json", "config.yaml"):
        assert (out / name).is_file() and (out / name).stat().st_size > 0, name
    results = json.loads((out / "results.json").read_text())
    assert set(results) == {f"{a}/nfe{n}/T{t}" for a in ("rfmp", "srfmp") for n in (1, 2)
                            for t in ("1", "1.6")}
    for entry in results.values():
        for key in ("dtw", "final", "jerk", "on_manifold", "success", "t_reached"):
            assert math.isfinite(entry[key]), (key, entry)
        assert entry["on_manifold"] <= 1e-5
    summary = (out / "summary.md").read_text()
    assert "| SRFMP | 1 | 1 |" in summary and "ONNX controller" in summary
    # The exported controller replays the PyTorch policy's closed loop.
    line = next(ln for ln in summary.splitlines() if "max trajectory difference" in ln)
    assert float(line.rsplit("difference", 1)[1].split()[0]) <= 1e-4


@pytest.mark.slow
def test_quickstart_seeds_benchmark_writes_one_row_per_seed(tmp_path):
    out = tmp_path / "seeds.md"
    cmd = [
        sys.executable, str(ROOT / "recipes" / "benchmarks" / "quickstart_seeds.py"),
        "--seeds", "0", "1", "--out", str(out),
        "steps=5", "batch_size=16", "shapes=[LShape]", "downsample=25", "down_dims=[16,32]",
        "extra_steps=2", "max_step=0.3", "threads=1",
    ]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=300, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr[-3000:]
    rows = [ln for ln in out.read_text().splitlines() if ln.startswith("| ") and ln[2].isdigit()]
    assert [r.split("|")[1].strip() for r in rows] == ["0", "1"]
    for row in rows:
        cells = [c.strip() for c in row.strip("|").split("|")]
        ratios = [float(c) for c in cells[-3:-1]]  # NFE 5 and NFE 10
        dtw = [float(c) for c in cells[2:8]]
        assert all(math.isfinite(x) and x > 0 for x in dtw + ratios)
        assert cells[-1] == ("yes" if max(ratios) <= 1.10 else "no")
    assert "steps=5" in out.read_text()
