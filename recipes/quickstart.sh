#!/usr/bin/env bash
# The main job: sets up .venv when missing, then runs recipes/quickstart.py (hydra overrides
# pass through, e.g. `bash recipes/quickstart.sh steps=300 shapes=[LShape]`).
set -euo pipefail
HERE="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
exec bash "$HERE/venv.sh" python "$HERE/quickstart.py" "$@"
