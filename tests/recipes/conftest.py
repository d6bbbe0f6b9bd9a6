"""Shared fixtures of the recipe smoke tests."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

HERE = str(Path(__file__).resolve().parent)
if HERE not in sys.path:  # `from recipe_loader import ...` in the tests
    sys.path.insert(0, HERE)


@pytest.fixture(autouse=True)
def _restore_threads():
    """The recipes set torch's thread count from their config; leave it as it was."""
    import torch

    threads = torch.get_num_threads()
    yield
    torch.set_num_threads(threads)
