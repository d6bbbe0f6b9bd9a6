"""Pieces every training recipe shares (imported by recipes/<task>/utils.py and train.py):
the optimiser with its budget-aware learning-rate rule, the TorchRL logger, the fixed-noise
validation loss, the training loop with EMA and best-checkpoint keeping, and the acting policy
(FlowPolicy inside MultiStepActorWrapper) with the solver settings of each algorithm."""

from __future__ import annotations

import json
import math
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import torch
from omegaconf import DictConfig, OmegaConf
from tensordict import TensorDict
from torchrl.modules import MultiStepActorWrapper
from tqdm import tqdm

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from rfmp_rl.checkpoint import save_checkpoint  # noqa: E402
from rfmp_rl.modules import EMA, FlowPolicy  # noqa: E402
from rfmp_rl.objectives import make_loss  # noqa: E402
from rfmp_rl.solvers import step_sizes  # noqa: E402

#: Recipe algorithm name -> ModelConfig algorithm.
ALGOS = {"rfmp": "rfmp", "srfmp": "srfmp", "dp": "ddim"}


def resolve(path: str | Path) -> Path:
    """Relative data paths are taken from the repository root (not the working directory)."""
    path = Path(path)
    return path if path.is_absolute() else (ROOT / path).resolve()


def split_stores(episodes: list, source, data_cfg: DictConfig, fmt: str):
    """Train and validation `DemonstrationStore`s: the last ``data.val_episodes`` episodes are
    held out (for the validation loss); ``data.max_episodes`` trims the training ones. Each
    store's manifest names its episodes as the source does."""
    from rfmp_rl.data import DemonstrationStore, Manifest

    n_val = int(data_cfg.val_episodes)
    if not 0 < n_val < len(episodes):
        raise ValueError(f"data.val_episodes must be in [1, {len(episodes) - 1}], got {n_val}")
    train, val = episodes[:-n_val], episodes[-n_val:]
    if data_cfg.max_episodes:
        train = train[: int(data_cfg.max_episodes)]
    stores = []
    for split, eps, offset in (("train", train, 0), ("val", val, len(episodes) - n_val)):
        manifest = Manifest(source=source.source, format=f"{fmt}/{split}", rate_hz=source.rate_hz)
        for i, ep in enumerate(eps):
            manifest.add(ep, name=source.episode_names[offset + i])
        stores.append(DemonstrationStore.from_episodes(eps, manifest))
    return stores[0], stores[1]


def load_for_eval(cfg: DictConfig, check_config) -> tuple:
    """``(model with EMA weights, task config, checkpoint extras, output folder)`` for eval.py:
    the task comes from the checkpoint's stored training config, ``eval.*``, ``seed`` and
    ``threads`` from this command line."""
    from rfmp_rl.checkpoint import load_checkpoint

    if not cfg.checkpoint:
        raise SystemExit("eval.py: give the checkpoint: checkpoint=runs/<recipe>/<run>/best.pt")
    checkpoint = Path(cfg.checkpoint)
    if not checkpoint.exists():
        raise SystemExit(f"eval.py: no such checkpoint: {checkpoint}")
    torch.set_num_threads(int(cfg.threads))
    model, payload = load_checkpoint(checkpoint, use_ema=True)
    task = OmegaConf.merge(OmegaConf.create(payload["config"]),
                           {"eval": cfg.eval, "seed": cfg.seed, "threads": cfg.threads})
    check_config(task)
    out = Path(cfg.eval.out) if cfg.eval.out else checkpoint.parent / "eval"
    return model, task, payload.get("extra", {}), out


def make_optimizer(model, cfg: DictConfig):
    """AdamW and its learning-rate rule: linear warm-up, then a cosine decay to 0 over the run's
    *progress* = max(step / train.steps, minutes / train.max_minutes), so the decay completes
    whichever budget ends first (a wall-clock-capped CPU run still ends at lr 0)."""
    # fused: one kernel for all parameters (about 3x faster than the per-tensor loop on CPU here)
    optim = torch.optim.AdamW(model.parameters(), lr=cfg.optim.lr,
                              weight_decay=cfg.optim.weight_decay, fused=True)
    warmup = max(1, int(cfg.optim.warmup_steps))

    def lr_at(step: int, progress: float) -> float:
        progress = min(max(progress, 0.0), 1.0)
        return cfg.optim.lr * min(1.0, step / warmup) * 0.5 * (1 + math.cos(math.pi * progress))

    return optim, lr_at


def make_logger(run_dir: Path, cfg: DictConfig):
    """TorchRL's CSV logger in ``<run>/logs`` with the config as hyper-parameters."""
    from torchrl.record.loggers import get_logger

    logger = get_logger("csv", logger_name=str(run_dir), experiment_name="logs")
    logger.log_hparams(OmegaConf.to_container(cfg, resolve=True))
    return logger


def validation_loss(model, loss_fn, rb, batches: int, seed: int) -> float:
    """Mean loss over ``batches`` fixed batches with fixed noise (comparable across calls)."""
    rb.sampler.generator.manual_seed(seed)
    total = 0.0
    with torch.random.fork_rng(), torch.no_grad():
        torch.manual_seed(seed)
        for _ in range(batches):
            out = loss_fn(rb.sample())
            total += float(sum(v for k, v in out.items() if k.startswith("loss_")))
    return total / batches


@dataclass
class FitResult:
    steps: int
    minutes: float
    best_val: float  # the lowest validation loss, or the highest rollout score with rollout_score
    best_step: int


def fit(model, rb, val_rb, cfg: DictConfig, run_dir: Path, camera_keys=None,
        rollout_score=None) -> FitResult:
    """Train ``model`` on ``rb`` (AdamW, EMA, budget-aware lr), validate the EMA weights every
    ``train.val_every`` steps on ``val_rb`` and keep ``best.pt`` (lowest validation loss) and
    ``last.pt``; ``history.json`` and the CSV logs record the curves.

    ``rollout_score(ema_model) -> float`` (higher is better; e.g. the mean task score over
    validation seeds) is also computed at every validation and then chooses ``best.pt`` instead
    of the loss, as Diffusion Policy keeps its checkpoints by rollout score. It runs with the
    global RNG state saved and restored, so training draws the same numbers either way."""
    ema = EMA(model, decay=cfg.optim.ema_decay)
    loss_fn = make_loss(model, camera_keys)
    val_loss_fn = make_loss(ema.module, camera_keys)
    optim, lr_at = make_optimizer(model, cfg)
    logger = make_logger(run_dir, cfg)

    def update(batch: TensorDict, lr: float) -> float:
        for group in optim.param_groups:
            group["lr"] = lr
        out = loss_fn(batch)
        loss = sum(v for k, v in out.items() if k.startswith("loss_"))
        optim.zero_grad()
        loss.backward()
        optim.step()
        ema.update(model)
        return float(loss.detach())

    config = OmegaConf.to_container(cfg, resolve=True)
    # best.pt: the lowest validation loss, or the highest rollout score
    sign, label = (-1.0, "score") if rollout_score is not None else (1.0, "val")
    best, best_step, start, running = sign * float("inf"), 0, time.perf_counter(), None
    history = []
    bar = tqdm(range(1, int(cfg.train.steps) + 1), desc=f"train {cfg.algo}", unit="step",
               dynamic_ncols=True)
    step, minutes = 0, 0.0
    for step in bar:
        minutes = (time.perf_counter() - start) / 60
        lr = lr_at(step, max(step / cfg.train.steps, minutes / cfg.train.max_minutes))
        value = update(rb.sample(), lr)
        running = value if running is None else 0.98 * running + 0.02 * value
        if step % cfg.train.log_every == 0:
            logger.log_scalar("train/loss", running, step=step)
            logger.log_scalar("train/lr", lr, step=step)
            bar.set_postfix({"loss": f"{running:.4f}", f"best_{label}": f"{best:.4f}"})
        stop = minutes >= cfg.train.max_minutes
        if step % cfg.train.val_every == 0 or step == cfg.train.steps or stop:
            val = validation_loss(ema.module, val_loss_fn, val_rb, cfg.train.val_batches, cfg.seed)
            logger.log_scalar("val/loss", val, step=step)
            entry = {"step": step, "minutes": minutes, "train": running, "val": val}
            criterion, scores = val, {}
            if rollout_score is not None:
                with torch.random.fork_rng():
                    criterion = float(rollout_score(ema.module))
                logger.log_scalar("val/rollout_score", criterion, step=step)
                entry["rollout"] = scores["rollout_score"] = criterion
            history.append(entry)
            if sign * criterion < sign * best:
                best, best_step = criterion, step
                save_checkpoint(run_dir / "best.pt", model, ema, config, step=step, val_loss=val,
                                train_minutes=minutes, **scores)
        if stop:
            print(f"stopping at step {step}: train.max_minutes={cfg.train.max_minutes} reached")
            break
    minutes = (time.perf_counter() - start) / 60
    save_checkpoint(run_dir / "last.pt", model, ema, config, step=step, train_minutes=minutes)
    (run_dir / "history.json").write_text(json.dumps(history, indent=1))
    what = "rollout score" if rollout_score is not None else "validation loss"
    print(f"trained {step} steps in {minutes:.1f} min; best {what} {best:.4f} at step {best_step}")
    return FitResult(step, minutes, best, best_step)


def solver_settings(model, nfe: int, t_end: float) -> dict:
    """FlowPolicy arguments: SRFMP the paper's schedule (first step 1/lambda_x), RFMP uniform
    steps to T, DDIM ``nfe`` DDIM steps (T does not apply)."""
    if model.cfg.algorithm == "ddim":
        return {"nfe": nfe}
    schedule = "srfmp" if model.cfg.algorithm == "srfmp" else "uniform"
    return {"nfe": nfe, "t_end": t_end, "schedule": schedule}


def end_time(model, nfe: int, t_end: float) -> float:
    """The flow time actually reached (SRFMP's first step is 1/lambda_x, so NFE=1 ends there)."""
    if model.cfg.algorithm == "ddim":
        return 1.0
    kw = solver_settings(model, nfe, t_end)
    return sum(step_sizes(nfe, "euler", t_end, kw["schedule"], model.cfg.lambda_x))


def make_actor(model, nfe: int, t_end: float, observation_key="obs_window",
               camera_keys=None) -> MultiStepActorWrapper:
    """FlowPolicy executing T_a of every T_p actions (receding horizon)."""
    policy = FlowPolicy(model, observation_key=observation_key, camera_keys=camera_keys,
                        **solver_settings(model, nfe, t_end))
    return MultiStepActorWrapper(policy, n_steps=model.cfg.horizon,
                                 replan_interval=model.cfg.action_steps)


def sweep_settings(model, nfes, t_ends, time_table=()) -> list[tuple[int, float]]:
    """(NFE, T) pairs: every NFE x T, plus ``time_table`` pairs; DDIM: every NFE at T = 1."""
    if model.cfg.algorithm == "ddim":
        return [(int(nfe), 1.0) for nfe in nfes]
    settings = [(int(nfe), float(t)) for t in t_ends for nfe in nfes]
    for nfe, t_end in time_table or []:
        if (int(nfe), float(t_end)) not in settings:
            settings.append((int(nfe), float(t_end)))
    return settings
