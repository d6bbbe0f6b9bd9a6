"""The training benchmarks at tiny sizes on the CPU: recipes/benchmarks/training_throughput.py
writes every row with finite positive figures (compilation tested on its own: it costs about a
minute per model), and recipes/benchmarks/gpu_check.py exits 0 with one line without CUDA while
its per-setting and DDP runners train, report and pass ONNX parity with ``device=cpu``."""

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

import gpu_check  # noqa: E402
import training_throughput  # noqa: E402

PUSHT = Path(os.environ.get("RFMP_PUSHT_ZARR", ROOT.parent / "shared/data/pusht/"
                            "pusht_cchi_v7_replay.zarr"))
TINY = ["--tasks", "pusht_state", "--steps", "2", "--warmup", "1", "--batch", "8",
        "--down-dims", "16", "32"]
#: | label | P x T | step ms | samples/s | ratio x | share % ...
ROW = re.compile(r"^\| (?P<label>[^|]+?) \| (?P<procs>\d+) x (?P<threads>\d+) \| "
                 r"(?P<ms>[\d.,]+) \| (?P<rate>[\d.,]+) \| (?P<ratio>[\d.]+)x \| "
                 r"(?P<share>[\d.]+)%")

pytestmark = pytest.mark.slow


def _run(args: list, timeout: float, **env) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, *map(str, args)], capture_output=True, text=True,
                          cwd=ROOT, timeout=timeout,
                          env=dict(os.environ, OMP_NUM_THREADS="1", **env))


def _rows(text: str) -> dict[str, dict[str, float]]:
    rows = {}
    for line in text.splitlines():
        match = ROW.match(line)
        if match:
            rows[match["label"]] = {k: float(match[k].replace(",", ""))
                                    for k in ("procs", "threads", "ms", "rate", "ratio", "share")}
    return rows


def _check_figures(rows: dict[str, dict[str, float]]) -> None:
    for label, row in rows.items():
        for name in ("ms", "rate", "ratio"):
            assert math.isfinite(row[name]) and row[name] > 0, (label, name, row)
        assert 0 < row["share"] < 100, (label, row)


# ----- training_throughput.py ------------------------------------------------------------------
def test_throughput_report_has_eager_bf16_and_ddp_rows_with_positive_figures(tmp_path):
    out = tmp_path / "throughput.md"
    proc = _run([BENCH / "training_throughput.py", *TINY, "--no-compile", "--ddp-repeats", "1",
                 "--out", out], 300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    text = out.read_text()
    assert "training_throughput.py --tasks pusht_state --steps 2" in text.split("\n## ")[0]
    assert "CPU figures" in text and "bf16" in text
    rows = _rows(text)
    assert set(rows) == {"eager fp32", "bf16 autocast (eager)", "DDP 1 process (eager fp32)",
                         "DDP 2 processes (eager fp32)"}, text
    _check_figures(rows)
    assert rows["eager fp32"]["ratio"] == 1.0
    assert rows["DDP 1 process (eager fp32)"]["procs"] == 1
    assert rows["DDP 2 processes (eager fp32)"]["procs"] == 2
    assert all(row["threads"] == 1 for row in rows.values())
    assert "| 8 per rank; world size 1" in text and "| 4 per rank |" in text  # global batch kept
    scaling = re.search(r"2 processes / 1 process = ([\d.]+)x", text)
    assert scaling and float(scaling[1]) > 0
    share = re.search(r"Data pipeline \(eager fp32\): .* = ([\d.]+)%; target <= 10%: "
                      r"(met|MISSED)", text)
    assert share and 0 < float(share[1]) < 100


def test_throughput_compiled_row_reports_its_compile_time_separately(tmp_path):
    out = tmp_path / "compiled.md"
    # the on-disk inductor cache: a rerun of the suite compiles this model in seconds
    proc = _run([BENCH / "training_throughput.py", *TINY, "--no-ddp", "--warm-compile-cache",
                 "--out", out], 600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    text = out.read_text()
    rows = _rows(text)
    assert set(rows) == {"eager fp32", "compiled fp32", "bf16 autocast (eager)"}, text
    _check_figures(rows)
    compiled = re.search(r"torch.compile: first step ([\d.]+) s", text)
    assert compiled and float(compiled[1]) > 0


def test_throughput_rejects_zero_steps():
    with pytest.raises(SystemExit):
        training_throughput.parse_args(["--steps", "0"])


# ----- gpu_check.py ----------------------------------------------------------------------------
def test_gpu_check_without_cuda_prints_one_line_and_exits_0():
    proc = _run([BENCH / "gpu_check.py", "--steps", "3"], 120, CUDA_VISIBLE_DEVICES="")
    assert proc.returncode == 0, proc.stderr[-3000:]
    lines = proc.stdout.strip().splitlines()
    assert len(lines) == 1, proc.stdout
    assert re.fullmatch(r"gpu_check: no CUDA device visible \(torch \S+\); nothing to check",
                        lines[0])


def test_gpu_check_settings_cover_both_tasks_precisions_and_ddp_on_several_gpus():
    one, notes = gpu_check.build_settings(300, 1)
    assert [(s.task, s.precision, s.compile) for s in one] == [
        (task, precision, compiled) for task in ("pusht_state", "pusht_image")
        for precision, compiled in (("fp32", False), ("bf16", False), ("fp32", True))]
    assert [s.batch for s in one] == [256] * 3 + [64] * 3
    assert all(s.steps == 300 and s.processes == 1 for s in one)
    assert any("DDP skipped" in n for n in notes)
    four, notes = gpu_check.build_settings(300, 4)
    assert four[:-1] == one and not notes
    ddp = four[-1]
    assert (ddp.task, ddp.precision, ddp.processes, ddp.batch) == ("pusht_state", "bf16", 4, 256)
    assert len({s.name for s in four}) == len(four)


def test_gpu_check_ddp_overrides_are_the_recipes_settings(tmp_path):
    from hydra import compose, initialize_config_dir

    setting = gpu_check.Setting("ddp", "pusht_state", "bf16", False, 256, 300, processes=2)
    overrides = gpu_check.ddp_overrides(setting, "cuda", tmp_path, PUSHT, "paper", 30)
    with initialize_config_dir(config_dir=str(ROOT / "recipes" / "pusht"), version_base="1.3"):
        cfg = compose("config", overrides=overrides)  # an unknown key would raise here
    assert (cfg.device, cfg.precision, cfg.model.unet_preset, cfg.obs) == ("cuda", "bf16", "paper",
                                                                     "state")
    assert cfg.train.steps == 300 and cfg.train.max_minutes == 30
    assert cfg.train.batch_size == 256 and cfg.eval.final_eval is False
    assert cfg.out_dir == str(tmp_path) and cfg.logger.backend == "none"


@pytest.fixture(scope="module")
def state_data():
    return training_throughput.load_task_data("pusht_state", 8, PUSHT)


def _check_outcome(outcome: gpu_check.Outcome) -> None:
    assert outcome.ok, outcome.error
    for name in ("samples_per_s", "final_loss", "val_loss"):
        value = getattr(outcome, name)
        assert math.isfinite(value) and value > 0, (name, value)
    assert 0 <= outcome.parity <= gpu_check.PARITY_LIMIT
    assert 0 <= outcome.sphere_error <= gpu_check.SPHERE_LIMIT


@pytest.mark.parametrize("precision", ["fp32", "bf16"])
def test_gpu_check_runner_trains_reports_and_passes_parity_on_cpu(tmp_path, state_data,
                                                                  precision):
    settings, _ = gpu_check.build_settings(3, 1, tasks=("pusht_state",), state_batch=8)
    (setting,) = [s for s in settings if s.precision == precision and not s.compile]
    outcome = gpu_check.run_setting(setting, "cpu", state_data, tmp_path, preset="small",
                                    down_dims=[16, 32], warmup=1)
    _check_outcome(outcome)
    assert outcome.peak_memory_gb is None  # a CUDA-only figure
    assert not list(tmp_path.iterdir())  # the run folder is removed


def test_gpu_check_runner_trains_the_image_policy_on_synthetic_batches(tmp_path):
    data = training_throughput.load_task_data("pusht_image", 2, synthetic=True)
    assert not data.real and "synthetic" in data.source
    setting = gpu_check.Setting("image", "pusht_image", "fp32", False, 2, 3)
    outcome = gpu_check.run_setting(setting, "cpu", data, tmp_path, preset="small",
                                    down_dims=[16, 32], warmup=1)
    _check_outcome(outcome)


def test_gpu_check_failures_are_reported_not_raised():
    setting = gpu_check.Setting("x", "pusht_state", "fp32", False, 8, 3)
    bad = gpu_check.Outcome(setting, 10.0, None, math.nan, 1.0, 0.0, 0.0)
    bad.check()
    assert not bad.ok and "final_loss" in bad.error
    off = gpu_check.Outcome(setting, 10.0, None, 1.0, 1.0, 2e-4, 0.0)
    off.check()
    assert not off.ok and "parity" in off.error
    assert "FAIL" in gpu_check.table([bad])[-1]


@pytest.mark.skipif(not PUSHT.exists(), reason=f"Push-T zarr not found at {PUSHT}")
def test_gpu_check_ddp_runner_trains_the_recipe_over_two_gloo_ranks(tmp_path):
    setting = gpu_check.Setting("ddp cpu", "pusht_state", "fp32", False, 4, 3, processes=2)
    outcome = gpu_check.run_ddp(setting, "cpu", tmp_path, PUSHT, preset="small", extra=[
        "threads=1", "down_dims=[16,32]", "data.max_episodes=3", "data.val_episodes=2"],
        timeout=300)
    _check_outcome(outcome)
