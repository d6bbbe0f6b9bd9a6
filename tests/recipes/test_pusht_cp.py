"""Smoke test of the Consistency Policy in the Push-T recipe on the real zarr: a tiny DDIM teacher
trains a few steps, a cp student is distilled from it (``algo=cp teacher=...``), evaluated at
NFE 1, exported at NFE 1 and run by the torch-free deploy controller."""

from __future__ import annotations

import hashlib
import importlib.util
from pathlib import Path

import pytest
import torch
from recipe_loader import PUSHT_TINY, compose, load_recipe, pusht_marks

from rfmp_rl.checkpoint import load_checkpoint, read_checkpoint
from rfmp_rl.eval import read_table
from rfmp_rl.modules import ConsistencyModel

ROOT = Path(__file__).resolve().parents[2]
pytestmark = pusht_marks()

TINY = PUSHT_TINY


@pytest.fixture(scope="module")
def recipe():
    """train.py, eval.py and eval_onnx.py (imported while the recipe's `utils` is importable)."""
    pytest.importorskip("onnxruntime")
    for mods in load_recipe("pusht"):
        spec = importlib.util.spec_from_file_location(
            "pusht_eval_onnx", ROOT / "recipes" / "pusht" / "eval_onnx.py")
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        yield {**mods, "eval_onnx": module}


@pytest.fixture(scope="module")
def teacher(recipe, tmp_path_factory) -> Path:
    run = recipe["train"].train(compose("pusht", [
        "algo=ddim", f"out_dir={tmp_path_factory.mktemp('ddim')}", "eval.final_eval=false",
        *TINY]))
    return run / "best.pt"


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def test_cp_distils_a_ddim_teacher_evaluates_and_deploys_at_nfe_1(recipe, teacher, tmp_path):
    before = _digest(teacher)
    run = recipe["train"].train(compose("pusht", [
        "algo=cp", f"teacher={teacher}", f"out_dir={tmp_path / 'cp'}", *TINY]))
    assert _digest(teacher) == before  # the teacher's file is only read
    (row,) = read_table(run / "eval" / "eval.csv")
    assert row["algo"] == "cp" and row["nfe"] == "1" and row["t_end"] == "1.0"
    assert 0.0 <= float(row["score"]) <= 1.0
    payload = read_checkpoint(run / "best.pt")
    assert payload["algorithm"] == "cp" and payload["solver"]["method"] == "consistency"
    assert payload["loss"]["teacher"] == str(teacher.resolve())
    assert not any("teacher" in key for key in payload["state_dict"])
    # the student started as the teacher and trained away from it; the normalisers are its
    student, _ = load_checkpoint(run / "best.pt", use_ema=False)
    ddim, _ = load_checkpoint(teacher, use_ema=False)
    assert isinstance(student, ConsistencyModel)
    for name, value in ddim.state_dict().items():
        if "normalizer" in name or name == "alphas_cumprod":
            assert torch.equal(student.state_dict()[name], value), name
    assert any(not torch.equal(student.state_dict()[n], v) for n, v in ddim.state_dict().items()
               if n.startswith("network."))
    # exported at NFE 1 and run by the deploy controller beside the PyTorch policy
    out = tmp_path / "onnx"
    result = recipe["eval_onnx"].evaluate_onnx(compose("pusht", [
        f"checkpoint={run / 'best.pt'}", "onnx_nfe=1", "onnx_precisions=[fp32]", "eval.seeds=2",
        "eval.max_steps=12", f"eval.out={out}", "threads=1"]),
        command="python recipes/pusht/eval_onnx.py checkpoint=best.pt")
    assert (out / "policy_nfe1_fp32.onnx").stat().st_size > 0
    assert 0.0 <= result["fp32"] <= 1.0 and 0.0 <= result["torch"] <= 1.0
    md = (out / "eval_onnx.md").read_text()
    assert "cp" in md and "| ONNX controller | fp32 | 1 | 1 |" in md
    import onnx

    meta = {p.key: p.value for p in onnx.load(str(out / "policy_nfe1_fp32.onnx")).metadata_props}
    assert (meta["algorithm"], meta["nfe"], meta["method"]) == ("cp", "1", "consistency")
    # eval.py re-evaluates the checkpoint at NFE 1 and 3 (T = 1 only) without the teacher
    rows = recipe["eval"].evaluate_checkpoint(compose("pusht", [
        f"checkpoint={run / 'best.pt'}", "eval.seeds=2", "eval.nfes=[1,3]",
        "eval.t_ends=[1.0,1.6]", "eval.max_steps=10", f"eval.out={tmp_path / 'ev'}",
        "threads=1"]))
    assert [(r["nfe"], r["t_end"]) for r in rows] == [(1, 1.0), (3, 1.0)]


def test_cp_names_a_missing_or_wrong_teacher(recipe, teacher, tmp_path):
    with pytest.raises(ValueError, match="algo=cp distils a Diffusion Policy.*teacher="):
        recipe["train"].train(compose("pusht", ["algo=cp", f"out_dir={tmp_path / 'a'}", *TINY]))
    flow = recipe["train"].train(compose("pusht", [
        "algo=rfmp", f"out_dir={tmp_path / 'rfmp'}", "eval.final_eval=false", *TINY]))
    with pytest.raises(ValueError, match=r"rfmp/best\.pt: the Consistency Policy's teacher must "
                                         r"be a Diffusion Policy checkpoint"):
        recipe["train"].train(compose("pusht", [
            "algo=cp", f"teacher={flow / 'best.pt'}", f"out_dir={tmp_path / 'b'}", *TINY]))
    with pytest.raises(ValueError, match=r"other model settings \(down_dims: teacher \[16, 32\], "
                                         r"this run \[16, 64\]"):
        recipe["train"].train(compose("pusht", [
            "algo=cp", f"teacher={teacher}", f"out_dir={tmp_path / 'c'}", *TINY,
            "model.down_dims=[16,64]"]))
