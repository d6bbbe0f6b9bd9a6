#!/usr/bin/env bash
# The test command: sets up .venv when missing, checks style, then runs the suite.
#   bash tests/run.sh [pytest args]
set -euo pipefail
HERE="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
exec bash "$HERE/../recipes/venv.sh" bash -c 'ruff check . && python -m pytest tests --durations=12 "$@"' _ "$@"
