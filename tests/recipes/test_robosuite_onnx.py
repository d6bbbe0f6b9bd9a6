"""Smoke test of recipes/robosuite/eval_onnx.py: a tiny Lift checkpoint (as in
test_robosuite.py), exported to ONNX and run by the deploy controller on 2 seeds next to the
PyTorch policy."""

from __future__ import annotations

import csv
import os

import pytest
from recipe_loader import compose, load_recipe

pytestmark = pytest.mark.slow
os.environ.setdefault("MUJOCO_GL", "egl")
pytest.importorskip("robosuite")
pytest.importorskip("onnxruntime")
pytest.importorskip("onnxscript")

TINY = [
    "data.demos=3", "data.val_episodes=1", "train.steps=2", "train.val_every=1",
    "train.val_batches=1", "train.batch_size=4", "train.log_every=1", "optim.warmup_steps=1",
    "eval.seeds=2", "eval.nfes=[1]", "eval.max_steps=12", "model.down_dims=[16,32]", "threads=1",
]


@pytest.fixture(scope="module")
def recipe():
    """The robosuite recipe's train.py, eval.py and eval_onnx.py."""
    yield from load_recipe("robosuite", extra=("eval_onnx",))


def test_eval_onnx_writes_both_success_rates(recipe, tmp_path_factory, tmp_path):
    data = tmp_path_factory.mktemp("robosuite_demos") / "Lift_delta.hdf5"
    run = recipe["train"].train(compose("robosuite", [
        "task=Lift", "algo=srfmp", f"out_dir={tmp_path / 'run'}", "eval.final_eval=false",
        f"data.path={data}", *TINY]))
    out = tmp_path / "ev"
    result = recipe["eval_onnx"].evaluate_onnx(compose("robosuite", [
        f"checkpoint={run / 'best.pt'}", "eval.seeds=2", "eval.seed_start=100000",
        "eval.max_steps=20", f"eval.out={out}", "threads=1", "onnx_nfe=1"]),
        command="python recipes/robosuite/eval_onnx.py checkpoint=best.pt")
    for name in ("policy_nfe1.onnx", "eval_onnx.md", "eval_onnx.csv"):
        assert (out / name).is_file() and (out / name).stat().st_size > 0, name
    md = (out / "eval_onnx.md").read_text()
    assert "PyTorch" in md and "ONNX controller" in md
    assert f"| {result['torch']:.2f} |" in md and f"| {result['onnx']:.2f} |" in md
    assert "checkpoint=best.pt" in md and "parity" in md
    with open(out / "eval_onnx.csv") as f:
        rows = list(csv.DictReader(f))
    assert [r["seed"] for r in rows] == ["100000", "100001"]
    assert all(r["torch_success"] in "01" and r["onnx_success"] in "01" for r in rows)
    assert len(result["differ"]) == sum(r["torch_success"] != r["onnx_success"] for r in rows)
    # the control: PyTorch again with its actions shifted by the export's largest difference
    assert [int(r["torch_shifted_success"]) for r in rows] == result["control"]
    assert "| control: PyTorch, actions shifted by ±" in md
    assert "- Control: seeds where PyTorch and PyTorch with every executed action shifted" in md
    assert "| NFE | T asked | T reached |" in md and "| 1 | 1 | 0.40 |" in md  # SRFMP NFE 1


def test_shifted_actor_moves_every_action_coordinate_by_the_shift(recipe):
    import torch
    from tensordict import TensorDict
    from tensordict.nn import TensorDictModule

    base = TensorDictModule(lambda obs: obs * 0 + 0.5, in_keys=["observation"],
                            out_keys=["action"])
    actor = recipe["eval_onnx"].shifted_actor(base, 1e-3)
    out = actor(TensorDict({"observation": torch.zeros(2, 4)}, batch_size=[2]))
    assert torch.allclose(out["action"], torch.tensor([[0.501, 0.499, 0.501, 0.499]] * 2))


def test_eval_onnx_missing_checkpoint_names_the_path(recipe, tmp_path):
    missing = tmp_path / "nope.pt"
    with pytest.raises(SystemExit, match="nope.pt"):
        recipe["eval_onnx"].evaluate_onnx(compose("robosuite", [f"checkpoint={missing}"]))
