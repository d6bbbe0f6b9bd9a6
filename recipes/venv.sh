#!/usr/bin/env bash
# Create (or refresh) the project's .venv, then run the given command inside it.
#
#   bash recipes/venv.sh python -m pytest tests     # what tests/run.sh does
#
# Idempotent: the install runs only when .venv is missing or pyproject.toml changed since the
# last successful install (a hash stamp in .venv), so an up-to-date call costs well under a second.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
VENV="$ROOT/.venv"
STAMP="$VENV/.rfmp_rl-install-stamp"
PYTHON="${RFMP_PYTHON:-python3.11}"
command -v "$PYTHON" >/dev/null 2>&1 || PYTHON=python3

want="$(cat "$ROOT/pyproject.toml" "$ROOT/deploy/requirements.txt" | sha256sum | cut -d' ' -f1)"
have="$(cat "$STAMP" 2>/dev/null || true)"
if [[ ! -x "$VENV/bin/python" || "$want" != "$have" ]]; then
    echo "[rfmp_rl] setting up $VENV (first run takes several minutes) ..." >&2
    [[ -x "$VENV/bin/python" ]] || "$PYTHON" -m venv "$VENV"
    "$VENV/bin/python" -m pip install --quiet --upgrade pip >&2
    # torch/torchvision first, pinned, so nothing else drags in a different build.
    "$VENV/bin/python" -m pip install --quiet "torch==2.14.1" "torchvision==0.29.1" >&2
    "$VENV/bin/python" -m pip install --quiet -e "$ROOT[all]" >&2
    # robosuite prints warnings until its private macros file exists.
    "$VENV/bin/python" - <<'PY' >&2 || true
import importlib.util, pathlib, shutil
spec = importlib.util.find_spec("robosuite")
if spec is not None:
    root = pathlib.Path(spec.origin).parent
    src, dst = root / "macros.py", root / "macros_private.py"
    if src.exists() and not dst.exists():
        shutil.copy(src, dst)
PY
    echo "$want" > "$STAMP"
    echo "[rfmp_rl] environment ready." >&2
fi
export PATH="$VENV/bin:$PATH"
export VIRTUAL_ENV="$VENV"
export MUJOCO_GL="${MUJOCO_GL:-egl}"
cd "$ROOT"
exec "$@"
