"""FlowPolicy / VectorField as TensorDict modules, alone and inside TorchRL's rollout machinery."""

from __future__ import annotations

import pytest
import torch
from tensordict import TensorDict
from torchrl.envs.utils import ExplorationType, set_exploration_type

from rfmp_rl.modules import FlowPolicy, VectorField

ALGOS = ["rfmp", "srfmp", "ddim"]


@pytest.mark.parametrize("algorithm", ALGOS)
def test_policy_writes_an_on_manifold_chunk_for_any_leading_shape(make_tiny_model, algorithm):
    model = make_tiny_model(algorithm, "R3 x S3 x R1", horizon=8).eval()
    policy = FlowPolicy(model, nfe=4)
    for lead in [(), (5,), (2, 3)]:
        td = TensorDict({"observation": torch.randn(*lead, 2, 3)}, batch_size=lead)
        action = policy(td)["action"]
        assert action.shape == (*lead, 8, 8)
        quat = action[..., 3:7]
        assert ((quat.norm(dim=-1) - 1).abs() <= 1e-5).all()


@pytest.mark.parametrize("algorithm", ALGOS)
def test_deterministic_mode_starts_from_a_fixed_base_sample(make_tiny_model, algorithm):
    model = make_tiny_model(algorithm, "S2").eval()
    policy = FlowPolicy(model, nfe=2)
    td = TensorDict({"observation": torch.randn(4, 2, 3)}, [4])
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        a1 = policy(td.clone())["action"]
        a2 = policy(td.clone())["action"]
    torch.testing.assert_close(a1, a2, rtol=0, atol=0)
    torch.manual_seed(1)
    r1 = policy(td.clone())["action"]
    r2 = policy(td.clone())["action"]
    assert not torch.equal(r1, r2)  # random exploration draws fresh prior samples
    if algorithm != "ddim":
        x0 = model.initial_state(None, 3, deterministic=True)[..., : model.chunk.dim]
        torch.testing.assert_close(model.chunk.projx(x0), x0)  # the fixed start is on S^2


def test_prior_noise_in_the_input_makes_sampling_reproducible(make_tiny_model):
    model = make_tiny_model("srfmp", "S2").eval()
    policy = FlowPolicy(model, nfe=1)
    noise = torch.randn(4, model.noise_dim)
    td = TensorDict({"observation": torch.randn(4, 2, 3), "prior_noise": noise}, [4])
    a1, a2 = policy(td.clone())["action"], policy(td.clone())["action"]
    torch.testing.assert_close(a1, a2, rtol=0, atol=0)
    cond = model.encode(td["observation"])
    torch.testing.assert_close(a1, model.sample(cond, noise, nfe=1))


def test_policy_refuses_a_budget_the_solver_cannot_meet(make_tiny_model):
    model = make_tiny_model("rfmp", "S2")
    with pytest.raises(ValueError, match="NFE=3"):
        FlowPolicy(model, nfe=3, method="rk4")


def test_vector_field_module_matches_the_model(make_tiny_model):
    for algorithm in ("rfmp", "srfmp"):
        model = make_tiny_model(algorithm, "S2")
        vf = VectorField(model, observation_key=("obs", "state"))
        x = model.chunk.random_base(5)
        td = TensorDict(
            {("obs", "state"): torch.randn(5, 2, 3), "x_t": x, "time": torch.rand(5, 1)}, [5]
        )
        out = vf(td)
        expected = model.velocity(x, td["time"], model.encode(td["obs", "state"]))
        if algorithm == "srfmp":
            torch.testing.assert_close(out["velocity"], expected[0])
            torch.testing.assert_close(out["velocity_tau"], expected[1])
        else:
            torch.testing.assert_close(out["velocity"], expected)


def _pendulum_env():
    gym = pytest.importorskip("gymnasium")
    del gym
    from torchrl.envs import CatFrames, Compose, GymEnv, InitTracker, SerialEnv, TransformedEnv
    from torchrl.envs.transforms import UnsqueezeTransform

    # MultiStepActorWrapper needs a batched env (it re-indexes the batch on re-planning).
    return TransformedEnv(
        SerialEnv(1, lambda: GymEnv("Pendulum-v1")),
        Compose(
            InitTracker(),
            UnsqueezeTransform(dim=-2, in_keys=["observation"], out_keys=["obs_step"]),
            CatFrames(N=2, dim=-2, in_keys=["obs_step"], out_keys=["obs_window"]),
        ),
    )


def test_multistep_wrapper_executes_t_a_actions_of_each_chunk_in_a_gym_rollout(make_tiny_model):
    from torchrl.modules import MultiStepActorWrapper

    env = _pendulum_env()
    env.set_seed(0)
    model = make_tiny_model("srfmp", "R1", horizon=4)  # T_p = 4, T_a = 2
    policy = FlowPolicy(model, nfe=1, observation_key="obs_window")
    calls = []
    original = model.sample

    def counting_sample(*args, **kw):
        out = original(*args, **kw)
        calls.append(out.clone())
        return out

    model.sample = counting_sample
    actor = MultiStepActorWrapper(policy, n_steps=4, replan_interval=2)
    rollout = env.rollout(10, actor, break_when_any_done=False)
    assert rollout["action"].shape == (1, 10, 1)
    assert len(calls) == 5  # one chunk every T_a = 2 steps
    executed = rollout["action"].reshape(5, 2, 1)
    torch.testing.assert_close(executed, torch.stack([c[0, :2] for c in calls]))


def test_flow_policy_runs_inside_a_sync_data_collector(make_tiny_model):
    # torchrl 0.14 names the single-process synchronous collector `Collector`
    # (formerly `SyncDataCollector`).
    from torchrl.collectors import Collector
    from torchrl.modules import MultiStepActorWrapper

    model = make_tiny_model("rfmp", "R1", horizon=4)
    actor = MultiStepActorWrapper(
        FlowPolicy(model, nfe=2, observation_key="obs_window"), n_steps=4, replan_interval=2
    )
    collector = Collector(_pendulum_env, actor, frames_per_batch=8, total_frames=16)
    batches = list(collector)
    collector.shutdown()
    assert len(batches) == 2
    for batch in batches:
        assert batch["action"].shape == (1, 8, 1)
        assert torch.isfinite(batch["next", "reward"]).all()


@pytest.mark.parametrize("repeat", [True, False])
def test_prior_repeat_sets_one_base_action_or_one_per_step(make_tiny_model, repeat):
    model = make_tiny_model("rfmp", horizon=4, prior_repeat=repeat)
    assert model.noise_dim == (3 if repeat else 12)
    x0 = model.chunk.unflatten(model.prior.from_noise(torch.randn(5, model.noise_dim)))
    same = bool((x0 == x0[:, :1]).all())
    assert same == repeat
    assert float((x0.norm(dim=-1) - 1).abs().max()) < 1e-6
    chunk = model.sample(model.encode(torch.randn(5, 2, 3)), nfe=2)
    assert chunk.shape == (5, 4, 3)
