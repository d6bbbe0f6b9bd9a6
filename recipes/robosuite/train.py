"""Train RFMP / SRFMP / Diffusion Policy (DDIM) on robosuite Lift, PickPlaceCan or
NutAssemblySquare from scripted-expert demonstrations (robomimic HDF5), then evaluate the best
checkpoint over 50 seeds at NFE {1, 2, 3, 5, 10}.

    python recipes/robosuite/train.py task=Lift algo=srfmp train.max_minutes=60
    python recipes/robosuite/train.py task=PickPlaceCan action_space=abs_pose   # R3 x S3 x R1
    python recipes/robosuite/train.py task=Lift action_space=abs_pose geometry=euclidean

The demonstrations default to ``data/robosuite/<task>_<action_space>.hdf5``, written by the
scripted expert on first use (``python -m rfmp_rl.envs.robosuite_experts`` does it alone).
Writes ``runs/robosuite/<task>_<algo>_<obs>_<action_space>_<time>/``: ``best.pt``, ``last.pt``,
``logs/``, ``history.json`` and ``eval/`` (eval.csv, eval.md).
"""

from __future__ import annotations

from datetime import datetime
from pathlib import Path

import hydra
import torch
from omegaconf import DictConfig, OmegaConf
from utils import (  # noqa: I001
    ROOT,
    check_config,
    fit,
    make_model,
    make_replay_buffer,
    make_stores,
    sweep,
    write_tables,
)

from rfmp_rl.checkpoint import load_checkpoint


def show(row: dict) -> None:
    print(f"  NFE={row['nfe']:<2} T={row['t_end']:.1f}: success {row['success']:.2f}, "
          f"jerk {row['jerk']:.3g} ({row['seconds']:.0f} s)")


def train(cfg: DictConfig) -> Path:
    """Train, keep the best checkpoint, optionally evaluate it; returns the run folder."""
    check_config(cfg)
    torch.manual_seed(cfg.seed)
    torch.set_num_threads(int(cfg.threads))
    stamp = datetime.now().strftime("%Y%m%d_%H%M%S")
    name = f"{cfg.task}_{cfg.algo}_{cfg.obs}_{cfg.action_space}_{stamp}"
    run_dir = Path(cfg.out_dir or ROOT / "runs" / "robosuite" / name)
    run_dir.mkdir(parents=True, exist_ok=True)
    (run_dir / "config.yaml").write_text(OmegaConf.to_yaml(cfg))

    train_store, val_store = make_stores(cfg)
    print(train_store.manifest)
    rb = make_replay_buffer(train_store, cfg, seed=cfg.seed)
    val_rb = make_replay_buffer(val_store, cfg, seed=cfg.seed + 1)
    model = make_model(cfg, train_store)
    n_params = sum(p.numel() for p in model.parameters())
    print(f"{cfg.algo} on {cfg.task} ({cfg.obs}, {cfg.action_space}): {n_params / 1e6:.2f}M "
          f"parameters, {len(train_store)} steps in {train_store.num_episodes} episodes")
    result = fit(model, rb, val_rb, cfg, run_dir)

    if cfg.eval.final_eval:
        best_model, meta = load_checkpoint(run_dir / "best.pt", use_ema=True)
        rows = sweep(best_model, cfg, progress=show)
        title = (f"{cfg.task} {cfg.obs} {cfg.action_space}: {cfg.algo} ({cfg.preset}, best of "
                 f"{result.steps} steps at step {meta['extra'].get('step')}, "
                 f"{result.minutes:.0f} min)")
        command = f"python recipes/robosuite/eval.py checkpoint={run_dir / 'best.pt'}"
        print(write_tables(rows, run_dir / "eval", title, command).read_text())
    print(f"run folder: {run_dir}")
    return run_dir


@hydra.main(config_path=".", config_name="config", version_base="1.3")
def main(cfg: DictConfig) -> None:
    train(cfg)


if __name__ == "__main__":
    main()
