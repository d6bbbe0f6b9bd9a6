"""Launched by tests/training/test_engine.py with ``torchrun --nproc_per_node=2``: each rank
trains the toy policy (float64, so the comparison sees the engine, not fp32 summation order)
on its half of the fixed batches, with epoch snapshots; rank 0 saves the final weights."""

from __future__ import annotations

import sys
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))

from toy import BatchList, fixed_batches, tiny_model  # noqa: E402

from rfmp_rl.training import OptimConfig, TrainConfig, Trainer, setup_runtime  # noqa: E402


def main(out: str, steps: int, batch: int) -> None:
    torch.set_num_threads(1)
    runtime = setup_runtime("cpu", "fp32", False)
    model = tiny_model(dtype=torch.float64)
    batches = fixed_batches(model, steps, batch, dtype=torch.float64)
    data = BatchList(batches, runtime.rank, runtime.world_size)
    val = BatchList(batches[:1])
    # an epoch of 5 * batch windows at the global batch (batch / 2 per rank): 5 steps
    trainer = Trainer(model, data, val, runtime=runtime, run_dir=Path(out) / "run", recipe="toy",
                      optim=OptimConfig(lr=1e-3, warmup_steps=1),
                      train=TrainConfig(steps=steps, val_every=10 * steps, val_batches=1,
                                        checkpoint_every=10 * steps,
                                        batch_size=batch // runtime.world_size,
                                        snapshot_every_epochs=2),
                      epoch_windows=5 * batch, progress=False)
    trainer.fit()
    if runtime.is_main:
        torch.save({"model": trainer.model.state_dict(),
                    "ema": trainer.ema.module.state_dict(),
                    "world_size": runtime.world_size}, Path(out) / "weights.pt")
    else:  # the EMA must stay identical on every rank: rank 1 saves its own for the check
        torch.save({"ema": trainer.ema.module.state_dict()}, Path(out) / "ema_rank1.pt")
    runtime.shutdown()


if __name__ == "__main__":
    main(sys.argv[1], int(sys.argv[2]), int(sys.argv[3]))
