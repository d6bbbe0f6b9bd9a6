"""The training engine on the CPU: DDP (2 gloo ranks) against one process, SIGTERM + resume
against an uninterrupted run, bf16 autocast, torch.compile against eager, loggers, and the
settings it refuses. CUDA-only paths skip with their reason."""

from __future__ import annotations

import math
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from toy import BatchList, fixed_batches, replay_buffer, tiny_model, toy_store

from rfmp_rl.checkpoint import load_checkpoint, read_checkpoint
from rfmp_rl.training import (
    LoggerConfig,
    OptimConfig,
    TrainConfig,
    Trainer,
    compile_networks,
    resolve_device,
    setup_runtime,
)

HERE = Path(__file__).resolve().parent
CPU = setup_runtime("cpu", "fp32", False)
NO_CUDA = "needs a CUDA device (run recipes/benchmarks/gpu_check.py on a GPU machine)"


def _relative(a: torch.Tensor, b: torch.Tensor) -> float:
    return float((a - b).norm() / b.norm().clamp_min(1e-12))


def _trainer(model, data, val, run_dir, steps, runtime=CPU, **train):
    return Trainer(model, data, val, runtime=runtime, run_dir=run_dir, recipe="toy",
                   optim=OptimConfig(lr=1e-3, warmup_steps=1),
                   train=TrainConfig(steps=steps, val_batches=1, **train), progress=False)


# ----- (a) DDP ---------------------------------------------------------------------------------
@pytest.mark.slow
def test_ddp_two_gloo_ranks_at_half_batch_match_one_process_at_full_batch(tmp_path):
    steps, batch = 20, 16
    env = dict(os.environ, OMP_NUM_THREADS="1")
    torchrun = Path(sys.executable).parent / "torchrun"
    proc = subprocess.run(
        [str(torchrun), "--standalone", "--nproc_per_node=2", str(HERE / "ddp_worker.py"),
         str(tmp_path / "ddp"), str(steps), str(batch)],
        capture_output=True, text=True, timeout=600, env=env, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr[-3000:]
    ddp = torch.load(tmp_path / "ddp" / "weights.pt", weights_only=True)
    assert ddp["world_size"] == 2
    model = tiny_model(dtype=torch.float64)
    batches = fixed_batches(model, steps, batch, dtype=torch.float64)
    single = _trainer(model, BatchList(batches), BatchList(batches[:1]), tmp_path / "one", steps,
                      val_every=10 * steps, checkpoint_every=10 * steps)
    single.fit()
    names = [n for n, p in single.model.named_parameters()]
    ours = torch.cat([single.model.state_dict()[n].flatten() for n in names])
    theirs = torch.cat([ddp["model"][n].flatten() for n in names])
    # float64, so what is compared is the engine (sampling, all-reduce, EMA), not the fp32
    # summation order that Adam amplifies over 20 steps (~1e-5 in float32)
    assert _relative(theirs, ours) <= 1e-5, _relative(theirs, ours)
    for name in names:
        assert _relative(ddp["model"][name], single.model.state_dict()[name]) <= 1e-5, name
    # the parameters moved (the comparison is not between two initialisations)
    start = torch.cat([tiny_model(dtype=torch.float64).state_dict()[n].flatten() for n in names])
    assert _relative(ours, start) > 1e-3
    # EMA weights stay identical across the ranks
    ema1 = torch.load(tmp_path / "ddp" / "ema_rank1.pt", weights_only=True)["ema"]
    for name, p in ddp["ema"].items():
        torch.testing.assert_close(ema1[name], p, rtol=0, atol=0)
    # epoch snapshots count epochs at the global batch; rank 0 writes them without a collective
    run = tmp_path / "ddp" / "run"
    assert sorted(p.name for p in (run / "snapshots").iterdir()) == ["epoch_002.pt",
                                                                      "epoch_004.pt"]
    payload = read_checkpoint(run / "snapshots" / "epoch_004.pt")
    assert (payload["extra"]["step"], payload["extra"]["steps_per_epoch"]) == (steps, 5)
    for name, p in ddp["ema"].items():
        torch.testing.assert_close(payload["ema_state_dict"][name], p, rtol=0, atol=0)


# ----- (b) resume ------------------------------------------------------------------------------
class _SignalAt:
    """A replay buffer that sends this process SIGTERM when its ``at``-th batch is drawn."""

    def __init__(self, rb, at: int) -> None:
        self.rb, self.at, self.n = rb, at, 0
        self.sampler = rb.sampler

    def sample(self):
        self.n += 1
        if self.n == self.at:
            os.kill(os.getpid(), signal.SIGTERM)
        return self.rb.sample()


def _fresh(seed_data: int = 0):
    torch.manual_seed(123)
    store = toy_store()
    return tiny_model(), replay_buffer(store, seed=seed_data), replay_buffer(store, seed=99)


def test_sigterm_then_resume_matches_an_uninterrupted_run(tmp_path):
    k = 6
    model, rb, val = _fresh()
    full = _trainer(model, rb, val, tmp_path / "full", 2 * k, val_every=4, checkpoint_every=5)
    full.fit()

    model, rb, val = _fresh()
    first = _trainer(model, _SignalAt(rb, k), val, tmp_path / "cut", 2 * k, val_every=4,
                     checkpoint_every=5)
    result = first.fit()
    assert result.interrupted == "SIGTERM" and result.steps == k
    state = read_checkpoint(tmp_path / "cut" / "last.pt")["training_state"]
    assert state["step"] == k and state["recipe"] == "toy"

    torch.manual_seed(999)  # whatever the new process's streams, resume restores them
    model, rb, val = _fresh(seed_data=5)
    second = Trainer(model, rb, val, runtime=CPU, run_dir=tmp_path / "cut", recipe="toy",
                     optim=OptimConfig(lr=1e-3, warmup_steps=1),
                     train=TrainConfig(steps=2 * k, val_batches=1, val_every=4,
                                       checkpoint_every=5),
                     resume=tmp_path / "cut" / "last.pt", progress=False)
    assert second.step == k
    assert second.fit().steps == 2 * k
    for a, b in ((second.model, full.model), (second.ema.module, full.ema.module)):
        for (name, p), q in zip(a.state_dict().items(), b.state_dict().values(), strict=True):
            torch.testing.assert_close(p, q, rtol=0, atol=1e-6, msg=name)
    opt_a, opt_b = second.optimizer.state_dict()["state"], full.optimizer.state_dict()["state"]
    assert opt_a.keys() == opt_b.keys()
    for i in opt_a:
        for key in ("exp_avg", "exp_avg_sq", "step"):
            torch.testing.assert_close(opt_a[i][key], opt_b[i][key], rtol=0, atol=1e-6)
    # the history and the best checkpoint continue the same run
    assert [h["step"] for h in second.history] == [h["step"] for h in full.history] == [4, 8, 12]
    assert second.best_step == full.best_step and second.best == pytest.approx(full.best)
    # last.pt and best.pt stay ordinary checkpoints (export, FlowPolicy)
    for name in ("last.pt", "best.pt"):
        restored, _ = load_checkpoint(tmp_path / "cut" / name)
        assert restored.cfg.algorithm == "srfmp"


def test_a_run_stopped_by_its_time_cap_resumes_without_training_until_the_cap_is_raised(
        tmp_path, capsys):
    model, rb, val = _fresh()
    run = tmp_path / "capped"
    first = _trainer(model, rb, val, run, 50, max_minutes=1e-9)
    assert first.fit().steps == 1  # the cap ends the run after its first step
    before = read_checkpoint(run / "last.pt")["training_state"]

    def resumed(max_minutes):
        model, rb, val = _fresh()
        return Trainer(model, rb, val, runtime=CPU, run_dir=run, recipe="toy",
                       optim=OptimConfig(lr=1e-3, warmup_steps=1),
                       train=TrainConfig(steps=50, val_batches=1, max_minutes=max_minutes),
                       resume=run / "last.pt", progress=False)

    again = resumed(1e-9)
    assert again.fit().steps == 1  # not one more step past the cap
    assert "train.max_minutes=1e-09 was reached at step 1" in capsys.readouterr().out
    assert read_checkpoint(run / "last.pt")["training_state"]["step"] == before["step"]
    assert resumed(math.inf).fit().steps == 50  # a raised cap continues the run


def test_resume_refuses_a_different_model_or_recipe_and_best_pt(tmp_path):
    model, rb, val = _fresh()
    _trainer(model, rb, val, tmp_path / "run", 2, val_every=1).fit()
    before = {p: p.read_bytes() for p in (tmp_path / "run").rglob("*") if p.is_file()}
    with pytest.raises(ValueError, match="algorithm: run 'srfmp' vs now 'rfmp'"):
        Trainer(tiny_model("rfmp"), rb, val, runtime=CPU, run_dir=tmp_path / "run",
                recipe="toy", resume=tmp_path / "run" / "last.pt")
    with pytest.raises(ValueError, match="a run of recipe 'toy', not 'pusht'"):
        Trainer(tiny_model(), rb, val, runtime=CPU, run_dir=tmp_path / "run", recipe="pusht",
                resume=tmp_path / "run" / "last.pt")
    with pytest.raises(ValueError, match="no training state"):
        Trainer(tiny_model(), rb, val, runtime=CPU, run_dir=tmp_path / "run", recipe="toy",
                resume=tmp_path / "run" / "best.pt")
    after = {p: p.read_bytes() for p in (tmp_path / "run").rglob("*") if p.is_file()}
    assert after == before


# ----- (c) bf16 --------------------------------------------------------------------------------
@pytest.mark.slow
def test_bf16_autocast_trains_on_cpu_and_keeps_sphere_outputs_on_the_sphere(tmp_path):
    runtime = setup_runtime("cpu", "bf16", False)
    model, rb, val = _fresh()
    trainer = _trainer(model, rb, val, tmp_path / "bf16", 200, runtime=runtime)
    torch.manual_seed(0)
    assert trainer.model.amp_dtype == torch.bfloat16
    losses = [float(trainer.update(rb.sample(), 3e-3)) for _ in range(200)]
    first, last = sum(losses[:20]) / 20, sum(losses[-20:]) / 20
    assert last < 0.5 * first, (first, last)
    # as far as fp32 gets on the same batches and noise
    torch.manual_seed(0)
    model32, rb32, val32 = _fresh()
    reference = _trainer(model32, rb32, val32, tmp_path / "fp32", 200)
    losses32 = [float(reference.update(rb32.sample(), 3e-3)) for _ in range(200)]
    # (measured: 3.59 -> 0.82 in bf16, 0.62 in fp32; a 20-step mean of a noisy loss)
    assert abs(last - sum(losses32[-20:]) / 20) < 0.5 * last, (last, losses32[-20:])
    # the networks ran in bf16 (their outputs differ from fp32 by bf16 rounding) ...
    batch = rb.sample()
    with torch.no_grad():
        cond = trainer.model.encode(batch["observation"])
        x, tau = trainer.model.chunk.random_base(len(cond)), torch.rand(len(cond), 1)
        v_bf16 = trainer.model.velocity(x, tau, cond)[0]
        trainer.model.set_precision("fp32")
        v_fp32 = trainer.model.velocity(x, tau, cond)[0]
        trainer.model.set_precision("bf16")
    error = float((v_bf16 - v_fp32).abs().max() / v_fp32.abs().max())
    assert v_bf16.dtype == torch.float32 and 0 < error < 0.1, error
    # ... while normaliser, manifold maps and solver stay fp32: every sample lies on S^2
    for ema_model in (trainer.model, trainer.ema.module):
        assert ema_model.amp_dtype == torch.bfloat16
        with torch.no_grad():
            cond = ema_model.encode(batch["observation"])
            for nfe in (1, 3):
                action = ema_model.sample(cond, nfe=nfe, t_end=1.6)
                assert action.dtype == torch.float32
                assert float((action.norm(dim=-1) - 1).abs().max()) <= 1e-6


# ----- (d) compile -----------------------------------------------------------------------------
@pytest.mark.slow
def test_compiled_and_eager_training_steps_give_the_same_loss(tmp_path):
    model = tiny_model()
    batches = fixed_batches(model, 3, 16)
    eager = _trainer(model, BatchList(batches), BatchList(batches), tmp_path / "e", 3)
    compiled = _trainer(tiny_model(), BatchList(batches), BatchList(batches), tmp_path / "c", 3,
                        runtime=setup_runtime("cpu", "fp32", True))
    assert hasattr(compiled.model.network, "_compiled_call_impl")
    for batch in batches:
        a, b = eager.update(batch.clone(), 1e-3), compiled.update(batch.clone(), 1e-3)
        assert abs(float(a) - float(b)) <= 1e-5 * max(1.0, abs(float(a))), (float(a), float(b))
    # the state dict keys stay plain (checkpoints load into an uncompiled model)
    assert compiled.model.state_dict().keys() == eager.model.state_dict().keys()
    # the compiled evaluation policy samples what the eager one samples
    policy = compile_networks(tiny_model()).eval()
    reference = tiny_model().eval()
    obs, noise = batches[0]["observation"], batches[0]["prior_noise"]
    with torch.no_grad():
        torch.testing.assert_close(policy.sample(policy.encode(obs), noise, nfe=2),
                                   reference.sample(reference.encode(obs), noise, nfe=2),
                                   rtol=1e-5, atol=1e-5)


# ----- dtype and device follow the inputs -----------------------------------------------------
@pytest.mark.parametrize("algorithm", ["rfmp", "srfmp", "ddim"])
def test_losses_and_sampling_follow_the_inputs_dtype(algorithm):
    from tensordict import TensorDict

    from rfmp_rl.modules import FlowPolicy
    from rfmp_rl.objectives import make_loss

    model = tiny_model(algorithm, dtype=torch.float64)
    action = model.chunk.unflatten(model.chunk.random_base(5, dtype=torch.float64))
    obs = torch.randn(5, 2, 3, dtype=torch.float64)
    out = make_loss(model)(TensorDict({"observation": obs, "action": action}, [5]))
    assert {v.dtype for v in out.values()} == {torch.float64}
    sampled = FlowPolicy(model, nfe=2)(TensorDict({"observation": obs}, [5]))["action"]
    assert sampled.dtype == torch.float64
    assert float((sampled.norm(dim=-1) - 1).abs().max()) <= 1e-12


# ----- loggers ---------------------------------------------------------------------------------
@pytest.mark.parametrize("backend", ["tensorboard", "wandb"])
def test_loggers_from_torchrl(tmp_path, backend, monkeypatch):
    pytest.importorskip("tensorboard" if backend == "tensorboard" else "wandb")
    monkeypatch.setenv("WANDB_SILENT", "true")
    model, rb, val = _fresh()
    trainer = Trainer(model, rb, val, runtime=CPU, run_dir=tmp_path, recipe="toy",
                      train=TrainConfig(steps=2, val_every=1, log_every=1, val_batches=1),
                      logger=LoggerConfig(backend=backend, wandb_mode="offline"), progress=False)
    trainer.fit()
    if backend == "tensorboard":
        assert list(tmp_path.glob("logs/**/events.out.tfevents.*"))
    else:
        assert list(tmp_path.rglob("offline-run-*")), sorted(map(str, tmp_path.rglob("*")))


def test_no_logger_trains_and_writes_no_logs(tmp_path):
    model, rb, val = _fresh()
    trainer = Trainer(model, rb, val, runtime=CPU, run_dir=tmp_path, recipe="toy",
                      train=TrainConfig(steps=3, val_every=2, log_every=1, val_batches=1),
                      logger=LoggerConfig(backend="none"), progress=False)
    assert trainer.fit().steps == 3 and not (tmp_path / "logs").exists()


def test_unknown_logger_is_refused(tmp_path):
    model, rb, val = _fresh()
    trainer = Trainer(model, rb, val, runtime=CPU, run_dir=tmp_path, recipe="toy",
                      train=TrainConfig(steps=1), logger=LoggerConfig(backend="mlflow"))
    with pytest.raises(ValueError, match="logger.backend='mlflow'"):
        trainer.fit()


# ----- settings the engine refuses -------------------------------------------------------------
def test_bad_runtime_settings_name_the_setting():
    with pytest.raises(ValueError, match="device='tpu'"):
        setup_runtime("tpu")
    with pytest.raises(ValueError, match="precision='fp8'"):
        setup_runtime("cpu", "fp8")
    with pytest.raises(ValueError, match="precision=fp16 needs a CUDA device"):
        setup_runtime("cpu", "fp16")
    if not torch.cuda.is_available():
        for device in ("cuda", "cuda:1"):
            with pytest.raises(ValueError, match=f"device={device}: CUDA was requested"):
                resolve_device(device)
    assert resolve_device("auto").type == ("cuda" if torch.cuda.is_available() else "cpu")
    with pytest.raises(ValueError, match="train.checkpoint_every must be >= 1"):
        TrainConfig(checkpoint_every=0)
    with pytest.raises(ValueError, match="train.select_by"):
        TrainConfig(select_by="loss")
    assert TrainConfig(max_minutes=None).max_minutes == math.inf


# ----- CUDA ------------------------------------------------------------------------------------
@pytest.mark.skipif(not torch.cuda.is_available(), reason=NO_CUDA)
@pytest.mark.parametrize("precision", ["fp32", "bf16", "fp16"])
def test_cuda_training_in_every_precision(tmp_path, precision):
    runtime = setup_runtime("cuda", precision, False)
    model, rb, val = _fresh()
    trainer = _trainer(model, rb, val, tmp_path, 20, runtime=runtime, val_every=10)
    trainer.fit()
    assert next(trainer.model.parameters()).device.type == "cuda"
    assert trainer.scaler.is_enabled() == (precision == "fp16")
    with torch.no_grad():
        obs = rb.sample()["observation"].cuda()
        action = trainer.ema.module.sample(trainer.ema.module.encode(obs), nfe=3)
    assert action.device.type == "cuda" and action.dtype == torch.float32
    assert float((action.norm(dim=-1) - 1).abs().max()) <= 1e-6
    restored, _ = load_checkpoint(tmp_path / "best.pt")
    assert next(restored.parameters()).device.type == "cpu"


def test_checkpoints_carry_the_loss_settings_and_the_rate_and_resume_keeps_them(tmp_path):
    from rfmp_rl.objectives import LossConfig

    loss = LossConfig(time_max=2.0, t0_fraction=0.25)
    model, rb, val = _fresh()
    trainer = Trainer(model, rb, val, runtime=CPU, run_dir=tmp_path / "run", recipe="toy",
                      train=TrainConfig(steps=2, val_every=1, val_batches=1), progress=False,
                      logger=LoggerConfig("none"), loss=loss, control_rate_hz=20.0)
    assert trainer.loss_fn.loss_cfg == loss == trainer.val_loss_fn.loss_cfg
    trainer.fit()
    for name in ("best.pt", "last.pt"):
        payload = read_checkpoint(tmp_path / "run" / name)
        assert payload["loss"] == loss.to_dict() and payload["control_rate_hz"] == 20.0
    with pytest.raises(ValueError, match=r"other loss settings \(time_max: run 2.0 vs now 1.0"):
        Trainer(tiny_model(), rb, val, runtime=CPU, run_dir=tmp_path / "run", recipe="toy",
                train=TrainConfig(steps=4, val_batches=1), resume=tmp_path / "run" / "last.pt",
                loss=LossConfig(t0_fraction=0.25))
    resumed = Trainer(tiny_model(), rb, val, runtime=CPU, run_dir=tmp_path / "run",
                      recipe="toy", train=TrainConfig(steps=4, val_batches=1),
                      resume=tmp_path / "run" / "last.pt", loss=loss)
    assert resumed.step == 2
