"""Shared set-up of the engine tests."""

from __future__ import annotations

import sys
from pathlib import Path

HERE = str(Path(__file__).resolve().parent)
if HERE not in sys.path:  # `from toy import ...` in the tests
    sys.path.insert(0, HERE)
