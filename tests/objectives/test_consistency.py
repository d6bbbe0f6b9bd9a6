"""Consistency Policy: the consistency distillation loss against closed-form consistency
functions, the frozen teacher, reductions, teachers given by checkpoint, and the student's
sampling, checkpoint and ONNX export."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from tensordict import TensorDict
from torch import nn

from rfmp_rl.checkpoint import load_checkpoint, save_checkpoint
from rfmp_rl.modules import ConsistencyModel, DiffusionModel, FlowPolicy, build_model
from rfmp_rl.objectives import ConsistencyDistillationLoss, LossConfig, make_loss
from rfmp_rl.solvers import SolverConfig

STEP = 10  # LossConfig.teacher_step (the default)


def teacher_and_student(make_tiny_model, manifold="R2", **kw):
    teacher = make_tiny_model("ddim", manifold, **kw)
    return teacher, ConsistencyModel.from_teacher(teacher)


def batch(model, n=64, generator=None, actions=None):
    if actions is None:
        actions = model.chunk.unflatten(model.chunk.random_base(n, generator=generator))
    n = actions.shape[0]
    return TensorDict({"observation": torch.randn(n, 2, model.cfg.obs_dim, generator=generator),
                       "action": actions}, [n])


# ----- closed-form teachers and students ---------------------------------------------------------
# On data whose law is known in the teacher's normalised action space (the normalisers of these
# tiny models are the identity), the exact noise predictor eps*(x_k, k) = E[eps | x_k] is known in
# closed form. In y = x / sqrt(ab_k) = a + sigma_k eps (sigma_k = sqrt(1 - ab_k) / sqrt(ab_k)),
# a DDIM step is an Euler step in sigma: y' = y - (sigma_k - sigma_k') eps*.


def sigmas(model) -> torch.Tensor:
    ab = model.alphas_cumprod.double()
    return ((1 - ab) / ab).sqrt()


class ClosedForm(nn.Module):
    """A UNet stand-in computing ``out(y, k)`` from the chunk and the step, in float64."""

    def __init__(self, model, out) -> None:
        super().__init__()
        self.sigma = sigmas(model)
        self.ab = model.alphas_cumprod.double()
        self.out = out

    def forward(self, sample, timestep, cond):
        k = timestep.round().long()
        ab = self.ab[k].view(-1, 1, 1)
        y = sample.double() / ab.sqrt()
        return self.out(y, self.sigma[k].view(-1, 1, 1), k).to(sample.dtype)


def consistent(model, f):
    """A student network whose consistency function is ``f(y, sigma, k)``: the output ``F`` with
    ``sqrt(ab) x + sqrt(1 - ab) F = f``, i.e. ``F = (f - ab y) / sqrt(1 - ab)``."""
    def out(y, sg, k):
        ab = 1 / (1 + sg ** 2)
        return (f(y, sg, k) - ab * y) / (1 - ab).sqrt()

    return ClosedForm(model, out)


def chain_factor(model, k: int, mu_s2: float) -> float:
    """Gaussian data N(mu, s^2): the factor P with y_clean - mu = P (y_k - mu) after the
    teacher's exact DDIM steps k -> k - STEP -> ... -> clean (sigma = 0)."""
    sigma = sigmas(model)
    factor = 1.0
    while k >= 0:
        s_now = float(sigma[k])
        s_next = float(sigma[k - STEP]) if k - STEP >= 0 else 0.0
        factor *= 1 - (s_now - s_next) * s_now / (mu_s2 + s_now ** 2)
        k -= STEP
    return factor


def distillation_loss(teacher, student, actions, seed=0):
    loss = ConsistencyDistillationLoss(student, teacher=teacher)
    torch.manual_seed(seed)
    return float(loss(batch(student, actions=actions))["loss_consistency"].detach())


def test_an_exact_consistency_function_of_dirac_data_has_zero_loss(make_tiny_model):
    # Every demonstration is the same chunk c: eps* = (x - sqrt(ab) c) / sqrt(1 - ab) is
    # constant along the probability-flow ODE's trajectories, so the teacher's DDIM step is exact
    # on that ODE and the exact consistency function is f = c everywhere. The student that is f
    # has zero loss (below 1e-8; measured 1e-15, float32 rounding).
    teacher, student = teacher_and_student(make_tiny_model)
    c = torch.tensor([0.3, -0.6]).repeat(4).view(1, 4, 2)  # the chunk (T_p = 4, D = 2)
    teacher.network = ClosedForm(teacher, lambda y, s, k: (y - c) / s)
    student.network = consistent(student, lambda y, s, k: c.expand_as(y))
    actions = c.expand(256, 4, 2)
    zero = distillation_loss(teacher, student, actions)
    assert zero < 1e-8
    # consistent along the trajectories but ending 0.05 off c: the steps k < STEP, whose target
    # is the teacher's clean estimate (f(x, clean) = x), pay 0.05^2, a tenth of the draws
    student.network = consistent(student, lambda y, s, k: (c + 0.05).expand_as(y))
    off = distillation_loss(teacher, student, actions)
    assert 0.5 * 0.1 * 0.05 ** 2 < off < 2 * 0.1 * 0.05 ** 2
    # the exact f maps any noisy chunk to c in one evaluation
    student.network = consistent(student, lambda y, s, k: c.expand_as(y))
    noise = torch.randn(8, student.noise_dim)
    out = student.sample(torch.zeros(8, 1), noise, nfe=1)
    torch.testing.assert_close(out, c.expand(8, 4, 2), atol=1e-5, rtol=0)


def test_the_exact_consistency_function_of_gaussian_data_has_zero_loss_and_the_denoiser_not(
    make_tiny_model,
):
    # Demonstrations ~ N(mu, s^2) per coordinate: eps* = sigma (y - mu) / (s^2 + sigma^2), each
    # teacher DDIM step is affine, and the teacher's consistency function (the end of its
    # STEP-strided DDIM chain) is f = mu + P(k) (y - mu) with P the product of the steps'
    # factors. That student has zero loss; the one-step denoiser E[a | x_k] (the teacher's own
    # one-step estimate, what the student is initialised to) is not a consistency function here
    # and its loss is clearly positive (measured: exact 3e-13, tolerance 1e-8; denoiser 2.1e-3).
    mu, s = 0.2, 0.5
    teacher, student = teacher_and_student(make_tiny_model, clip_sample=False)
    teacher.network = ClosedForm(teacher, lambda y, sg, k: sg * (y - mu) / (s ** 2 + sg ** 2))
    factors = torch.tensor([chain_factor(student, k, s ** 2) for k in range(100)],
                           dtype=torch.float64)
    student.network = consistent(student,
                                 lambda y, sg, k: mu + (y - mu) * factors[k].view(-1, 1, 1))
    gen = torch.Generator().manual_seed(1)
    actions = mu + s * torch.randn(512, 4, 2, generator=gen)
    zero = distillation_loss(teacher, student, actions)
    assert zero < 1e-8
    student.network = consistent(student,  # E[a | y] = y - sigma^2 (y - mu) / (s^2 + sigma^2)
                                 lambda y, sg, k: y - sg ** 2 * (y - mu) / (s ** 2 + sg ** 2))
    denoiser = distillation_loss(teacher, student, actions)
    assert denoiser > 1e-3 and denoiser > 1e5 * max(zero, 1e-12)
    # Against the continuous probability-flow ODE's consistency function mu + s (y - mu) /
    # sqrt(s^2 + sigma^2) the loss is the teacher's discretisation error: small, not zero (1e-4).
    student.network = consistent(
        student, lambda y, sg, k: mu + (y - mu) * s / (s ** 2 + sg ** 2).sqrt())
    ode = distillation_loss(teacher, student, actions)
    assert zero < ode < denoiser


# ----- the frozen teacher ------------------------------------------------------------------------
def test_an_optimiser_step_changes_the_student_and_leaves_the_teacher_unchanged(make_tiny_model):
    teacher, student = teacher_and_student(make_tiny_model)
    policy = FlowPolicy(student, nfe=1)
    loss = make_loss(policy, teacher=teacher)
    assert isinstance(loss, ConsistencyDistillationLoss) and loss.model is student
    assert all(not p.requires_grad for p in loss.teacher.parameters())
    # the teacher is a frozen copy: not the caller's module, not in the student's parameters
    assert loss.teacher is not teacher
    student_ids = {id(p) for p in student.parameters()}
    assert not student_ids & {id(p) for p in loss.teacher.parameters()}
    teacher_before = {k: v.clone() for k, v in loss.teacher.state_dict().items()}
    student_before = {k: v.clone() for k, v in student.state_dict().items()}
    # the student starts as the teacher (Consistency Policy initialises it so)
    assert all(torch.equal(student_before[k], v) for k, v in teacher_before.items())
    optimiser = torch.optim.Adam(student.parameters(), lr=1e-2)
    loss.train()
    assert not loss.teacher.training
    gen = torch.Generator().manual_seed(0)
    for _ in range(2):
        out = loss(batch(student, 32, gen))
        optimiser.zero_grad()
        out["loss_consistency"].backward()
        assert all(p.grad is None for p in loss.teacher.parameters())
        optimiser.step()
    for key, value in loss.teacher.state_dict().items():
        assert torch.equal(value, teacher_before[key]), key
    changed = [k for k, v in student.state_dict().items() if not torch.equal(v, student_before[k])]
    assert any(k.startswith("network.") for k in changed)
    assert not any(k.startswith(("action_normalizer", "obs_normalizer")) for k in changed)
    assert "teacher" not in " ".join(student.state_dict())


def test_reduction_none_gives_one_loss_per_sample(make_tiny_model):
    teacher, student = teacher_and_student(make_tiny_model)
    td = batch(student, 6, torch.Generator().manual_seed(0))
    td["prior_noise"] = torch.randn(6, student.noise_dim)
    td["flow_time"] = torch.rand(6, 1)
    per_sample = ConsistencyDistillationLoss(student, teacher=teacher, reduction="none")(td)
    mean = ConsistencyDistillationLoss(student, teacher=teacher)(td)
    summed = ConsistencyDistillationLoss(student, teacher=teacher, reduction="sum")(td)
    values = per_sample["loss_consistency"]
    assert values.shape == (6,) and (values > 0).all()
    torch.testing.assert_close(values.mean(), mean["loss_consistency"])
    torch.testing.assert_close(values.sum(), summed["loss_consistency"])
    # padded steps do not count: a sample whose later steps are padding averages its first ones
    td["action_is_pad"] = torch.zeros(6, 4, dtype=torch.bool)
    td["action_is_pad"][0, 2:] = True
    padded = ConsistencyDistillationLoss(student, teacher=teacher, reduction="none")(td)
    assert not torch.isclose(padded["loss_consistency"][0], values[0])
    torch.testing.assert_close(padded["loss_consistency"][1:], values[1:])


def test_the_boundary_the_parameterisation_and_the_teacher_step(make_tiny_model):
    # f(x, -1) = x for any network (the boundary condition by parameterisation); elsewhere
    # f = sqrt(ab) x + sqrt(1 - ab) F; the loss's teacher step from k to -1 is the teacher's
    # DDIM clean estimate, and from k to k' its DDIM update.
    teacher, student = teacher_and_student(make_tiny_model, clip_sample=False)
    x, cond = torch.randn(5, student.chunk.dim), torch.randn(5, student.obs_encoder.out_dim)
    torch.testing.assert_close(student.consistency(x, torch.full((5,), -1), cond), x)
    k = torch.tensor([0, 7, 50, 98, 99])
    ab = student.alphas_cumprod[k].unsqueeze(-1)
    network = student.predict_noise(x, k.float(), cond)
    torch.testing.assert_close(student.consistency(x, k, cond),
                               ab.sqrt() * x + (1 - ab).sqrt() * network)
    loss = ConsistencyDistillationLoss(student, teacher=teacher)
    eps = teacher.predict_noise(x, k.float(), cond)
    clean = (x - (1 - ab).sqrt() * eps) / ab.sqrt()
    torch.testing.assert_close(loss.teacher_ddim_step(x, k, torch.full((5,), -1), cond), clean)
    earlier = (k - 3).clamp_min(0)
    ab_prev = student.alphas_cumprod[earlier].unsqueeze(-1)
    torch.testing.assert_close(loss.teacher_ddim_step(x, k, earlier, cond),
                               ab_prev.sqrt() * clean + (1 - ab_prev).sqrt() * eps)
    # the student starts with the teacher's weights (its features; the head's meaning differs)
    for name, value in teacher.state_dict().items():
        assert torch.equal(student.state_dict()[name], value), name


# ----- teachers given by checkpoint --------------------------------------------------------------
def test_a_teacher_checkpoint_is_loaded_and_recorded_and_a_wrong_one_named(tmp_path,
                                                                           make_tiny_model):
    teacher, student = teacher_and_student(make_tiny_model)
    path = save_checkpoint(tmp_path / "ddim.pt", teacher)
    loss = make_loss(student, LossConfig(teacher=str(path)))
    assert loss.loss_cfg.teacher == str(path)
    for key, value in teacher.state_dict().items():
        assert torch.equal(loss.teacher.state_dict()[key], value)
    assert float(loss(batch(student, 8))["loss_consistency"].detach()) >= 0
    flow = save_checkpoint(tmp_path / "srfmp.pt", make_tiny_model("srfmp", "R2"))
    with pytest.raises(ValueError, match=r"srfmp\.pt: the Consistency Policy's teacher must be a "
                                         r"Diffusion Policy checkpoint .*'srfmp'"):
        ConsistencyDistillationLoss(student, teacher=flow)
    with pytest.raises(FileNotFoundError, match="nope.pt"):
        make_loss(student, LossConfig(teacher=str(tmp_path / "nope.pt")))
    with pytest.raises(ValueError, match="needs a teacher"):
        make_loss(student)
    with pytest.raises(TypeError, match="give the teacher once"):
        make_loss(student, LossConfig(teacher=str(path)), teacher=teacher)
    with pytest.raises(ValueError, match="LossConfig.teacher .* for ddim"):
        make_loss(teacher, LossConfig(teacher=str(path)))
    with pytest.raises(ValueError, match="t0_fraction.*cp"):
        make_loss(student, LossConfig(t0_fraction=0.1), teacher=teacher)


def test_a_student_that_does_not_match_its_teacher_is_refused(make_tiny_model):
    teacher = make_tiny_model("ddim", "R2")
    other = build_model(ConsistencyModel.from_teacher(make_tiny_model("ddim", "R2", horizon=8)).cfg)
    with pytest.raises(ValueError, match=r"differ in horizon: student 8, teacher 4"):
        ConsistencyDistillationLoss(other, teacher=teacher)
    student = ConsistencyModel.from_teacher(teacher)
    student.action_normalizer.fit(torch.randn(32, 2) * 3)
    with pytest.raises(ValueError, match="action_normalizer differs"):
        ConsistencyDistillationLoss(student, teacher=teacher)
    with pytest.raises(TypeError, match="needs a ConsistencyModel"):
        ConsistencyDistillationLoss(teacher, teacher=teacher)
    with pytest.raises(TypeError, match="must be a Diffusion Policy"):
        ConsistencyModel.from_teacher(make_tiny_model("rfmp", "R2"))


# ----- the student: sampling, checkpoint, export -------------------------------------------------
def test_multistep_sampling_denoises_renoises_with_a_fresh_draw_and_denoises(make_tiny_model):
    _, student = teacher_and_student(make_tiny_model)
    student.eval()
    assert student.consistency_timesteps(1) == [99]
    assert student.consistency_timesteps(2) == [99, 49]
    assert student.consistency_timesteps(100) == list(range(99, -1, -1))
    with pytest.raises(ValueError, match=r"NFE must be in \[1, 100\]"):
        student.consistency_timesteps(0)
    dim = student.noise_dim
    assert (student.prior_noise_dim(1), student.prior_noise_dim(3)) == (dim, 3 * dim)
    cond, draws = torch.randn(3, student.obs_encoder.out_dim), torch.randn(3, 2 * dim)
    z, xi = draws[:, :dim], draws[:, dim:]
    with torch.no_grad():
        first = student.consistency(z, torch.full((3,), 99), cond).clamp(-1, 1)
        ab = student.alphas_cumprod[49]
        second = student.consistency(ab.sqrt() * first + (1 - ab).sqrt() * xi,
                                     torch.full((3,), 49), cond).clamp(-1, 1)
        torch.testing.assert_close(student.sample(cond, z, nfe=1),
                                   student.unnormalize_action(student.chunk.projx(first)))
        torch.testing.assert_close(student.sample(cond, draws, nfe=2),
                                   student.unnormalize_action(student.chunk.projx(second)))
        # the start draw alone: the re-noising draw comes from torch's generator
        torch.manual_seed(5)
        partial = student.sample(cond, z, nfe=2)
        torch.manual_seed(5)
        fresh = torch.randn(3, dim)
        torch.testing.assert_close(partial, student.sample(cond, torch.cat([z, fresh], -1),
                                                           nfe=2))
        # deterministic: every draw zero
        zeros = torch.zeros(3, 2 * dim)
        torch.testing.assert_close(student.sample(cond, deterministic=True, nfe=2),
                                   student.sample(cond, zeros, nfe=2))
    for bad in (torch.randn(3, dim + 1), torch.randn(3, 3 * dim)):
        with pytest.raises(ValueError, match=r"NFE 2 takes 1 to 2 prior draws"):
            student.sample(cond, bad, nfe=2)


def test_the_student_checkpoint_loads_and_acts_without_the_teacher(tmp_path, make_tiny_model):
    teacher, student = teacher_and_student(make_tiny_model, manifold="S2")
    teacher_path = save_checkpoint(tmp_path / "ddim.pt", teacher)
    loss = make_loss(student, LossConfig(teacher=str(teacher_path)))
    path = save_checkpoint(tmp_path / "cp.pt", student, loss=loss,
                           solver=SolverConfig(nfe=1))
    teacher_path.unlink()  # not needed to act
    model, payload = load_checkpoint(path)
    assert isinstance(model, ConsistencyModel) and payload["algorithm"] == "cp"
    assert payload["loss"]["teacher"] == str(teacher_path)
    assert not any("teacher" in k for k in payload["state_dict"])
    policy = FlowPolicy.from_checkpoint(path)
    assert policy.solver == SolverConfig(1, 1.0, "consistency", "consistency", None)
    action = policy(TensorDict({"observation": torch.randn(5, 2, 3)}, [5]))["action"]
    assert action.shape == (5, 4, 3)
    torch.testing.assert_close(action.norm(dim=-1), torch.ones(5, 4))
    assert isinstance(teacher, DiffusionModel) and not isinstance(teacher, ConsistencyModel)


@pytest.mark.parametrize("nfe", [1, 3])
def test_the_exported_graph_equals_the_pytorch_policy(tmp_path, make_tiny_model, nfe):
    ort = pytest.importorskip("onnxruntime")
    from rfmp_rl.onnx_export import InferenceGraph, export_onnx

    _, student = teacher_and_student(make_tiny_model, manifold="R2")
    gen = torch.Generator().manual_seed(0)
    student.action_normalizer.fit(torch.randn(64, 2, generator=gen) * 2 + 1)
    student.obs_normalizer.fit(torch.randn(32, 3, generator=gen) * 4)
    student.eval()
    report = export_onnx(student, tmp_path / "cp.onnx", nfe=nfe, control_rate_hz=10.0)
    assert report.max_abs_diff <= 1e-4
    assert (report.metadata["algorithm"], report.metadata["nfe"],
            report.metadata["method"]) == ("cp", str(nfe), "consistency")
    session = ort.InferenceSession(str(tmp_path / "cp.onnx"), providers=["CPUExecutionProvider"])
    assert report.metadata["noise"].count(f'"dim": {student.prior_noise_dim(nfe)}') == 1
    obs = torch.randn(4, 2, 3, generator=gen) * 4
    noise = torch.randn(4, student.prior_noise_dim(nfe), generator=gen)  # one draw per NFE
    got = session.run(["action"], {"observation": obs.numpy(), "prior_noise": noise.numpy()})[0]
    with torch.no_grad():
        graph = InferenceGraph(student, nfe=nfe)(obs, noise)
        policy = FlowPolicy(student, nfe=nfe)(TensorDict({"observation": obs,
                                                          "prior_noise": noise}, [4]))["action"]
    torch.testing.assert_close(graph, policy)
    np.testing.assert_allclose(got, policy.numpy(), atol=1e-4 * float(
        student.action_normalizer.scale.max()), rtol=0)


def test_a_checkpoint_written_before_the_teacher_options_reads_with_their_defaults(tmp_path,
                                                                                   make_tiny_model):
    path = save_checkpoint(tmp_path / "old.pt", make_tiny_model("srfmp"),
                           loss=LossConfig(time_max=2.0))
    payload = torch.load(path, weights_only=False)
    for name in ("teacher", "teacher_step"):
        del payload["loss"][name]
    torch.save(payload, path)
    from rfmp_rl.checkpoint import read_checkpoint

    assert read_checkpoint(path)["loss"] == LossConfig(time_max=2.0).to_dict()


@pytest.mark.slow
def test_distillation_moves_a_trainable_student_to_the_teachers_consistency_function(
    make_tiny_model,
):
    # The closed-form Gaussian teacher of the test above, a tiny trainable UNet student: 300
    # Adam steps on the loss alone bring the student's f within reach of the exact consistency
    # function of the teacher's sampler (mean squared error 0.13 at the start, 0.006 measured
    # after; 15 s on one CPU thread).
    mu, s = 0.2, 0.5
    teacher, student = teacher_and_student(make_tiny_model, clip_sample=False)
    teacher.network = ClosedForm(teacher, lambda y, sg, k: sg * (y - mu) / (s ** 2 + sg ** 2))
    loss = ConsistencyDistillationLoss(student, teacher=teacher)
    factors = torch.tensor([chain_factor(student, k, s ** 2) for k in range(100)],
                           dtype=torch.float64)
    gen = torch.Generator().manual_seed(3)
    k = torch.randint(0, 100, (2048,), generator=gen)
    x = student.add_noise(mu + s * torch.randn(2048, 8, generator=gen),
                          torch.randn(2048, 8, generator=gen), k)
    ab = student.alphas_cumprod.double()[k].unsqueeze(-1)
    exact = (mu + (x.double() / ab.sqrt() - mu) * factors[k].unsqueeze(-1)).float()
    cond = student.encode(torch.zeros(2048, 2, 3))

    def error() -> float:
        with torch.no_grad():
            return float(((student.consistency(x, k, cond) - exact) ** 2).mean())

    start = error()
    torch.manual_seed(0)
    optimiser = torch.optim.Adam(student.parameters(), lr=1e-3)
    for _ in range(300):
        out = loss(batch(student, actions=mu + s * torch.randn(256, 4, 2)))
        optimiser.zero_grad()
        out["loss_consistency"].backward()
        optimiser.step()
    assert start > 0.05 and error() < min(0.03, start / 5)
