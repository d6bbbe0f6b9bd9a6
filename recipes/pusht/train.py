"""Train RFMP / SRFMP / Diffusion Policy (DDIM) on Push-T or Sphere Push-T from Diffusion
Policy's human demonstrations, then evaluate the best checkpoint.

    python recipes/pusht/train.py algo=srfmp obs=state space=euclidean train.max_minutes=60
    python recipes/pusht/train.py algo=rfmp space=sphere prior=wrapped

Writes to ``runs/pusht/<algo>_<obs>_<space>_<time>/``: ``best.pt`` (the EMA weights of the best
validation loss, or of the best rollout score on the selection seeds with
``train.select_by=rollout``), ``last.pt``, ``logs/`` (TorchRL CSV logger: train loss, lr,
validation loss and rollout score), and, with ``eval.final_eval=true``, ``eval/`` (eval.csv,
eval.md, eval.png) from `eval.py`'s sweep.
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
    selection_score,
    sweep,
    write_tables,
)

from rfmp_rl.checkpoint import load_checkpoint


def train(cfg: DictConfig) -> Path:
    """Train, keep the best checkpoint, optionally evaluate it; returns the run folder."""
    check_config(cfg)
    torch.manual_seed(cfg.seed)
    torch.set_num_threads(int(cfg.threads))
    stamp = datetime.now().strftime("%Y%m%d_%H%M%S")
    name = f"{cfg.algo}_{cfg.obs}_{cfg.space}_{stamp}"
    run_dir = Path(cfg.out_dir or ROOT / "runs" / "pusht" / name)
    run_dir.mkdir(parents=True, exist_ok=True)
    (run_dir / "config.yaml").write_text(OmegaConf.to_yaml(cfg))

    train_store, val_store = make_stores(cfg)
    print(train_store.manifest)
    rb = make_replay_buffer(train_store, cfg, seed=cfg.seed)
    val_rb = make_replay_buffer(val_store, cfg, seed=cfg.seed + 1)
    model = make_model(cfg, train_store)
    n_params = sum(p.numel() for p in model.parameters())
    print(f"{cfg.algo} on Push-T ({cfg.obs}, {cfg.space}): {n_params / 1e6:.2f}M parameters, "
          f"{len(train_store)} training steps in {train_store.num_episodes} episodes")
    result = fit(model, rb, val_rb, cfg, run_dir, rollout_score=selection_score(cfg))
    step, minutes = result.steps, result.minutes

    if cfg.eval.final_eval:
        best_model, meta = load_checkpoint(run_dir / "best.pt", use_ema=True)
        best_model.eval()

        def show(row):
            print(f"  NFE={row['nfe']:<2} T={row['t_end']:.1f}: score {row['score']:.3f}, "
                  f"success {row['success']:.2f}, jerk {row['jerk']:.3g} ({row['seconds']:.0f} s)")

        rows = sweep(best_model, cfg, progress=show)
        title = (f"Push-T {cfg.obs} {cfg.space}: {cfg.algo} ({cfg.preset}, best of {step} steps "
                 f"at step {meta['extra'].get('step')}, {minutes:.0f} min)")
        command = f"python recipes/pusht/eval.py checkpoint={run_dir / 'best.pt'}"
        print(write_tables(rows, run_dir / "eval", title, command, cfg.eval.time_table).read_text())
    print(f"run folder: {run_dir}")
    return run_dir


@hydra.main(config_path=".", config_name="config", version_base="1.3")
def main(cfg: DictConfig) -> None:
    train(cfg)


if __name__ == "__main__":
    main()
