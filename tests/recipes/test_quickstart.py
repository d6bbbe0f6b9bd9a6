"""Smoke test of the README main job with tiny overrides: all outputs exist and hold numbers."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]

pytestmark = pytest.mark.slow


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
