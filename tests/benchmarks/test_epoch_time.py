"""recipes/benchmarks/epoch_time.py at tiny sizes on the CPU: one row per algorithm (and CP with
its teacher) with finite positive figures, the command at the top, and its options checked."""

from __future__ import annotations

import math
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
BENCH = ROOT / "recipes" / "benchmarks"
sys.path.insert(0, str(BENCH))

import epoch_time  # noqa: E402

PUSHT = Path(os.environ.get("RFMP_PUSHT_ZARR", ROOT.parent / "shared/data/pusht/"
                            "pusht_cchi_v7_replay.zarr"))
TINY = ["--steps", "2", "--rounds", "1", "--warmup", "1", "--max-episodes", "3",
        "--batch-size", "8", "--down-dims", "16", "32", "--data", str(PUSHT)]
#: | algo | params | s/step | min-max or - | steps/epoch | s/epoch | ratio x |
ROW = re.compile(r"^\| (?P<algo>[a-z+]+) \| [^|]+ \| (?P<step>[\d.]+) \| [^|]+ \| "
                 r"(?P<steps>\d+) \| (?P<epoch>[\d.]+) \| (?P<ratio>[\d.]+)x \|$")

pytestmark = pytest.mark.slow


@pytest.mark.skipif(not PUSHT.exists(), reason=f"Push-T zarr not found at {PUSHT}")
def test_epoch_time_report_has_a_row_per_algorithm_with_positive_figures(tmp_path):
    out = tmp_path / "epoch_time.md"
    proc = subprocess.run([sys.executable, BENCH / "epoch_time.py", *TINY, "--out", out],
                          capture_output=True, text=True, cwd=ROOT, timeout=300,
                          env=dict(os.environ, OMP_NUM_THREADS="1"))
    assert proc.returncode == 0, proc.stderr[-3000:]
    text = out.read_text()
    head = text.split("| algorithm |")[0]
    assert "epoch_time.py --steps 2 --rounds 1 --warmup 1 --max-episodes 3" in head
    rows = {}
    for line in text.splitlines():
        match = ROW.match(line)
        if match:
            rows[match["algo"]] = {k: float(match[k]) for k in ("step", "steps", "epoch",
                                                                 "ratio")}
    assert list(rows) == ["rfmp", "srfmp", "ddim", "cp", "cp+teacher"], text
    for algo, row in rows.items():
        assert all(math.isfinite(v) and v > 0 for v in row.values()), (algo, row)
    assert rows["ddim"]["ratio"] == 1.0
    windows = int(re.search(r"(\d+) training windows", text)[1])
    assert rows["ddim"]["steps"] == math.ceil(windows / 8)
    assert rows["cp+teacher"]["step"] == pytest.approx(rows["cp"]["step"]
                                                       + rows["ddim"]["step"], abs=2e-4)
    assert "frozen teacher's forward" in text


def test_epoch_time_options_are_checked():
    assert epoch_time.parse_args(["--algos", "cp", "rfmp"]).algos == ["ddim", "cp", "rfmp"]
    for bad in (["--steps", "0"], ["--rounds", "0"], ["--batch-size", "0"],
                ["--algos", "dp"], ["--max-episodes", "0"]):
        with pytest.raises(SystemExit):
            epoch_time.parse_args(bad)
