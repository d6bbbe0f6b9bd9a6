"""Shared fixtures: small policy configs that build in milliseconds, and the export command line
run in the test process (`to_onnx_cli`)."""

from __future__ import annotations

import contextlib
import importlib.util
import io
from pathlib import Path
from types import SimpleNamespace

import pytest
import torch

from rfmp_rl.modules import ModelConfig, build_model

TO_ONNX = Path(__file__).resolve().parents[1] / "export" / "to_onnx.py"


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


@pytest.fixture(scope="session")
def to_onnx_cli():
    """``to_onnx_cli(*args)`` -> ``returncode``, ``stdout``, ``stderr`` of ``export/to_onnx.py
    args``: its ``main`` in this process, output captured (an argparse usage error gives its exit
    code, 2), without a new interpreter importing torch for every call (a few seconds each).
    The script itself runs as a subprocess in tests/export/test_to_onnx.py."""
    spec = importlib.util.spec_from_file_location("to_onnx_script", TO_ONNX)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)

    def run(*args) -> SimpleNamespace:
        out, err = io.StringIO(), io.StringIO()
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            try:
                code = module.main([str(a) for a in args])
            except SystemExit as exit_:
                code = exit_.code
        return SimpleNamespace(returncode=code, stdout=out.getvalue(), stderr=err.getvalue())

    return run
