#!/bin/sh
# On the lent machine (the device tool's `run`, from the repository root, `.whl` carried; its python3 holds torch
# with CUDA): install the carried wheels beside the image's packages, then the one budgeted run into $OUT.
# Written by package-config/accelerator-wheels.sh here first. MINUTES (default 8.5) is the training run's own budget:
# with the pip install and the start of Python before it the whole command stays under 9 minutes.
set -eu
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl
export PYTHONPATH=/tmp/site:$PWD/server:$PWD/models
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader || true
exec python3 -m worldsplat.cli train-accelerator --out "$OUT" --minutes "${MINUTES:-8.5}" --captions .whl/captions.pt \
  --work /tmp/worldsplat-accelerator "$@"
