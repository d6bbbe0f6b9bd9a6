"""What the recipes' scripted experts share (recipes/kitchen/experts.py,
recipes/robosuite/experts.py): the batched expert policy's step, the collection of successful
episodes from consecutive seeds, and the summary line of their command lines."""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Sequence, Sized
from typing import Any

import numpy as np

from rfmp_rl import keys


def act_batched(tensordict: Any, experts: Sequence[Any], sims: Sequence[Any]) -> Any:
    """One step of a batch of experts: expert ``i`` acts on ``sims[i]``, reset first when its
    instance starts an episode (``step_count == 0``); writes ``action (N, A)`` (float32) into
    ``tensordict`` and returns it.

    Example::

        td = act_batched(td, [KitchenExpert(), KitchenExpert()], env.instances)
    """
    import torch

    counts = tensordict.get("step_count").reshape(-1).tolist()
    actions = []
    for i, (expert, sim) in enumerate(zip(experts, sims, strict=True)):
        if counts[i] == 0:
            expert.reset(sim)
        actions.append(expert.act(sim))
    action = torch.as_tensor(np.stack(actions), dtype=torch.float32, device=tensordict.device)
    return tensordict.set(keys.ACTION, action)


def attempts_limit(n_success: int, max_attempts: int | None) -> int:
    """How many episodes `collect_successes` may run: ``max_attempts``, by default
    ``2 * n_success + 20``.

    Example:
        >>> attempts_limit(10, None)
        40
    """
    if n_success < 1:
        raise ValueError(f"generate_demos: n_success must be >= 1, got {n_success}")
    return 2 * n_success + 20 if max_attempts is None else int(max_attempts)


def collect_successes(
    run_episode: Callable[[int], tuple[Any, bool, int]],
    n_success: int,
    max_attempts: int,
    *,
    seed_start: int,
    close: Callable[[], Any],
    label: str,
    context: str = "",
    verbose: bool = True,
) -> tuple[list, list[int], list[int], float]:
    """Run ``run_episode(seed) -> (episode, success, steps)`` from ``seed_start`` on until
    ``n_success`` episodes succeeded or ``max_attempts`` ran, then ``close()`` the env.

    Returns:
        ``(successful episodes, their seeds, the failed seeds, seconds)``.

    Raises:
        RuntimeError: fewer than ``n_success`` successes (``context`` follows the attempts in
            the message).

    Example::

        episodes, kept, failed, seconds = collect_successes(
            run, 2, 24, seed_start=0, close=env.close, label="[Lift/delta]")
    """
    episodes: list = []
    kept: list[int] = []
    failed: list[int] = []
    seed = seed_start
    start = time.perf_counter()
    while len(episodes) < n_success and seed - seed_start < max_attempts:
        episode, success, steps = run_episode(seed)
        if success:
            episodes.append(episode)
            kept.append(seed)
        else:
            failed.append(seed)
        if verbose:
            print(f"{label} seed {seed}: {'ok' if success else 'FAILED'} ({steps} steps) "
                  f"{len(episodes)}/{n_success}", flush=True)
        seed += 1
    seconds = time.perf_counter() - start
    close()
    if len(episodes) < n_success:
        raise RuntimeError(f"generate_demos: only {len(episodes)} of {n_success} successes in "
                           f"{seed - seed_start} attempts{context}; failed seeds: {failed}")
    return episodes, kept, failed, seconds


def success_summary(n_episodes: int, failed: Sized, lengths: Sequence[int], seconds: float,
                    **rates: Any) -> dict[str, Any]:
    """An expert evaluation's figures: ``attempts``, ``successes``, ``success_rate``, then
    ``rates`` (e.g. per subtask), ``failed_seeds``, ``mean_steps`` (of the successful episodes)
    and ``seconds_per_episode``.

    Example:
        >>> success_summary(4, [2], [10, 12, 14], 2.0)["success_rate"]
        0.75
    """
    return {
        "attempts": n_episodes,
        "successes": n_episodes - len(failed),
        "success_rate": (n_episodes - len(failed)) / max(n_episodes, 1),
        **rates,
        "failed_seeds": failed,
        "mean_steps": float(np.mean(lengths)) if lengths else float("nan"),
        "seconds_per_episode": seconds / max(n_episodes, 1),
    }


def print_summary(result: dict[str, Any]) -> None:
    """Print ``result`` as one JSON line, without its list of kept seeds."""
    print(json.dumps({k: v for k, v in result.items() if k != "seeds"}), flush=True)
