"""A toy training problem shared by the engine tests and the torchrun worker they launch:
a tiny SRFMP policy on S^2 and fixed batches that carry their own prior noise and flow times,
so a loss is a deterministic function of its batch (one process at batch B and two ranks at
B/2 each then see exactly the same samples and noise)."""

from __future__ import annotations

import torch
from tensordict import TensorDict

from rfmp_rl.data import DemonstrationStore
from rfmp_rl.modules import ModelConfig, build_model

HORIZON = 4


def tiny_model(algorithm: str = "srfmp", seed: int = 0, dtype: torch.dtype = torch.float32):
    torch.manual_seed(seed)
    model = build_model(ModelConfig(algorithm, "S2", obs_dim=3, horizon=HORIZON, action_steps=2,
                                    down_dims=[16, 32], time_embed_dim=32, tau_hidden_dim=32))
    model.action_normalizer.set_stats(-torch.ones(3), torch.ones(3))
    model.obs_normalizer.set_stats(-2 * torch.ones(3), 2 * torch.ones(3))
    return model.to(dtype)


def fixed_batches(model, steps: int, batch: int, seed: int = 1,
                  dtype: torch.dtype = torch.float32) -> list[TensorDict]:
    """``steps`` batches of ``batch`` samples with ``prior_noise`` and ``flow_time``."""
    g = torch.Generator().manual_seed(seed)
    out = []
    for _ in range(steps):
        action = torch.nn.functional.normalize(torch.randn(batch, HORIZON, 3, generator=g), dim=-1)
        out.append(TensorDict({
            "observation": torch.randn(batch, 2, 3, generator=g),
            "action": action,
            "prior_noise": torch.randn(batch, model.noise_dim, generator=g),
            "flow_time": torch.rand(batch, 1, generator=g),
        }, [batch]).to(dtype))
    return out


class BatchList:
    """``sample()`` returns the next fixed batch, or this rank's share of it."""

    def __init__(self, batches, rank: int = 0, world_size: int = 1) -> None:
        self.batches, self.i = batches, 0
        self.rank, self.world_size = rank, world_size

    def sample(self) -> TensorDict:
        full = self.batches[self.i % len(self.batches)]
        self.i += 1
        share = full.shape[0] // self.world_size
        return full[self.rank * share:(self.rank + 1) * share]


def toy_store(seed: int = 0) -> DemonstrationStore:
    """Episodes moving along great circles of S^2: observation x_t, action x_{t+1} (learnable:
    the observation window gives the direction)."""
    g = torch.Generator().manual_seed(seed)
    episodes = []
    for n in (30, 22, 26):
        e1, e2 = torch.linalg.qr(torch.randn(3, 2, generator=g))[0].T  # orthonormal
        t = 0.1 * torch.arange(n + 1, dtype=torch.float32)[:, None]
        x = torch.cos(t) * e1 + torch.sin(t) * e2  # (n + 1, 3) on S^2
        episodes.append(TensorDict({"observation": x[:-1], "action": x[1:]}, [n]))
    return DemonstrationStore.from_episodes(episodes)


def replay_buffer(store: DemonstrationStore, seed: int, batch: int = 16):
    return store.replay_buffer(HORIZON, ["observation"], batch_size=batch,
                               generator=torch.Generator().manual_seed(seed))
