"""Shared set-up of the data tests."""

from __future__ import annotations

import sys
from pathlib import Path

HERE = str(Path(__file__).resolve().parent)
if HERE not in sys.path:  # `from lerobot_fixture import ...` in the tests
    sys.path.insert(0, HERE)
