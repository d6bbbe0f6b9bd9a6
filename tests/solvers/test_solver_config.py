"""One solver config for the policy, the exported graph, the checkpoint and the recipes."""

from __future__ import annotations

import pytest
import torch
from tensordict import TensorDict
from torchrl.envs.utils import ExplorationType, set_exploration_type

from rfmp_rl.checkpoint import read_checkpoint, save_checkpoint
from rfmp_rl.modules import FlowPolicy
from rfmp_rl.onnx_export import InferenceGraph, onnx_metadata
from rfmp_rl.solvers import SolverConfig


def fitted(model):
    model.action_normalizer.fit(model.chunk.unflatten(model.chunk.random_base(16)))
    model.obs_normalizer.fit(torch.randn(16, model.cfg.obs_dim))
    return model.eval()


@pytest.mark.parametrize("algorithm,schedule,method", [
    ("srfmp", "srfmp", "euler"), ("rfmp", "uniform", "euler"), ("ddim", "ddim", "ddim")])
def test_each_algorithm_resolves_its_defaults_in_one_place(algorithm, schedule, method):
    solver = SolverConfig(nfe=2, t_end=1.5).resolve(algorithm)
    assert (solver.schedule, solver.method) == (schedule, method)
    assert solver.t_end == (1.0 if algorithm == "ddim" else 1.5)
    assert solver.resolve(algorithm) == solver  # idempotent


def test_bad_settings_are_refused_with_their_name():
    with pytest.raises(ValueError, match="NFE must be a positive integer"):
        SolverConfig(nfe=0).resolve("rfmp")
    with pytest.raises(ValueError, match="unknown ODE method 'heun'"):
        SolverConfig(method="heun").resolve("srfmp")
    with pytest.raises(ValueError, match=r"unknown solver field\(s\) \['steps'\]"):
        SolverConfig.from_dict({"nfe": 1, "steps": 3})
    with pytest.raises(ValueError, match="unknown algorithm"):
        SolverConfig().resolve("dp")


def test_policy_graph_and_metadata_read_the_same_solver(make_tiny_model):
    model = fitted(make_tiny_model("srfmp", "S2", horizon=4))
    solver = SolverConfig(nfe=3, t_end=1.2)
    policy = FlowPolicy(model, solver=solver)
    legacy = FlowPolicy(model, nfe=3, t_end=1.2)
    graph = InferenceGraph(model, solver=solver)
    assert policy.solver == legacy.solver == graph.solver == solver.resolve("srfmp")
    meta = onnx_metadata(graph, control_rate_hz=10.0)
    assert (meta["nfe"], meta["t_end"], meta["schedule"], meta["method"]) == (
        "3", "1.2", "srfmp", "euler")
    obs = torch.randn(2, 2, 3)
    with set_exploration_type(ExplorationType.DETERMINISTIC), torch.no_grad():
        a = policy(TensorDict({"observation": obs}, [2]))["action"]
        b = legacy(TensorDict({"observation": obs}, [2]))["action"]
    torch.testing.assert_close(a, b)
    with pytest.raises(TypeError, match="either solver= or"):
        FlowPolicy(model, solver=solver, nfe=1)
    with pytest.raises(ValueError, match="refine_dt"):  # validated at construction
        FlowPolicy(model, solver=SolverConfig(nfe=3, refine_dt=5.0))


def test_checkpoints_store_the_solver_and_policies_start_from_it(tmp_path, make_tiny_model):
    model = fitted(make_tiny_model("rfmp", "S2", horizon=4))
    path = save_checkpoint(tmp_path / "a.pt", model, solver=SolverConfig(nfe=4, t_end=1.6))
    assert read_checkpoint(path)["solver"] == {"nfe": 4, "t_end": 1.6, "method": "euler",
                                               "schedule": "uniform", "refine_dt": None}
    assert FlowPolicy.from_checkpoint(path).solver.nfe == 4
    assert FlowPolicy.from_checkpoint(path, nfe=2, t_end=1.0).solver == SolverConfig(
        2, 1.0, "euler", "uniform")
    # A checkpoint written before solvers were stored: the algorithm's defaults at NFE 1.
    payload = torch.load(path, weights_only=True)
    del payload["solver"]
    torch.save(payload, tmp_path / "old.pt")
    assert FlowPolicy.from_checkpoint(tmp_path / "old.pt").solver == SolverConfig(
        1, 1.0, "euler", "uniform")


def test_exporter_defaults_to_the_checkpoint_solver(tmp_path, make_tiny_model, to_onnx_cli):
    onnx = pytest.importorskip("onnx")
    model = fitted(make_tiny_model("srfmp", "S2", horizon=4))
    ckpt = save_checkpoint(tmp_path / "c.pt", model,
                           solver=SolverConfig(nfe=2, t_end=1.4, method="midpoint"),
                           control_rate_hz=10.0)
    result = to_onnx_cli("--checkpoint", ckpt)
    assert result.returncode == 0, result.stderr
    out = tmp_path / "policy_srfmp_nfe2.onnx"
    meta = {p.key: p.value for p in onnx.load(str(out)).metadata_props}
    assert (meta["nfe"], meta["t_end"], meta["method"]) == ("2", "1.4", "midpoint")
