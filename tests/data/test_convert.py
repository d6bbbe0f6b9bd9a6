"""`rfmp-convert`: a flag the chosen format does not read is refused, not ignored."""

from __future__ import annotations

import pytest

from rfmp_rl.data.convert import main, read_source


@pytest.mark.parametrize("fmt, flag, value", [
    ("lasa", "--keys", "pos"),
    ("lasa", "--config", "topics.yaml"),
    ("lasa", "--filter", "train"),
    ("lasa", "--rate", "5"),
    ("lasa", "--episodes", "0"),
    ("ros", "--keys", "joints"),
    ("ros", "--filter", "train"),
    ("lerobot", "--config", "topics.yaml"),
    ("lerobot", "--filter", "train"),
    ("dp_zarr", "--filter", "train"),
    ("minari", "--config", "topics.yaml"),
    ("robomimic", "--config", "topics.yaml"),
])
def test_a_flag_the_format_does_not_read_is_refused(fmt, flag, value, capsys):
    source = "LShape" if fmt == "lasa" else "no/such/source"
    assert main([fmt, source, flag, value, "--dry-run"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("rfmp-convert: error:") and flag in err and fmt in err


def test_read_source_refuses_unread_options():
    with pytest.raises(ValueError, match="--config"):
        read_source("lasa", "LShape", config="topics.yaml")
    with pytest.raises(ValueError, match="--keys"):
        read_source("ros", "bags", keys=["joints"], config="topics.yaml")
