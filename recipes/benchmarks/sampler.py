"""Cost of drawing training samples from the demonstration store vs one training step.

    .venv/bin/python recipes/benchmarks/sampler.py [--zarr PATH] [--out results/sampler.md]

On the real Push-T zarr (Diffusion Policy's 206 human episodes): builds the Push-T state store
(tensor storage) and the image store (memory-mapped ``uint8`` images), then times, in one
process on the same threads,

- ``rb.sample()`` of the paper's samples (context, reference, T_p = 16 chunk, padding mask),
- one SRFMP training step (loss, backward, AdamW) of the small preset on such a batch,

at the recipe's batch sizes (state 256, image 64). The target: sampling <= 10% of a step.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import sys
import time
from pathlib import Path

import torch

from rfmp_rl import keys
from rfmp_rl.data import DemonstrationStore, read_dp_zarr
from rfmp_rl.envs.pusht import pusht_episodes
from rfmp_rl.modules import ModelConfig, build_model
from rfmp_rl.objectives import make_loss

ROOT = Path(__file__).resolve().parents[2]


def median_seconds(fn, repeats: int) -> float:
    fn()  # warm-up
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def bench(name, store, model_cfg, batch, camera, sample_repeats, step_repeats) -> dict:
    rb = store.replay_buffer(16, [keys.OBSERVATION], camera_keys=[keys.PIXELS] if camera else [],
                             batch_size=batch, generator=torch.Generator().manual_seed(0))
    model = build_model(model_cfg)
    model.action_normalizer.set_stats(*store.stats(keys.ACTION))
    model.obs_normalizer.set_stats(*store.stats(keys.OBSERVATION))
    loss_fn = make_loss(model)
    optim = torch.optim.AdamW(model.parameters(), lr=1e-4, weight_decay=1e-3)
    fixed = rb.sample()

    def step():
        out = loss_fn(fixed)
        loss = sum(v for k, v in out.items() if k.startswith("loss_"))
        optim.zero_grad()
        loss.backward()
        optim.step()

    sample_s = median_seconds(rb.sample, sample_repeats)
    step_s = median_seconds(step, step_repeats)
    return {"name": name, "batch": batch, "sample_ms": sample_s * 1e3, "step_ms": step_s * 1e3,
            "ratio": sample_s / step_s}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--zarr", default=str(ROOT.parent / "shared/data/pusht/"
                                              "pusht_cchi_v7_replay.zarr"))
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    raw, _ = read_dp_zarr(args.zarr, ["state", "keypoint", "action", "img"])
    rows = []
    state = DemonstrationStore.from_episodes(pusht_episodes(raw, "state"))
    cfg = ModelConfig("srfmp", "R2", obs_dim=20, unet_preset="small")
    rows.append(bench("Push-T state (tensor storage)", state, cfg, 256, False, 200, 10))
    image = DemonstrationStore.from_episodes(pusht_episodes(raw, "image"), memmap=True)
    cfg = ModelConfig("srfmp", "R2", obs_dim=2, cameras={keys.PIXELS: [3, 96, 96]},
                      crop_shape=[84, 84], unet_preset="small")
    rows.append(bench("Push-T image (memory-mapped uint8)", image, cfg, 64, True, 50, 5))
    cpu = platform.processor() or platform.machine()
    lines = [
        "# Demonstration sampler vs training step",
        "",
        f"Command: `.venv/bin/python recipes/benchmarks/sampler.py {' '.join(sys.argv[1:])}` "
        f"({cpu}, {args.threads} threads, torch {torch.__version__}); medians of "
        "200 (state) / 50 (image) draws and 10 / 5 training steps.",
        "",
        f"Measured on a {os.cpu_count()}-core CPU machine (both timings in the same process, so "
        "the ratio is like for like even when other jobs share the cores).",
        "",
        "| store | batch | rb.sample() ms | SRFMP small train step ms | sample / step |",
        "|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(f"| {r['name']} | {r['batch']} | {r['sample_ms']:.2f} | {r['step_ms']:.0f} "
                     f"| {100 * r['ratio']:.1f}% |")
    text = "\n".join(lines) + "\n"
    print(text)
    if args.out:
        args.out.write_text(text)


if __name__ == "__main__":
    main()
