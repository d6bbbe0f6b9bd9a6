"""The engine's epoch budget (``train.epochs``) and epoch snapshots
(``train.snapshot_every_epochs``): the steps an epoch takes, the files written and when, their
contents, and a resumed run that keeps the snapshots it has."""

from __future__ import annotations

import dataclasses
import os
import signal

import pytest
import torch
from toy import BatchList, fixed_batches, replay_buffer, tiny_model, toy_store

from rfmp_rl.checkpoint import load_checkpoint, read_checkpoint
from rfmp_rl.training import (
    LoggerConfig,
    OptimConfig,
    TrainConfig,
    Trainer,
    setup_runtime,
    snapshot_path,
    steps_per_epoch,
)

CPU = setup_runtime("cpu", "fp32", False)
BATCH = 16
WINDOWS = 30 + 22 + 26  # toy_store's steps: one training window each
EPOCH = 5  # ceil(78 / 16)


def _data(seed: int = 0):
    torch.manual_seed(123)
    store = toy_store()
    return tiny_model(), replay_buffer(store, seed, BATCH), replay_buffer(store, 99, BATCH)


def _trainer(model, rb, val, run_dir, runtime=CPU, resume=None, **train):
    settings = {"steps": 1000, "batch_size": BATCH, "val_every": 4, "val_batches": 1,
                "checkpoint_every": 100, **train}
    return Trainer(model, rb, val, runtime=runtime, run_dir=run_dir, recipe="toy",
                   optim=OptimConfig(lr=1e-3, warmup_steps=1), train=TrainConfig(**settings),
                   logger=LoggerConfig("none"), resume=resume, progress=False)


class _SignalAt:
    """Sends this process SIGTERM when the ``at``-th batch is drawn (the run saves last.pt
    after that step and stops)."""

    def __init__(self, rb, at: int) -> None:
        self.rb, self.at, self.n = rb, at, 0
        self.sampler, self.batch_size = rb.sampler, rb.batch_size

    def __len__(self) -> int:
        return len(self.rb)

    def sample(self):
        self.n += 1
        if self.n == self.at:
            os.kill(os.getpid(), signal.SIGTERM)
        return self.rb.sample()


def _snapshots(run_dir) -> list[str]:
    return sorted(p.name for p in (run_dir / "snapshots").glob("*.pt"))


def test_steps_per_epoch_is_one_pass_at_the_global_batch():
    assert steps_per_epoch(WINDOWS, BATCH) == EPOCH
    assert steps_per_epoch(64, 16) == 4 and steps_per_epoch(65, 16) == 5
    assert steps_per_epoch(WINDOWS, 8, world_size=2) == EPOCH  # global batch 16
    with pytest.raises(ValueError, match="at least one training window"):
        steps_per_epoch(0, 16)


@pytest.mark.parametrize("name", ["epochs", "snapshot_every_epochs"])
@pytest.mark.parametrize("value", [0, -1, 2.5, True])
def test_bad_epoch_settings_name_the_setting(name, value):
    with pytest.raises(ValueError, match=f"train.{name} must be null or an integer >= 1"):
        TrainConfig(**{name: value})


def test_the_epoch_budget_wins_over_steps_and_snapshots_end_their_epochs(tmp_path, capsys):
    model, rb, val = _data()
    trainer = _trainer(model, rb, val, tmp_path, epochs=3, snapshot_every_epochs=1)
    assert (trainer.steps_per_epoch, trainer.total_steps) == (EPOCH, 3 * EPOCH)
    result = trainer.fit()
    assert result.steps == 3 * EPOCH  # not train.steps=1000
    assert "78 training windows at global batch 16 = 5 steps; 3 epochs = 15 steps" in \
        capsys.readouterr().out
    assert _snapshots(tmp_path) == ["epoch_001.pt", "epoch_002.pt", "epoch_003.pt"]
    for epoch in (1, 2, 3):
        payload = read_checkpoint(snapshot_path(tmp_path, epoch))
        assert payload["extra"]["epoch"] == epoch and payload["extra"]["step"] == epoch * EPOCH
        assert payload["extra"]["steps_per_epoch"] == EPOCH
        assert "training_state" not in payload  # a policy checkpoint, as best.pt
    # the last snapshot holds the final weights; eval loads its EMA weights as it loads best.pt
    policy, _ = load_checkpoint(snapshot_path(tmp_path, 3))
    for name, p in trainer.ema.module.state_dict().items():
        torch.testing.assert_close(policy.state_dict()[name], p, rtol=0, atol=0, msg=name)
    earlier, _ = load_checkpoint(snapshot_path(tmp_path, 1))
    assert any(not torch.equal(earlier.state_dict()[n], p)
               for n, p in trainer.ema.module.state_dict().items())
    # the snapshots are written beside the run's usual files, not instead of them
    assert {"best.pt", "last.pt", "history.json"} <= {p.name for p in tmp_path.iterdir()}


def test_snapshots_every_k_epochs_within_a_step_budget(tmp_path):
    model, rb, val = _data()
    trainer = _trainer(model, rb, val, tmp_path, steps=4 * EPOCH + 3, snapshot_every_epochs=2)
    assert trainer.fit().steps == 4 * EPOCH + 3
    assert _snapshots(tmp_path) == ["epoch_002.pt", "epoch_004.pt"]
    assert read_checkpoint(snapshot_path(tmp_path, 4))["extra"]["step"] == 4 * EPOCH


def test_no_epoch_settings_write_no_snapshots_and_keep_the_step_budget(tmp_path):
    model, rb, val = _data()
    trainer = _trainer(model, rb, val, tmp_path, steps=3)
    assert trainer.steps_per_epoch is None and trainer.fit().steps == 3
    assert not (tmp_path / "snapshots").exists()


def test_a_resumed_run_keeps_its_snapshots_and_continues_them(tmp_path):
    full_dir, cut_dir = tmp_path / "full", tmp_path / "cut"
    model, rb, val = _data()
    _trainer(model, rb, val, full_dir, epochs=3, snapshot_every_epochs=1).fit()

    model, rb, val = _data()
    first = _trainer(model, _SignalAt(rb, 2 * EPOCH - 2), val, cut_dir, epochs=3,
                     snapshot_every_epochs=1)
    assert first.fit().interrupted == "SIGTERM"  # in its second epoch
    assert _snapshots(cut_dir) == ["epoch_001.pt"]
    kept = snapshot_path(cut_dir, 1)
    before = (kept.read_bytes(), kept.stat().st_mtime_ns)
    # a snapshot the run wrote before a hard kill left last.pt behind it: never rewritten
    stale = snapshot_path(cut_dir, 2)
    stale.write_bytes(kept.read_bytes())

    model, rb, val = _data(seed=5)
    second = _trainer(model, rb, val, cut_dir, epochs=3, snapshot_every_epochs=1,
                      resume=cut_dir / "last.pt")
    assert second.step == 2 * EPOCH - 2
    assert second.fit().steps == 3 * EPOCH
    assert _snapshots(cut_dir) == ["epoch_001.pt", "epoch_002.pt", "epoch_003.pt"]
    assert (kept.read_bytes(), kept.stat().st_mtime_ns) == before
    assert stale.read_bytes() == before[0]
    # the snapshot written after the resume is the uninterrupted run's
    resumed, _ = load_checkpoint(snapshot_path(cut_dir, 3))
    full, _ = load_checkpoint(snapshot_path(full_dir, 3))
    for name, p in full.state_dict().items():
        torch.testing.assert_close(resumed.state_dict()[name], p, rtol=0, atol=1e-6, msg=name)


def test_a_fresh_run_refuses_a_folder_with_snapshots(tmp_path):
    model, rb, val = _data()
    _trainer(model, rb, val, tmp_path, epochs=1, snapshot_every_epochs=1).fit()
    before = snapshot_path(tmp_path, 1).read_bytes()
    model, rb, val = _data()
    with pytest.raises(ValueError, match="already holds snapshots"):
        _trainer(model, rb, val, tmp_path, epochs=1, snapshot_every_epochs=1)
    assert snapshot_path(tmp_path, 1).read_bytes() == before


def test_only_rank_0_writes_snapshots(tmp_path):
    model, rb, val = _data()
    other = dataclasses.replace(CPU, rank=1)
    trainer = _trainer(model, rb, val, tmp_path, runtime=other, epochs=1,
                       snapshot_every_epochs=1)
    trainer.step = EPOCH
    assert trainer.save_snapshot() is None and not (tmp_path / "snapshots").exists()
    main = _trainer(model, rb, val, tmp_path, epochs=1, snapshot_every_epochs=1)
    main.step = EPOCH
    assert main.save_snapshot() == snapshot_path(tmp_path, 1)


def test_epochs_need_the_data_size_and_its_batch(tmp_path):
    model, rb, val = _data()
    with pytest.raises(ValueError, match="train.batch_size=32 but the training data samples "
                                         "batches of 16"):
        _trainer(model, rb, val, tmp_path, epochs=2, batch_size=32)
    batches = BatchList(fixed_batches(model, 2, BATCH))
    with pytest.raises(ValueError, match="has no len"):
        _trainer(model, batches, batches, tmp_path, epochs=2)
    trainer = Trainer(model, batches, batches, runtime=CPU, run_dir=tmp_path, recipe="toy",
                      train=TrainConfig(batch_size=BATCH, epochs=2), epoch_windows=40)
    assert (trainer.steps_per_epoch, trainer.total_steps) == (3, 6)
