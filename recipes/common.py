"""Pieces every training recipe shares (imported by recipes/<task>/utils.py and train.py): the
start of a run (runtime, resume, seeds, run folder), the call into the library's training
engine (`rfmp_rl.training.Trainer`), checkpoint loading for evaluation, and the acting policy
(FlowPolicy inside MultiStepActorWrapper) with the solver settings of each algorithm."""

from __future__ import annotations

import sys
from pathlib import Path

import torch
from omegaconf import DictConfig, OmegaConf

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from rfmp_rl import keys  # noqa: E402
from rfmp_rl.modules import RecedingHorizonActor  # noqa: E402
from rfmp_rl.modules import make_actor as make_receding_actor  # noqa: E402
from rfmp_rl.solvers import SolverConfig  # noqa: E402

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
    the task comes from the checkpoint's stored training config, ``eval.*``, ``seed``,
    ``threads``, ``device`` and ``compile`` from this command line (the policy runs on that
    device in fp32)."""
    from rfmp_rl.checkpoint import load_checkpoint

    if not cfg.checkpoint:
        raise SystemExit("eval.py: give the checkpoint: checkpoint=runs/<recipe>/<run>/best.pt")
    checkpoint = Path(cfg.checkpoint)
    if not checkpoint.exists():
        raise SystemExit(f"eval.py: no such checkpoint: {checkpoint}")
    torch.set_num_threads(int(cfg.threads))
    model, payload = load_checkpoint(checkpoint, use_ema=True)
    runtime = {k: cfg[k] for k in ("device", "precision", "compile") if k in cfg}
    task = OmegaConf.merge(OmegaConf.create(payload["config"]),
                           {"eval": cfg.eval, "seed": cfg.seed, "threads": cfg.threads, **runtime})
    check_config(task)
    from rfmp_rl.training import compile_networks, resolve_device

    model = model.to(resolve_device(task.get("device", "auto")))
    if task.get("compile", False):
        compile_networks(model)
    out = Path(cfg.eval.out) if cfg.eval.out else checkpoint.parent / "eval"
    return model, task, payload.get("extra", {}), out


def check_runtime_config(cfg: DictConfig) -> None:
    """The device / precision / compile / logger / eval.workers settings, checked before any
    work (each error names its setting)."""
    from rfmp_rl.training import LOGGER_BACKENDS, check_settings

    check_settings(cfg.get("device", "auto"), cfg.get("precision", "fp32"))
    if not isinstance(cfg.get("compile", False), bool):
        raise ValueError(f"compile must be true or false, got {cfg.get('compile')!r}")
    logger = cfg.get("logger", "csv")
    backend = logger if isinstance(logger, str) else logger.get("backend", "csv")
    if backend not in LOGGER_BACKENDS:
        raise ValueError(f"logger.backend={backend!r}: use one of {LOGGER_BACKENDS}")
    workers = cfg.get("eval", {}).get("workers", 1)
    if not isinstance(workers, int) or workers < 1:
        raise ValueError(f"eval.workers must be an integer >= 1, got {workers!r}")


def start_run(cfg: DictConfig, recipe: str, fixed, overrides=None, default_name: str = "run"):
    """Everything before the data: the resumed configuration (``resume=``), the runtime (device,
    precision, compile; the DDP process group under torchrun), the seeds (by seed and rank) and
    the run folder (rank 0's name on every rank). Returns ``(cfg, runtime, run_dir, last.pt to
    resume or None)``. Nothing is written here, so a refused setting leaves every folder as it
    was; a fresh run refuses a folder that already holds a run's ``last.pt``."""
    import torch.distributed as dist

    from rfmp_rl.training import rank_seed, setup_runtime
    from rfmp_rl.training.resume import resume_checkpoint, resume_config

    last = None
    if cfg.get("resume"):
        last = resume_checkpoint(cfg.resume, recipe)
        cfg = resume_config(cfg, last, fixed, overrides)
    elif cfg.out_dir and (Path(cfg.out_dir) / "last.pt").exists():
        raise ValueError(f"out_dir={cfg.out_dir} already holds a run (last.pt): continue it with "
                         f"resume={cfg.out_dir} or choose another out_dir")
    runtime = setup_runtime(cfg.device, cfg.precision, cfg.compile)
    torch.set_num_threads(int(cfg.threads))
    torch.manual_seed(rank_seed(cfg.seed, runtime.rank))
    name = [str(cfg.out_dir or ROOT / "runs" / recipe / default_name)]
    if runtime.distributed:  # the ranks' clocks may name different folders: take rank 0's
        dist.broadcast_object_list(name, src=0)
    return cfg, runtime, Path(name[0]), last


def build_training(cfg: DictConfig, runtime, make_stores, make_replay_buffer, make_model,
                   what: str):
    """The recipe's factories in order: stores, replay buffers (the training one seeded by seed
    and rank, the validation one by seed), the model with fitted normalisers; rank 0 prints
    what it built. Returns ``(model, rb, val_rb)``."""
    from rfmp_rl.training import rank_seed

    train_store, val_store = make_stores(cfg)
    rb = make_replay_buffer(train_store, cfg, seed=rank_seed(cfg.seed, runtime.rank))
    val_rb = make_replay_buffer(val_store, cfg, seed=cfg.seed + 1)
    model = make_model(cfg, train_store)
    if runtime.is_main:
        print(train_store.manifest)
        n_params = sum(p.numel() for p in model.parameters())
        print(f"{what}: {n_params / 1e6:.2f}M parameters, {len(train_store)} training steps in "
              f"{train_store.num_episodes} episodes; {runtime.world_size} process(es) on "
              f"{runtime.device} ({cfg.precision}), global batch "
              f"{cfg.train.batch_size * runtime.world_size}")
    return model, rb, val_rb


def fit(model, rb, val_rb, cfg: DictConfig, run_dir: Path, runtime, recipe: str, resume=None,
        camera_keys=None, rollout_score=None, loss=None, control_rate_hz=None):
    """Train with the library's engine (`rfmp_rl.training.Trainer`) and the recipe's settings
    (``optim``, ``train``, ``logger``), the loss options ``loss`` (`LossConfig`) and the env's
    ``control_rate_hz`` (both stored in the checkpoints). ``config.yaml`` is written once the
    engine has accepted the settings (a refused resume writes nothing)."""
    from rfmp_rl.training import LoggerConfig, OptimConfig, TrainConfig, Trainer

    trainer = Trainer(
        model, rb, val_rb, runtime=runtime, run_dir=run_dir, recipe=recipe,
        optim=OptimConfig.from_config(cfg.optim), train=TrainConfig.from_config(cfg.train),
        logger=LoggerConfig.from_config(cfg.get("logger", "csv")),
        config=OmegaConf.to_container(cfg, resolve=True), seed=int(cfg.seed),
        camera_keys=camera_keys, rollout_score=rollout_score, resume=resume,
        solver=run_solver(cfg), loss=loss, control_rate_hz=control_rate_hz,
    )
    if runtime.is_main:
        run_dir.mkdir(parents=True, exist_ok=True)
        (run_dir / "config.yaml").write_text(OmegaConf.to_yaml(cfg))
    return trainer.fit()


def eval_model(path: Path, cfg: DictConfig, runtime=None):
    """The EMA policy of a checkpoint on the run's device, compiled with ``compile=true``;
    returns ``(model, payload)``."""
    from rfmp_rl.checkpoint import load_checkpoint
    from rfmp_rl.training import compile_networks

    model, payload = load_checkpoint(path, use_ema=True)
    if runtime is not None:
        model = model.to(runtime.device)
        if runtime.compile:
            compile_networks(model)
    return model.eval(), payload


def deploy_classes():
    """``(Controller, Policy)`` of the torch-free deploy package (``deploy/rfmp_deploy``), as a
    robot PC runs it."""
    if str(ROOT / "deploy") not in sys.path:
        sys.path.insert(0, str(ROOT / "deploy"))
    from rfmp_deploy import Controller, Policy

    return Controller, Policy


def exit_code(result) -> int:
    """The process exit status of a training run: 0, or 128 + the signal that stopped it."""
    import signal

    if not result.interrupted or not result.interrupted.startswith("SIG"):
        return 0 if not result.interrupted else 1
    return 128 + int(getattr(signal, result.interrupted))


def solver_config(model, nfe: int, t_end: float) -> SolverConfig:
    """The solver at (NFE, T) with the algorithm's defaults (`rfmp_rl.solvers.SolverConfig`)."""
    return SolverConfig(nfe=nfe, t_end=t_end).resolve(model.cfg.algorithm)


def run_solver(cfg: DictConfig) -> SolverConfig:
    """The solver a run selects with (``train.select_nfe`` / ``select_t_end``; else the first
    evaluation NFE at T = 1): stored in its checkpoints."""
    nfe = cfg.train.get("select_nfe") or cfg.eval.nfes[0]
    return SolverConfig(nfe=int(nfe), t_end=float(cfg.train.get("select_t_end") or 1.0))


def end_time(model, nfe: int, t_end: float) -> float:
    """The flow time actually reached (SRFMP's first step is 1/lambda_x, so NFE=1 ends there)."""
    return solver_config(model, nfe, t_end).reached(model.cfg.lambda_x)


def make_actor(model, nfe: int, t_end: float, observation_key=keys.OBS_WINDOW,
               camera_keys=None) -> RecedingHorizonActor:
    """FlowPolicy executing T_a of every T_p actions (receding horizon;
    `rfmp_rl.modules.make_actor`)."""
    actor, _ = make_receding_actor(model, observation_key=observation_key,
                                   camera_keys=camera_keys,
                                   solver=solver_config(model, nfe, t_end))
    return actor


def sweep_settings(model, nfes, t_ends, time_table=()) -> list[tuple[int, float]]:
    """(NFE, T) pairs: every NFE x T, plus ``time_table`` pairs; DDIM: every NFE at T = 1."""
    if model.cfg.algorithm == "ddim":
        return [(int(nfe), 1.0) for nfe in nfes]
    settings = [(int(nfe), float(t)) for t in t_ends for nfe in nfes]
    for nfe, t_end in time_table or []:
        if (int(nfe), float(t_end)) not in settings:
            settings.append((int(nfe), float(t_end)))
    return settings
