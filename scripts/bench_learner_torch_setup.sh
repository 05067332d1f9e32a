#!/usr/bin/env bash
# Create .venv-bench-torch at the repo root with a pinned PyTorch (idempotent), for the PyTorch
# side of `asi bench learner` (scripts/bench_learner_torch.py).
#
# Only PyPI is reachable here, so this installs the default Linux wheel, which pulls the CUDA
# runtime packages (nvidia-*; about 5 GB in all with torch 2.15) although the bench runs on the CPU only. Set
# TORCH_VERSION to pin another version. Without this venv the bench skips the PyTorch side.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
VENV="$ROOT/.venv-bench-torch"
PY="${PYTHON:-python3}"
TORCH_VERSION="${TORCH_VERSION:-2.15.0}"
NUMPY_VERSION=2.2.6

if [ ! -x "$VENV/bin/python" ]; then
  "$PY" -m venv "$VENV"
fi
if "$VENV/bin/python" -c "import torch, numpy, sys; sys.exit(not torch.__version__.startswith('$TORCH_VERSION'))" 2>/dev/null; then
  echo "setup.sh: $VENV already has torch $TORCH_VERSION"
  exit 0
fi
"$VENV/bin/python" -m pip install --quiet --disable-pip-version-check "torch==$TORCH_VERSION" \
  "numpy==$NUMPY_VERSION"
"$VENV/bin/python" -c "import torch; print('setup.sh: torch', torch.__version__)"
