"""Fixtures for the robot-side package: `rfmp_deploy` from ``deploy/`` and tiny ONNX policies."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

HERE = Path(__file__).resolve().parent
DEPLOY = HERE.parents[1] / "deploy"
for entry in (str(DEPLOY), str(HERE)):  # `import rfmp_deploy`, `import toy_policy`
    if entry not in sys.path:
        sys.path.insert(0, entry)

from toy_policy import ToySpec, write_model  # noqa: E402


@pytest.fixture
def make_model(tmp_path):
    """``make_model(spec=None, name="policy.onnx", **write_model kwargs) -> Path``."""
    counter = iter(range(1_000_000))

    def make(spec: ToySpec | None = None, name: str | None = None, **kw) -> Path:
        return write_model(tmp_path / (name or f"policy_{next(counter)}.onnx"), spec, **kw)

    return make


@pytest.fixture
def make_policy(make_model):
    """``make_policy(spec=None, **kw) -> rfmp_deploy.Policy`` over a toy model."""
    from rfmp_deploy import Policy

    def make(spec: ToySpec | None = None, **kw):
        return Policy(make_model(spec, **kw))

    return make
