"""Pieces every training recipe shares (imported by recipes/<task>/utils.py, train.py and
eval.py): the recipe config's groups mapped onto the library's dataclasses (``model`` ->
`ModelConfig`, ``loss``, ``optim`` / ``train`` / ``logger`` -> `rfmp_rl.training`, ``eval`` ->
`rfmp_rl.eval.EvalConfig`), the start of a run (runtime, resume, seeds, run folder), the call
into the library's training engine, checkpoint loading for evaluation (configs of earlier
versions upgraded), the acting policy, and the sweep of `rfmp_rl.eval` with a task's env and
metrics (`TaskEval`)."""

from __future__ import annotations

import os
import shlex
import sys
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, fields, replace
from datetime import datetime
from pathlib import Path
from typing import Any

import torch
from omegaconf import DictConfig, OmegaConf
from omegaconf.errors import OmegaConfBaseException

from rfmp_rl import keys
from rfmp_rl.eval import Column, EvalConfig, plot_sweep, setting_label, sweep, write_tables
from rfmp_rl.flows import StablePath
from rfmp_rl.modules import ModelConfig, RecedingHorizonActor
from rfmp_rl.modules import make_actor as make_receding_actor
from rfmp_rl.objectives import LossConfig
from rfmp_rl.solvers import SolverConfig

ROOT = Path(__file__).resolve().parents[1]
#: Where `recipes/paper_comparison.py --record` keeps what a report needs of each run folder.
RECORDS = ROOT / "results" / "records"

#: The algorithms, named as the library names them (`ModelConfig.algorithm`).
ALGORITHMS = ("rfmp", "srfmp", "ddim", "cp")

#: Settings of earlier versions' flat recipe configs -> their place in the config groups.
RENAMED = {
    "preset": "model.unet_preset", "down_dims": "model.down_dims", "horizon": "model.horizon",
    "action_steps": "model.action_steps", "obs_horizon": "model.obs_horizon",
    "prior": "model.prior_sphere", "prior_scale": "model.prior_scale",
    "prior_repeat": "model.prior_repeat", "lambda_x": "loss.lambda_x",
    "lambda_tau": "loss.lambda_tau", "time_max": "loss.time_max",
    "t0_fraction": "loss.t0_fraction",
}
#: Group settings of earlier versions that moved to another group.
MOVED = {
    "train.select_seeds": "select.seeds", "train.select_seed_start": "select.seed_start",
    "train.select_nfe": "select.nfe", "train.select_t_end": "select.t_end",
}
#: Algorithm names of earlier versions -> the library's.
RENAMED_ALGOS = {"dp": "ddim"}
#: ModelConfig fields a task derives from its own settings (never set in ``model:``).
TASK_MODEL_FIELDS = ("algorithm", "action_manifold", "obs_dim", "obs_manifold", "obs_keys",
                     "cameras", "crop_shape", "obs_quaternions")
#: The training-time options of the loss (``loss:``).
LOSS_FIELDS = ("time_sampling", "time_max", "t0_fraction", "lambda_x", "lambda_tau")


# ----- configuration ---------------------------------------------------------------------------
def upgrade_argv(argv: Sequence[str]) -> list[str]:
    """A command line of earlier versions in today's names (``horizon=16`` ->
    ``model.horizon=16``, ``algo=dp`` -> ``algo=ddim``); each rename is printed."""
    out = []
    for arg in argv:
        key, eq, value = arg.partition("=")
        prefix = key[: len(key) - len(key.lstrip("+~"))]
        name = key[len(prefix):]
        new = arg
        if eq and name in RENAMED:
            new = f"{prefix}{RENAMED[name]}={value}"
        elif eq and name in MOVED:
            new = f"{prefix}{MOVED[name]}={value}"
        elif eq and name == "algo" and value in RENAMED_ALGOS:
            new = f"{key}={RENAMED_ALGOS[value]}"
        if new != arg:
            print(f"note: {arg} is now {new}", file=sys.stderr)
        out.append(new)
    return out


#: Environment variables that change how a recipe runs, kept with its command line.
COMMAND_ENV = ("OMP_NUM_THREADS", "MUJOCO_GL", "CUDA_VISIBLE_DEVICES")
#: Each run folder's command lines: the one that started it, then one per resume.
COMMAND_FILE = "command.txt"


def _shown(path: str, cwd: Path) -> str:
    """``path`` (as given in ``cwd``) for a command line run in ``cwd``: relative to the
    repository when ``cwd`` is its root and the path is inside it, absolute otherwise (symbolic
    links kept: a virtual environment's interpreter stays in its ``bin``)."""
    absolute = Path(os.path.abspath(os.path.join(cwd, path)))
    if cwd == ROOT and absolute.is_relative_to(ROOT):
        return str(absolute.relative_to(ROOT))
    return str(absolute)


def command_line(argv: Sequence[str] | None = None, environ: Mapping[str, str] | None = None,
                 cwd: str | Path | None = None) -> str:
    """This process's command as one shell line (or ``argv`` with ``environ``, run in ``cwd``):
    ``cd <cwd> &&`` unless it ran in the repository root, the `COMMAND_ENV` variables that are
    set, ``torchrun`` with its processes per node when under it (several nodes: their count;
    the cluster's rendezvous options are not known here), the interpreter and the script, the
    arguments quoted for the shell.

    Example:
        >>> command_line(["recipes/pusht/train.py", "eval.nfes=[1,3]"], {"OMP_NUM_THREADS": "1"},
        ...              cwd=ROOT)
        "OMP_NUM_THREADS=1 python recipes/pusht/train.py 'eval.nfes=[1,3]'"
        >>> command_line(["/x/train.py", "seed=1"], {"LOCAL_WORLD_SIZE": "2", "WORLD_SIZE": "4",
        ...                                         "GROUP_WORLD_SIZE": "2"}, cwd=ROOT)
        'torchrun --nnodes=2 --nproc_per_node=2 /x/train.py seed=1'
        >>> command_line(["train.py", "out_dir=runs/x"], {}, cwd="/tmp")
        'cd /tmp && python /tmp/train.py out_dir=runs/x'
    """
    this_process = argv is None
    argv = list(sys.argv if this_process else argv)
    environ = os.environ if environ is None else environ
    cwd = Path(os.path.abspath(os.getcwd() if cwd is None else cwd))
    parts = [] if cwd == ROOT else ["cd", shlex.quote(str(cwd)), "&&"]
    parts += [f"{k}={shlex.quote(environ[k])}" for k in COMMAND_ENV if k in environ]
    python = _shown(sys.executable, cwd) if this_process else "python"
    if "LOCAL_WORLD_SIZE" in environ:
        local = int(environ["LOCAL_WORLD_SIZE"])
        nodes = int(environ.get("GROUP_WORLD_SIZE") or
                    -(-int(environ.get("WORLD_SIZE", local)) // local))
        torchrun = Path(sys.executable).with_name("torchrun")
        parts += [_shown(str(torchrun), cwd) if this_process and torchrun.is_file()
                  else "torchrun", "--standalone" if nodes == 1 else f"--nnodes={nodes}",
                  f"--nproc_per_node={local}"]
    else:
        parts.append(shlex.quote(python))
    parts.append(shlex.quote(_shown(argv[0], cwd)))
    parts += [shlex.quote(a) for a in argv[1:]]
    return " ".join(parts)


def run_cli(main: Callable[[], Any]) -> None:
    """Run a recipe script's hydra ``main`` on the command line, its settings of earlier
    versions renamed first (`upgrade_argv` prints them)."""
    sys.argv = upgrade_argv(sys.argv)
    main()


def upgrade_config(config: Mapping[str, Any]) -> dict:
    """A stored recipe config (checkpoint or config.yaml) of earlier versions, whose model and
    loss settings were flat (``horizon``, ``t0_fraction``, ``algo: dp``), in today's groups;
    today's configs come back unchanged."""
    config = dict(OmegaConf.to_container(config) if isinstance(config, DictConfig) else config)
    for old, new in RENAMED.items():
        if old in config:
            group, name = new.split(".")
            config.setdefault(group, {})
            config[group] = {**config[group], name: config.pop(old)}
    for old, new in MOVED.items():
        (old_group, old_name), (group, name) = old.split("."), new.split(".")
        if old_name in (config.get(old_group) or {}):
            moved = dict(config[old_group])
            config[group] = {**(config.get(group) or {}), name: moved.pop(old_name)}
            config[old_group] = moved
    if config.get("algo") in RENAMED_ALGOS:
        config["algo"] = RENAMED_ALGOS[config["algo"]]
    if isinstance(config.get("logger"), str):  # logger=csv: the backend alone
        config["logger"] = {"backend": config["logger"]}
    return config


def check_algo(cfg: DictConfig) -> None:
    if cfg.algo in RENAMED_ALGOS:
        raise ValueError(f"algo={cfg.algo} is now algo={RENAMED_ALGOS[cfg.algo]} (the library's "
                         "name for the Diffusion Policy baseline)")
    if cfg.algo not in ALGORITHMS:
        raise ValueError(f"algo must be one of {ALGORITHMS}, got {cfg.algo!r}")


def loss_config(cfg: DictConfig) -> LossConfig:
    """The loss's training-time options from ``cfg.loss`` (`LOSS_FIELDS`); the flows' options
    are left at their neutral values for the algorithms that do not use them (``time_max`` is
    SRFMP's, ``t0_fraction`` the flows'). ``algo=cp`` adds its teacher (``teacher=``, a ddim
    checkpoint, stored as an absolute path)."""
    given = dict(cfg.loss)
    unknown = sorted(set(given) - set(LOSS_FIELDS))
    if unknown:
        raise ValueError(f"loss.{unknown[0]} is not a loss setting; the settings are "
                         f"{list(LOSS_FIELDS)}")
    if cfg.algo != "srfmp":
        given["time_max"] = 1.0
    if cfg.algo in ("ddim", "cp"):
        given["t0_fraction"] = 0.0
    if cfg.algo == "cp":
        if not cfg.get("teacher"):
            raise ValueError("algo=cp distils a Diffusion Policy: give its checkpoint, "
                             "teacher=runs/<recipe>/<ddim run>/best.pt")
        given["teacher"] = str(Path(cfg.teacher).resolve())
    return LossConfig(**given)


def model_config(cfg: DictConfig, **task) -> ModelConfig:
    """`ModelConfig` from ``cfg.model`` (architecture), ``cfg.algo`` and the fields the task
    derives (``task``: action manifold, observation keys and sizes, cameras, control rate), with
    the loss's options (`loss_config`) that ModelConfig also carries."""
    given = dict(cfg.model)
    names = {f.name for f in fields(ModelConfig)}
    for key in given:
        if key not in names or key in TASK_MODEL_FIELDS:
            raise ValueError(f"model.{key} is not an architecture setting of ModelConfig "
                             f"(the task sets {list(TASK_MODEL_FIELDS)})")
    if given.get("down_dims") is not None:
        given["down_dims"] = list(given["down_dims"])
    extra = {k: v for k, v in loss_config(cfg).to_dict().items() if k in names}
    return ModelConfig(algorithm=cfg.algo, **given, **task, **extra)


def eval_config(cfg: DictConfig) -> EvalConfig:
    """`EvalConfig` from ``cfg.eval``."""
    return EvalConfig.from_config(OmegaConf.to_container(cfg.eval, resolve=True))


def fixed_settings(cfg: DictConfig, task_keys: Sequence[str]) -> list[str]:
    """The settings that define a run (a resumed run may not change them): the task's choices,
    every ``model`` and ``loss`` setting, and the seed."""
    return [*task_keys, "algo", *(f"model.{k}" for k in cfg.model),
            *(f"loss.{k}" for k in cfg.loss), "seed"]


def resolve(path: str | Path) -> Path:
    """Relative data paths are taken from the repository root (not the working directory)."""
    path = Path(path)
    return path if path.is_absolute() else (ROOT / path).resolve()


def check_demo_count(path: str | Path, found: int, data_cfg: DictConfig) -> None:
    """A recipe's own demonstration file (``data.path`` not given) must hold the ``data.demos``
    the run asks for: a file written earlier with another count would be trained on silently.

    Raises:
        ValueError: naming the file and both counts.
    """
    if not data_cfg.path and found != int(data_cfg.demos):
        raise ValueError(
            f"{path} holds {found} demonstrations and data.demos={data_cfg.demos}: pass "
            f"data.demos={found} to train on them, or data.path=<another file> to write "
            f"{data_cfg.demos} there (a demonstration file is never replaced)")


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
    the task comes from the checkpoint's stored training config (that of an earlier version
    upgraded by `upgrade_config`), ``eval.*``, ``seed``, ``threads``, ``device`` and
    ``compile`` from this command line (the policy runs on that device in fp32)."""
    from rfmp_rl.checkpoint import load_checkpoint

    if not cfg.checkpoint:
        raise SystemExit("eval.py: give the checkpoint: checkpoint=runs/<recipe>/<run>/best.pt")
    checkpoint = Path(cfg.checkpoint)
    if not checkpoint.exists():
        raise SystemExit(f"eval.py: no such checkpoint: {checkpoint}")
    torch.set_num_threads(int(cfg.threads))
    model, payload = load_checkpoint(checkpoint, use_ema=True)
    stored = upgrade_config(payload["config"])
    stored.pop("eval", None)  # the evaluation is this command line's
    runtime = {k: cfg[k] for k in ("device", "precision", "compile") if k in cfg}
    try:
        task = OmegaConf.merge(cfg, stored, {"seed": cfg.seed, "threads": cfg.threads,
                                             **runtime})
    except OmegaConfBaseException as err:  # a setting this version's recipe does not have
        raise SystemExit(f"eval.py: {checkpoint} stores settings this recipe does not know "
                         f"({err}); rename or remove them in the checkpoint's 'config' entry "
                         "(torch.load, edit, torch.save) and evaluate again") from err
    check_config(task)
    from rfmp_rl.training import compile_networks, resolve_device

    if cfg.get("tau_max") is not None:
        set_tau_max(model, cfg.tau_max, payload.get("loss"), checkpoint)
    model = model.to(resolve_device(task.get("device", "auto")))
    if task.get("compile", False):
        compile_networks(model)
    out = Path(cfg.eval.out) if cfg.eval.out else checkpoint.parent / "eval"
    return model, task, payload.get("extra", {}), out


def set_tau_max(model, value, loss: dict | None, checkpoint: Path) -> None:
    """Give an SRFMP checkpoint's model the tau clamp `ModelConfig.tau_max`: ``"trained"``
    (tau at the time_max of the checkpoint's stored loss settings) or a number."""
    if not getattr(model, "stable", False):
        raise SystemExit(f"tau_max applies to SRFMP checkpoints; {checkpoint} holds "
                         f"{model.cfg.algorithm}")
    if value == "trained":
        if not loss:
            raise SystemExit(f"tau_max=trained: {checkpoint} stores no loss settings; give "
                             "tau_max as a number")
        lo = LossConfig.from_dict(loss)
        value = lo.trained_tau_max(StablePath(model.chunk, lo.lambda_x, lo.lambda_tau,
                                              model.cfg.tau0, model.cfg.tau1))
    try:
        model.cfg = replace(model.cfg, tau_max=float(value))
    except ValueError as err:
        raise SystemExit(f"tau_max={value}: {err}") from err
    print(f"SRFMP network tau clamped at tau_max={model.cfg.tau_max:.6g}")


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
    eval_config(cfg)  # each bad evaluation setting named


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
        stored = OmegaConf.to_container(OmegaConf.load(last.parent / "config.yaml"))
        if upgrade_config(stored) != stored:
            raise ValueError(
                f"resume={cfg.resume}: {last.parent / 'config.yaml'} has the flat settings of an "
                "earlier version; rename them there (" + ", ".join(
                    f"{k} -> {v}" for k, v in RENAMED.items() if k in stored)
                + (", algo: dp -> algo: ddim" if stored.get("algo") == "dp" else "")
                + ") and resume again")
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
    if cfg.algo == "cp":
        model = cp_student(model, cfg)
    if runtime.is_main:
        print(train_store.manifest)
        n_params = sum(p.numel() for p in model.parameters())
        print(f"{what}: {n_params / 1e6:.2f}M parameters, {len(train_store)} training steps in "
              f"{train_store.num_episodes} episodes; {runtime.world_size} process(es) on "
              f"{runtime.device} ({cfg.precision}), global batch "
              f"{cfg.train.batch_size * runtime.world_size}")
    return model, rb, val_rb


def cp_student(model, cfg: DictConfig):
    """``algo=cp``: the student initialised from the teacher (``teacher=``): its weights and
    normalisers (`ConsistencyModel.from_teacher`; distillation runs in the teacher's normalised
    space). The run's model settings must be the teacher's; each difference is named."""
    from rfmp_rl.modules import ConsistencyModel
    from rfmp_rl.objectives.consistency import load_teacher

    path = loss_config(cfg).teacher
    student = ConsistencyModel.from_teacher(load_teacher(path))
    mine, theirs = model.cfg.to_dict(), student.cfg.to_dict()
    differ = [f"{k}: teacher {theirs[k]!r}, this run {mine[k]!r}" for k in mine
              if mine[k] != theirs[k]]
    if differ:
        raise ValueError(f"teacher={path} was trained with other model settings ("
                         + "; ".join(differ) + "): give this run the teacher's")
    return student


def fit(model, rb, val_rb, cfg: DictConfig, run_dir: Path, runtime, recipe: str, resume=None,
        camera_keys=None, rollout_score=None, control_rate_hz=None, command: str | None = None):
    """Train with the library's engine (`rfmp_rl.training.Trainer`) and the recipe's settings
    (``optim``, ``train``, ``logger``). ``config.yaml`` is written once the engine has accepted
    the settings (a refused resume writes nothing), and ``command`` (the command line that
    started or resumed the run) is added to the run's ``command.txt``."""
    from rfmp_rl.training import LoggerConfig, OptimConfig, TrainConfig, Trainer

    trainer = Trainer(
        model, rb, val_rb, runtime=runtime, run_dir=run_dir, recipe=recipe,
        optim=OptimConfig.from_config(cfg.optim), train=TrainConfig.from_config(cfg.train),
        logger=LoggerConfig.from_config(cfg.get("logger", "csv")),
        config=OmegaConf.to_container(cfg, resolve=True), seed=int(cfg.seed),
        camera_keys=camera_keys, rollout_score=rollout_score, resume=resume,
        solver=run_solver(cfg), loss=loss_config(cfg), control_rate_hz=control_rate_hz,
    )
    if runtime.is_main:
        run_dir.mkdir(parents=True, exist_ok=True)
        (run_dir / "config.yaml").write_text(OmegaConf.to_yaml(cfg))
        if command:  # a fresh run starts the file, a resumed one adds its line
            with open(run_dir / COMMAND_FILE, "a" if resume is not None else "w") as f:
                f.write(command + "\n")
    return trainer.fit()


@dataclass
class RecipeTraining:
    """What a recipe's ``train.py`` plugs into `train_run`: its name, how its run folder and
    log lines name the run, its data and model builders and its evaluation.

    ``what(cfg)`` names the run in the logs (``"srfmp on Lift (state, delta)"``),
    ``heading(cfg, what, result, step)`` heads the final evaluation's table, ``prepare(cfg)``
    runs on rank 0 before the data is read (e.g. writes the expert's demonstrations), and
    ``fit_options(cfg)`` gives `fit`'s keyword arguments (``camera_keys``, ``rollout_score``,
    ``control_rate_hz``)."""

    recipe: str
    task_keys: Sequence[str]
    check: Callable[[DictConfig], None]
    run_name: Callable[[DictConfig], str]
    what: Callable[[DictConfig], str]
    make_stores: Callable
    make_replay_buffer: Callable
    make_model: Callable
    eval_task: Callable
    fit_options: Callable[[DictConfig], dict] = lambda cfg: {}
    prepare: Callable[[DictConfig], None] | None = None
    heading: Callable | None = None

    @classmethod
    def from_utils(cls, utils, **parts) -> RecipeTraining:
        """The training of the recipe whose ``utils`` module is given: its ``TASK_KEYS``,
        ``check_config``, ``make_stores``, ``make_replay_buffer``, ``make_model`` and
        ``eval_task``, `fit` told its ``CONTROL_RATE_HZ``; ``parts`` are the other fields (and
        may replace these).

        Example::

            TRAINING = RecipeTraining.from_utils(
                utils, recipe="kitchen", run_name=lambda cfg: str(cfg.algo),
                what=lambda cfg: f"{cfg.algo} on Franka Kitchen")
        """
        rate = utils.CONTROL_RATE_HZ
        return cls(**{
            "task_keys": utils.TASK_KEYS, "check": utils.check_config,
            "make_stores": utils.make_stores, "make_replay_buffer": utils.make_replay_buffer,
            "make_model": utils.make_model, "eval_task": utils.eval_task,
            "fit_options": lambda cfg: {"control_rate_hz": rate}, **parts})

    def run(self, cfg: DictConfig, overrides=None) -> tuple[Path, Any]:
        """`train`, also returning the engine's `FitResult` (steps, best score, interruption)."""
        return train_run(cfg, self, overrides)

    def train(self, cfg: DictConfig, overrides=None) -> Path:
        """Train, keep the best checkpoint, optionally evaluate it; returns the run folder.
        ``overrides``: the command line's explicit overrides (applied on top of a resumed run's
        configuration)."""
        return self.run(cfg, overrides)[0]

    def main(self, cfg: DictConfig) -> None:
        """The recipe's command line (its train.py's hydra ``main``): `run` with the command
        line's overrides, then exit with `exit_code`."""
        from hydra.core.hydra_config import HydraConfig

        _, result = train_run(cfg, self, list(HydraConfig.get().overrides.task),
                              command=command_line())
        raise SystemExit(exit_code(result))


def train_run(cfg: DictConfig, parts: RecipeTraining, overrides=None, command=None):
    """A recipe's training run: start (or resume) the run folder, build the data and the model,
    train with `fit` (``command``: the command line, kept in the run's ``command.txt``), then,
    with ``eval.final_eval``, evaluate ``best.pt`` and write ``<run>/eval``. Returns
    ``(run folder, FitResult)``."""
    parts.check(cfg)
    name = f"{parts.run_name(cfg)}_{datetime.now():%Y%m%d_%H%M%S}"
    fixed = fixed_settings(cfg, parts.task_keys)
    cfg, runtime, run_dir, last = start_run(cfg, parts.recipe, fixed, overrides, name)
    parts.check(cfg)
    if parts.prepare is not None:
        if runtime.is_main:
            parts.prepare(cfg)  # once, on rank 0
        runtime.barrier()
    what = parts.what(cfg)
    model, rb, val_rb = build_training(cfg, runtime, parts.make_stores, parts.make_replay_buffer,
                                       parts.make_model, what)
    result = fit(model, rb, val_rb, cfg, run_dir, runtime, parts.recipe, last,
                 command=command, **parts.fit_options(cfg))
    if cfg.eval.final_eval and runtime.is_main and not result.interrupted:
        best, meta = eval_model(run_dir / "best.pt", cfg, runtime)
        task = parts.eval_task(cfg)
        rows = run_sweep(best, cfg, task, progress=show(task))
        step = meta["extra"].get("step")
        title = (parts.heading(cfg, what, result, step) if parts.heading is not None else
                 f"{what}: {cfg.model.unet_preset}, best of {result.steps} steps at step "
                 f"{step}, {result.minutes:.0f} min")
        command = f"python recipes/{parts.recipe}/eval.py checkpoint={run_dir / 'best.pt'}"
        print(report(rows, run_dir / "eval", cfg, task, title, command).read_text())
    if runtime.is_main:
        print(f"run folder: {run_dir}")
    runtime.shutdown()
    return run_dir, result


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
    """The solver a run selects with (``select.nfe`` / ``select.t_end`` of a recipe with rollout
    selection; else the first evaluation NFE at T = 1): stored in its checkpoints."""
    select = cfg.get("select") or {}
    nfe = select.get("nfe") or cfg.eval.nfes[0]
    return SolverConfig(nfe=int(nfe), t_end=float(select.get("t_end") or 1.0))


def make_actor(model, nfe: int, t_end: float, observation_key=keys.OBS_WINDOW,
               camera_keys=None) -> RecedingHorizonActor:
    """FlowPolicy executing T_a of every T_p actions (receding horizon;
    `rfmp_rl.modules.make_actor`)."""
    actor, _ = make_receding_actor(model, observation_key=observation_key,
                                   camera_keys=camera_keys,
                                   solver=solver_config(model, nfe, t_end))
    return actor


# ----- evaluation ------------------------------------------------------------------------------
@dataclass
class TaskEval:
    """What a task recipe gives the evaluation sweep (`rfmp_rl.eval.sweep`) for one config.

    Args:
        env_fn: picklable env factory ``env_fn(batch_size=[N], seeds=[...], **env_kwargs)``.
        env_kwargs: the factory's other settings.
        make_actor: ``(model, nfe, t_end) -> actor`` acting in the env.
        metrics: ``metrics(rollout, steps)``, the per-seed figures.
        summary: per-seed values -> the row's figures.
        columns: the figures of the markdown table (the first three are printed as rows finish).
        labels: ``{field: value}`` opening every row (algorithm, task variant).
        max_steps: the episode limit when ``eval.max_steps`` is null.
        num_envs: envs stepped side by side when ``eval.num_envs`` is null (None: every seed).
        paper: ``{(NFE, T): value}``: the paper's figure for the column marked ``paper=True``.
        time_paper: ``{(NFE, T): value}``: the figures of the paper's integration-time table,
            beside ``paper``'s in the side-by-side row where the two tables differ.
        plot: ``(field, axis label, y range)`` of eval.png, or None for no plot.
        notes: lines printed under the table.
    """

    env_fn: Callable
    env_kwargs: dict
    make_actor: Callable
    metrics: Callable
    summary: Callable[[Mapping], dict]
    columns: list[Column]
    labels: dict
    max_steps: int | None = None
    num_envs: int | None = None
    paper: dict = field(default_factory=dict)
    time_paper: dict = field(default_factory=dict)
    plot: tuple | None = None
    notes: list[str] = field(default_factory=list)


def show(task: TaskEval):
    """A progress callback printing a finished row's setting and first figures."""
    def progress(row: dict) -> None:
        figures = ", ".join(f"{c.header} {c.cell(row)}" for c in task.columns[:3])
        print(f"  {setting_label(row)}: {figures} ({row['seconds']:.0f} s)")

    return progress


def run_sweep(model, cfg: DictConfig, task: TaskEval, progress=None) -> list[dict]:
    """Every (NFE, T) of ``cfg.eval`` for ``model`` in the task's envs; one row each."""
    settings = eval_config(cfg)
    settings.num_envs = settings.num_envs or task.num_envs
    return sweep(task.env_fn, model, lambda nfe, t_end: task.make_actor(model, nfe, t_end),
                 settings, task.metrics, seed=int(cfg.seed), labels=task.labels,
                 summary=task.summary, max_steps=task.max_steps, env_kwargs=task.env_kwargs,
                 progress=progress)


def evaluate_checkpoint(cfg: DictConfig, recipe: str, check_config: Callable[[DictConfig], None],
                        make_task: Callable[[DictConfig, Any], TaskEval],
                        name: Callable[[DictConfig], str]) -> list[dict]:
    """A recipe's eval.py: the sweep on ``cfg.checkpoint`` with the task settings of the
    checkpoint's config (``check_config`` checks them) and the ``eval.*`` fields of ``cfg``;
    prints and writes the tables (`report`) and returns their rows.

    ``make_task(task_cfg, model)`` gives the recipe's `TaskEval`; ``name(task_cfg)`` opens the
    table's title (``"Push-T state euclidean"``: ``"<name>: <algo> (<preset>, step ...)"``).
    """
    model, task_cfg, extra, out = load_for_eval(cfg, check_config)
    task = make_task(task_cfg, model)
    rows = run_sweep(model, task_cfg, task, progress=show(task))
    title = (f"{name(task_cfg)}: {task_cfg.algo} ({task_cfg.model.unet_preset}, step "
             f"{extra.get('step')}, {extra.get('train_minutes', float('nan')):.0f} min training)")
    command = f"python recipes/{recipe}/eval.py " + " ".join(sys.argv[1:])
    print(report(rows, out, task_cfg, task, title, command).read_text())
    return rows


def report(rows: list[dict], out: Path, cfg: DictConfig, task: TaskEval, title: str,
           command: str) -> Path:
    """eval.md and eval.csv (and eval.png) of a sweep in ``out``; returns eval.md."""
    path = write_tables(rows, out, title=title, command=command, columns=task.columns,
                        labels=list(task.labels), paper=task.paper,
                        time_table=cfg.eval.get("time_table") or (), time_paper=task.time_paper,
                        notes=task.notes)
    if task.plot is not None:
        key, ylabel, ylim = task.plot
        plot_sweep(rows, out / "eval.png", key, ylabel=ylabel, title=title, ylim=ylim)
    return path
