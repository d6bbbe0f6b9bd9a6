"""Every docstring example in the recipes runs and prints what it claims (the library's own:
tests/test_docstrings.py)."""

from __future__ import annotations

import doctest
import importlib

import pytest
from recipe_loader import ROOT

MODULES = ["recipes.common", "recipes.expert_demos", "recipes.paper", "recipes.paper_comparison",
           "recipes.robosuite.experts", "toy_modes", "training_throughput", "gpu_check"]


@pytest.mark.parametrize("name", MODULES)
def test_recipe_docstring_examples(name, tmp_path, monkeypatch):
    # the benchmark scripts import one another as scripts do, from their folder
    monkeypatch.syspath_prepend(str(ROOT / "recipes" / "benchmarks"))
    monkeypatch.chdir(tmp_path)
    module = importlib.import_module(name)
    result = doctest.testmod(module, optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE,
                             verbose=False)
    assert result.attempted > 0, f"{name} has no docstring examples"
    assert result.failed == 0, f"{result.failed} docstring example(s) failed in {name}"
