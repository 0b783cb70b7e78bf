#!/bin/sh
# On the lent machine (the device tool's `run`, from the repository root, `.whl` carried; its python3 holds torch
# with CUDA): install the carried wheels beside the image's packages, then `worldsplat train-stack` within MINUTES
# (default 7.5, so that the install, the start of Python and the packing stay inside a 10-minute budget) into a run
# folder outside the tree. What comes back in $OUT: MODEL_CARD.md, card.json and the run's weights, cards, stage
# states and logs as stack.tar.NN parts of at most 16 MB (here: `cat stack.tar.* | tar -x -C DIR`).
# Written by package-config/accelerator-wheels.sh here first. SIZE: large (default: the served widths at a GPU's
# batches), small or tiny.
set -u
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl
export PYTHONPATH=/tmp/site:$PWD/server:$PWD/models
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader || true
RUN=/tmp/worldsplat-stack
python3 -m worldsplat.cli train-stack --run-dir "$RUN" --size "${SIZE:-large}" --minutes "${MINUTES:-7.5}" \
  --captions .whl/captions.pt "$@"
rc=$?
cp "$RUN/MODEL_CARD.md" "$RUN/card.json" "$OUT/" 2>/dev/null
(cd "$RUN" && tar -cf - weights cards ./*.state.json ./*.log.jsonl 2>/dev/null) | split -b 16000000 -d - "$OUT/stack.tar."
exit $rc
