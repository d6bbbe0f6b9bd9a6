"""recipes/benchmarks/toy_modes.py's report: under its table, the T each case's solver reaches and,
when the cases run at different NFEs, that they are not compared with one another."""

from __future__ import annotations

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "recipes" / "benchmarks"))

import toy_modes  # noqa: E402


def test_the_caption_names_the_t_reached_by_every_case_and_refuses_cross_nfe_comparison():
    lines = toy_modes.caption(list(toy_modes.CASES)).splitlines()
    assert lines[0] == ("T = 1 asked: SRFMP at NFE 1 reaches T 0.40; RFMP at NFE 10 reaches "
                        "T 1.00; DDIM at NFE 10 reaches T 1.00.")
    assert lines[1].startswith("The cases run at different NFEs and are not compared")
    assert lines[1].endswith("(mean dist <= 0.05, both mode shares >= 0.3, sphere-norm error "
                             "<= 1e-5).")


def test_one_nfe_needs_no_warning():
    assert toy_modes.caption(["srfmp-pose"]) == "T = 1 asked: SRFMP at NFE 1 reaches T 0.40."
