"""Every docstring example in rfmp_deploy runs (against a toy ``policy.onnx``) and prints what it
claims; the examples' metadata is the toy model's."""

from __future__ import annotations

import doctest
import importlib
import pkgutil

import numpy as np
import pytest
import rfmp_deploy
from rfmp_deploy.metadata import example_metadata
from toy_policy import example_spec, toy_metadata, write_model

MODULES = ["rfmp_deploy"] + sorted(
    m.name for m in pkgutil.iter_modules(rfmp_deploy.__path__, prefix="rfmp_deploy.")
    if m.name not in ("rfmp_deploy.__main__",)
)


def test_example_metadata_matches_the_toy_model():
    assert toy_metadata(example_spec()) == example_metadata()


@pytest.mark.parametrize("name", MODULES)
def test_docstring_examples(name, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    write_model(tmp_path / "policy.onnx", example_spec())
    module = importlib.import_module(name)
    result = doctest.testmod(
        module,
        extraglobs={"np": np},
        optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE,
        verbose=False,
    )
    assert result.failed == 0, f"{result.failed} docstring example(s) failed in {name}"
