"""Evaluation envs whose per-seed noise and episodes do not depend on the batching: PriorNoise
streams per seed, ParallelEnv workers with padding seeds, FlatBatch."""

from __future__ import annotations

import pytest
import torch

pytest.importorskip("gym_pusht")

from rfmp_rl.envs.pusht import make_pusht_env  # noqa: E402
from rfmp_rl.eval.parallel import (  # noqa: E402
    PriorNoise,
    evaluation_env,
    flatten_workers,
)


def _noise(seeds, steps=3, noise_seed=0):
    env, n = evaluation_env(make_pusht_env, seeds, noise_dim=4, noise_seed=noise_seed,
                            max_steps=10)
    try:
        td = env.reset()
        rows = [td["prior_noise"].clone()]
        for _ in range(steps):
            td["action"] = torch.full((n, 2), 256.0)
            td = env.step(td)["next"]
            rows.append(td["prior_noise"].clone())
    finally:
        env.close()
    return torch.stack(rows, 1)  # (N, steps + 1, 4)


def test_prior_noise_is_a_function_of_the_env_seed_alone():
    together = _noise([11, 12, 13])
    alone = _noise([12])
    torch.testing.assert_close(together[1], alone[0], rtol=0, atol=0)
    assert not torch.equal(together[0], together[1])  # other seeds, other streams
    assert not torch.equal(_noise([12], noise_seed=1)[0], alone[0])  # the run offset counts
    assert not torch.equal(alone[0, 0], alone[0, 1])  # a new draw every step


def test_partial_reset_restarts_only_the_reset_envs_stream():
    env, _ = evaluation_env(make_pusht_env, [1, 2], noise_dim=3, max_steps=10)
    try:
        td = env.reset()
        td["action"] = torch.full((2, 2), 256.0)
        td = env.step(td)["next"]
        before = td["prior_noise"].clone()
        td["_reset"] = torch.tensor([[True], [False]])
        after = env.reset(td)["prior_noise"]
        fresh = env.reset()["prior_noise"]  # a full reset: both streams from the start
    finally:
        env.close()
    torch.testing.assert_close(after[1], before[1], rtol=0, atol=0)  # kept, not redrawn
    torch.testing.assert_close(after[0], fresh[0], rtol=0, atol=0)  # restarted


@pytest.mark.slow
def test_workers_split_the_seeds_and_padding_is_dropped():
    seeds = [100, 101, 102]
    env, n = evaluation_env(make_pusht_env, seeds, workers=2, noise_dim=4, max_steps=6)
    try:
        assert n == 3 and tuple(env.batch_size) == (2, 2)  # 2 workers x 2, one padding seed
        out = flatten_workers(env.rollout(3, break_when_any_done=False), n)
    finally:
        env.close()
    assert out.batch_size[0] == 3
    serial = _noise(seeds, steps=0)  # the noise of each seed identifies it: seed order kept
    torch.testing.assert_close(out["prior_noise"][:, 0], serial[:, 0], rtol=0, atol=0)
    with pytest.raises(ValueError, match="eval.workers"):
        evaluation_env(make_pusht_env, seeds, workers=0)


def test_prior_noise_needs_the_env_seed():
    from tensordict import TensorDict

    with pytest.raises(KeyError, match="seed"):
        PriorNoise(3)._reset(TensorDict({}, [2]), TensorDict({}, [2]))
