"""Shared fixtures: small policy configs that build in milliseconds."""

from __future__ import annotations

import pytest
import torch

from rfmp_rl.modules import ModelConfig, build_model


def tiny_config(
    algorithm: str = "srfmp", manifold: str = "S2", obs_dim: int = 3, horizon: int = 4, **kw
) -> ModelConfig:
    return ModelConfig(
        algorithm=algorithm,
        action_manifold=manifold,
        obs_dim=obs_dim,
        horizon=horizon,
        action_steps=max(1, horizon // 2),
        down_dims=[16, 32],
        time_embed_dim=32,
        tau_hidden_dim=32,
        **kw,
    )


@pytest.fixture
def make_tiny_model():
    def make(*args, **kw):
        torch.manual_seed(0)
        return build_model(tiny_config(*args, **kw))

    return make
