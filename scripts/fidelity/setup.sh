#!/usr/bin/env bash
# Create .venv-fidelity at the repo root with pinned mujoco + numpy (idempotent).
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)"
VENV="$ROOT/.venv-fidelity"
PY="${PYTHON:-python3}"
MUJOCO_VERSION=3.3.7
NUMPY_VERSION=2.2.6

if [ ! -x "$VENV/bin/python" ]; then
  "$PY" -m venv "$VENV"
fi
if "$VENV/bin/python" -c "import mujoco, numpy, sys; sys.exit(not (mujoco.__version__ == '$MUJOCO_VERSION' and numpy.__version__ == '$NUMPY_VERSION'))" 2>/dev/null; then
  echo "setup.sh: $VENV already has mujoco $MUJOCO_VERSION, numpy $NUMPY_VERSION"
  exit 0
fi
"$VENV/bin/python" -m pip install --quiet --disable-pip-version-check \
  "mujoco==$MUJOCO_VERSION" "numpy==$NUMPY_VERSION"
"$VENV/bin/python" -c "import mujoco, numpy; print('setup.sh: mujoco', mujoco.__version__, 'numpy', numpy.__version__)"
