"""LossConfig: the training-time options the losses own (time sampling, time_max, t0_fraction,
the SRFMP rates), their checks per algorithm, and the losses built from the actor with them."""

from __future__ import annotations

import math

import pytest
import torch
from tensordict import TensorDict
from torchrl.modules import MultiStepActorWrapper

from rfmp_rl.flows import StablePath
from rfmp_rl.modules import FlowPolicy, ModelConfig
from rfmp_rl.objectives import DiffusionPolicyLoss, LossConfig, RFMPLoss, SRFMPLoss, make_loss


def test_loss_config_round_trips_and_names_an_unknown_field():
    cfg = LossConfig(time_sampling="tau", time_max=3.0, t0_fraction=0.2, lambda_x=2.0,
                     lambda_tau=1.5)
    assert LossConfig.from_dict(cfg.to_dict()) == cfg
    assert LossConfig.from_dict(None) == LossConfig()
    assert [f for f in LossConfig().to_dict()] == ["time_sampling", "time_max", "t0_fraction",
                                                   "lambda_x", "lambda_tau", "teacher",
                                                   "teacher_step"]
    with pytest.raises(ValueError, match=r"unknown fields \['time_maxx'\]"):
        LossConfig.from_dict({"time_maxx": 2.0})


@pytest.mark.parametrize(("algorithm", "kwargs", "match"), [
    ("rfmp", {"time_max": 2.0}, "time_max.*rfmp"),
    ("ddim", {"time_max": 2.0}, "time_max.*ddim"),
    ("srfmp", {"time_max": 0.0}, "time_max"),
    ("srfmp", {"t0_fraction": 1.0}, "t0_fraction"),
    ("srfmp", {"t0_fraction": -0.1}, "t0_fraction"),
    ("ddim", {"t0_fraction": 0.2}, "t0_fraction.*ddim"),
    ("srfmp", {"time_sampling": "log"}, "time_sampling"),
    ("rfmp", {"time_sampling": "tau"}, "time_sampling='tau'.*rfmp"),
    ("srfmp", {"lambda_tau": 0.0}, "lambda_tau"),
    ("srfmp", {"lambda_x": -1.0}, "lambda_x"),
])
def test_settings_that_do_not_apply_to_the_algorithm_are_refused(make_tiny_model, algorithm,
                                                                  kwargs, match):
    with pytest.raises(ValueError, match=match):
        LossConfig(**kwargs).check(algorithm)
    with pytest.raises(ValueError, match=match):  # the loss checks at construction
        make_loss(make_tiny_model(algorithm), LossConfig(**kwargs))


def test_model_config_no_longer_takes_the_training_options():
    for name in ("time_sampling", "time_max", "t0_fraction", "lambda_tau", "control_rate_hz"):
        assert name not in ModelConfig.__dataclass_fields__
    with pytest.raises(TypeError):
        ModelConfig("srfmp", "S2", obs_dim=3, time_max=2.0)


@pytest.mark.parametrize("algorithm", ["rfmp", "srfmp"])
def test_t0_fraction_puts_that_share_of_training_times_at_the_start(make_tiny_model, algorithm):
    torch.manual_seed(0)
    model = make_tiny_model(algorithm)
    plain = make_loss(model).sample_times(20000)
    times = make_loss(model, LossConfig(t0_fraction=0.3)).sample_times(20000)
    assert times.shape == (20000, 1)
    assert float((plain == 0).float().mean()) < 1e-3
    assert abs(float((times == 0).float().mean()) - 0.3) < 0.02
    rest = times[times > 0]
    assert float(rest.max()) <= 1.0 and abs(float(rest.mean()) - float(plain.mean())) < 0.02


def test_srfmp_time_max_trains_the_field_past_t_one_where_its_refinement_steps_land(
    make_tiny_model,
):
    # After the SRFMP schedule's first step (dt = 1/lambda) the integrated pseudo-time is at
    # tau1 = 1, which t in [0, 1] never reaches (tau(1) = 1 - exp(-2.5) = 0.918); time_max = 2
    # trains tau up to 0.993.
    torch.manual_seed(0)
    model = make_tiny_model("srfmp")
    loss = SRFMPLoss(model, LossConfig(time_max=2.0, t0_fraction=0.3))
    times = loss.sample_times(20000)
    assert float(times.max()) <= 2.0 and abs(float((times > 1).float().mean()) - 0.35) < 0.02
    tau = loss.path.tau_at(times)
    assert float(tau.max()) > 0.99 > float(loss.path.tau_at(torch.ones(1)))
    first = model.initial_state(None, 1)[..., -1:] + loss.path.tau_field(torch.zeros(1)) / 2.5
    assert torch.allclose(first, torch.ones(1))


def test_tau_sampling_makes_the_pseudo_time_uniform(make_tiny_model):
    torch.manual_seed(0)
    loss = SRFMPLoss(make_tiny_model("srfmp"), LossConfig(time_sampling="tau", time_max=3.0))
    tau = loss.path.tau_at(loss.sample_times(20000))
    top = float(loss.path.tau_at(torch.tensor([3.0])))
    assert abs(float(tau.mean()) - top / 2) < 0.01  # uniform on [0, tau(3)]
    assert abs(float((tau < top / 2).float().mean()) - 0.5) < 0.02


def test_the_srfmp_path_uses_the_loss_rates_and_the_model_pseudo_times(make_tiny_model):
    model = make_tiny_model("srfmp", lambda_x=3.0, tau0=0.1, tau1=0.9)
    loss = make_loss(model, LossConfig(lambda_x=3.0, lambda_tau=1.5))
    assert isinstance(loss.path, StablePath)
    assert (loss.path.lambda_x, loss.path.lambda_tau) == (3.0, 1.5)
    assert (loss.path.tau0, loss.path.tau1) == (0.1, 0.9)
    fresh = make_tiny_model("srfmp", lambda_x=3.0, tau0=0.1, tau1=0.9)
    assert make_loss(fresh).loss_cfg.lambda_x == 3.0  # the default follows the model
    with pytest.raises(ValueError, match=r"lambda_x=2.5 differs .*ModelConfig.lambda_x=3.0"):
        make_loss(make_tiny_model("srfmp", lambda_x=3.0), LossConfig(lambda_x=2.5))


def test_the_losses_take_the_actor_or_its_wrapper(make_tiny_model):
    for algorithm, cls in (("rfmp", RFMPLoss), ("srfmp", SRFMPLoss),
                           ("ddim", DiffusionPolicyLoss)):
        model = make_tiny_model(algorithm)
        policy = FlowPolicy(model, nfe=2)
        actor = MultiStepActorWrapper(policy, n_steps=4, replan_interval=2)
        for given in (policy, actor, model):
            loss = cls(given)
            assert loss.model is model
            assert type(make_loss(given)) is cls
    srfmp = make_tiny_model("srfmp")
    loss = make_loss(FlowPolicy(srfmp), {"time_max": 2.0}, reduction="sum")
    assert loss.loss_cfg == LossConfig(time_max=2.0) and loss.reduction == "sum"
    with pytest.raises(ValueError, match="reduction"):
        SRFMPLoss(srfmp, reduction="max")
    td = TensorDict({"observation": torch.randn(4, 2, 3),
                     "action": srfmp.chunk.unflatten(srfmp.chunk.random_base(4))}, [4])
    out = loss(td)
    (out["loss_srfmp"] + out["loss_tau"]).backward()
    assert all(p.grad is not None for p in srfmp.network.parameters())


def test_the_srfmp_loss_records_the_pseudo_time_it_trains_up_to(make_tiny_model):
    model = make_tiny_model("srfmp")
    assert model.cfg.tau_max is None
    loss = make_loss(model, LossConfig(time_max=2.0, lambda_tau=1.5))
    assert model.cfg.tau_max == pytest.approx(1 - math.exp(-3.0))
    assert float(loss.path.tau_at(torch.tensor(2.0))) == pytest.approx(model.cfg.tau_max)
    assert ModelConfig.from_dict(model.cfg.to_dict()).tau_max == model.cfg.tau_max
    with pytest.raises(ValueError, match=r"tau_max=0.950213 differs .*time_max=1.0"):
        make_loss(model, LossConfig(lambda_tau=1.5))
    assert make_tiny_model("rfmp").cfg.tau_max is None
    make_loss(make_tiny_model("rfmp"))  # nothing to record for RFMP


def test_srfmp_sampling_gives_the_network_tau_clamped_to_the_trained_range(make_tiny_model):
    torch.manual_seed(0)
    model = make_tiny_model("srfmp")
    cond, x = torch.randn(3, model.obs_encoder.out_dim), model.prior.sample(3)
    inside, beyond = torch.full((3, 1), 0.5), torch.full((3, 1), 1.3)
    free = [v.detach() for v in model.velocity(x, beyond, cond)]
    model.cfg.tau_max = 0.5
    clamped = model.velocity(x, beyond, cond)
    at_max = model.velocity(x, inside, cond)
    torch.testing.assert_close(clamped[0], at_max[0])
    assert not torch.allclose(free[0], clamped[0])
    below = model.velocity(x, torch.full((3, 1), -0.2), cond)  # clamped at tau0 too
    torch.testing.assert_close(below[0], model.velocity(x, torch.zeros(3, 1), cond)[0])
    with pytest.raises(ValueError, match="tau_max must lie between"):
        ModelConfig(algorithm="srfmp", down_dims=[16, 32], tau_max=1.2)
