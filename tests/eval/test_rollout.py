"""The evaluation sweep: which (NFE, T) settings run, the T each reaches, per-seed results that
depend on the seed alone (not on how many envs step side by side), and the config's checks."""

from __future__ import annotations

import functools
import math

import pytest
import torch

pytest.importorskip("gym_pusht")

from torchrl.modules import MultiStepActorWrapper  # noqa: E402

from rfmp_rl import keys  # noqa: E402
from rfmp_rl.envs.pusht import make_pusht_env  # noqa: E402
from rfmp_rl.eval import (  # noqa: E402
    EvalConfig,
    evaluate,
    reached_time,
    seed_max,
    seed_mean,
    seed_std,
    sweep,
    sweep_settings,
)
from rfmp_rl.modules import FlowPolicy, ModelConfig, build_model  # noqa: E402
from rfmp_rl.solvers import SolverConfig  # noqa: E402


def _model(algorithm: str):
    torch.manual_seed(0)
    model = build_model(ModelConfig(algorithm=algorithm, action_manifold="R2", obs_dim=20,
                                    horizon=4, action_steps=2, down_dims=[8, 16]))
    model.action_normalizer.set_stats(torch.zeros(2), torch.full((2,), 512.0))
    model.obs_normalizer.set_stats(torch.zeros(20), torch.full((20,), 512.0))
    return model.eval()


def _actor(model):
    def make(nfe: int, t_end: float):
        policy = FlowPolicy(model, observation_key=keys.OBS_WINDOW,
                            solver=SolverConfig(nfe=nfe, t_end=t_end).resolve(
                                model.cfg.algorithm))
        return MultiStepActorWrapper(policy, n_steps=model.cfg.horizon,
                                     replan_interval=model.cfg.action_steps)
    return make


def _metrics(rollout, steps):
    return {"score": rollout["next", "max_coverage"][:, -1, 0].tolist(),
            "first_x": rollout[keys.ACTION][:, 0, 0].tolist(),
            "short": [float("nan")] * len(steps)}  # a figure no episode defines


ENV = functools.partial(make_pusht_env, max_steps=6)


def test_settings_sweep_every_nfe_at_every_t_then_the_time_table_and_ddim_at_t1():
    assert sweep_settings("srfmp", [1, 3], [1.0, 1.6], [[3, 1.0], [4, 1.6]]) == [
        (1, 1.0), (3, 1.0), (1, 1.6), (3, 1.6), (4, 1.6)]
    assert sweep_settings("ddim", [1, 3], [1.0, 1.6], [[4, 1.6]]) == [(1, 1.0), (3, 1.0)]
    cfg = EvalConfig(nfes=[2], t_ends=[1.2], time_table=[[5, 1.0]])
    assert cfg.settings("rfmp") == [(2, 1.2), (5, 1.0)] and cfg.settings("ddim") == [(2, 1.0)]


def test_reached_time_is_what_the_solver_integrates():
    srfmp, rfmp = _model("srfmp"), _model("rfmp")
    assert reached_time(srfmp, 1, 1.0) == pytest.approx(1 / 2.5)  # first step 1 / lambda_x
    assert reached_time(srfmp, 3, 1.6) == pytest.approx(1.2)  # 0.4 + two steps of 0.4
    assert reached_time(srfmp, 4, 1.6) == pytest.approx(1.6)
    assert reached_time(rfmp, 1, 1.6) == pytest.approx(1.6)


def test_sweep_rows_name_their_setting_and_do_not_depend_on_the_batching():
    model = _model("srfmp")
    cfg = EvalConfig(seeds=3, seed_start=40, nfes=[1, 2], t_ends=[1.0], max_steps=6)
    seen = []
    rows = sweep(ENV, model, _actor(model), cfg, _metrics, seed=0, labels={"algo": "srfmp"},
                 progress=seen.append)
    assert [(r["algo"], r["nfe"], r["t_end"]) for r in rows] == [("srfmp", 1, 1.0),
                                                                ("srfmp", 2, 1.0)]
    assert [r["nfe"] for r in seen] == [1, 2]
    assert rows[0]["t_reached"] == pytest.approx(0.4) and rows[1]["t_reached"] == pytest.approx(0.8)
    assert all(r["seeds"] == "40-42" and r["per_seed"]["seed"] == [40, 41, 42] for r in rows)
    assert rows[0]["env_steps"] == 18 and math.isnan(rows[0]["short"])
    assert rows[0]["score"] == pytest.approx(seed_mean(rows[0]["per_seed"]["score"]))
    # two envs side by side (seeds 40-41, then 42): the same episodes, the same rows (up to the
    # network's float rounding at another batch size)
    split = sweep(ENV, model, _actor(model), EvalConfig(**{**cfg.__dict__, "num_envs": 2}),
                  _metrics, seed=0)
    for a, b in zip(rows, split, strict=True):
        assert b["per_seed"]["first_x"] == pytest.approx(a["per_seed"]["first_x"], rel=1e-5)
        assert b["per_seed"]["score"] == pytest.approx(a["per_seed"]["score"], rel=1e-5)
    # one seed alone sees what it saw among the others
    alone = evaluate(ENV, model, _actor(model), 1, 1.0,
                     EvalConfig(seeds=1, seed_start=41, max_steps=6), _metrics, seed=0)
    assert alone.values["first_x"] == pytest.approx(rows[0]["per_seed"]["first_x"][1:2], rel=1e-5)
    # the run's seed offsets the prior noise: another seed, other actions
    other = evaluate(ENV, model, _actor(model), 1, 1.0, cfg, _metrics, seed=1)
    assert other.values["first_x"] != pytest.approx(rows[0]["per_seed"]["first_x"], rel=1e-3)


def test_ddim_sweeps_t1_only_and_deterministic_sampling_needs_no_noise():
    model = _model("ddim")
    cfg = EvalConfig(seeds=2, nfes=[1, 2], t_ends=[1.0, 1.6], max_steps=4,
                     sampling="deterministic")
    rows = sweep(ENV, model, _actor(model), cfg, _metrics)
    assert [(r["nfe"], r["t_end"], r["t_reached"]) for r in rows] == [(1, 1.0, 1.0),
                                                                     (2, 1.0, 1.0)]
    again = sweep(ENV, model, _actor(model), cfg, _metrics, seed=5)
    assert again[0]["per_seed"]["first_x"] == rows[0]["per_seed"]["first_x"]


def test_a_metric_with_the_wrong_number_of_values_is_named():
    model = _model("rfmp")
    with pytest.raises(ValueError, match="1 values of 'bad' for 2 seeds"):
        evaluate(ENV, model, _actor(model), 1, 1.0, EvalConfig(seeds=2, max_steps=2),
                 lambda rollout, steps: {"bad": [0.0]})


def test_the_episode_limit_must_come_from_somewhere():
    model = _model("rfmp")
    with pytest.raises(ValueError, match="eval.max_steps"):
        evaluate(ENV, model, _actor(model), 1, 1.0, EvalConfig(seeds=1), _metrics)


@pytest.mark.parametrize("changes,message", [
    ({"seeds": 0}, "eval.seeds"), ({"nfes": []}, "eval.nfes"), ({"t_ends": [0.0]}, "eval.t_ends"),
    ({"sampling": "mode"}, "eval.sampling"), ({"workers": 0}, "eval.workers"),
    ({"num_envs": 0}, "eval.num_envs"),
])
def test_bad_settings_are_named(changes, message):
    with pytest.raises(ValueError, match=message):
        EvalConfig(**changes)


def test_from_config_names_an_unknown_key():
    assert EvalConfig.from_config({"seeds": 3, "nfes": (1, 2)}).nfes == [1, 2]
    with pytest.raises(ValueError, match="eval.seed is not an evaluation setting"):
        EvalConfig.from_config({"seed": 3})


def test_seed_summaries_skip_undefined_values():
    assert seed_mean([1.0, float("nan"), 3.0]) == pytest.approx(2.0)
    assert seed_std([1.0, 3.0]) == pytest.approx(math.sqrt(2.0))
    assert math.isnan(seed_std([1.0])) and math.isnan(seed_mean([float("nan")]))
    assert seed_max([1e-8, float("nan"), 3e-8]) == 3e-8  # exact, no float32 rounding
