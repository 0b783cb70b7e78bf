#!/bin/sh
# Here, before a device run of `worldsplat train-stack` (web/docs/training.md "On a lent GPU"), from the
# repository root: what the lent H200 lacks, into .whl/ (ignored; carried by the call).
#   1. The pure-Python dependencies of the path the run imports (worldsplat.core.scenario needs pydantic; torch,
#      numpy, tqdm, safetensors, pillow and matplotlib are in the machine's image, /work/.library/device/KINDS.md),
#      as cp312 manylinux wheels, pinned as in requirements.lock. pydantic 2.14 needs typing-extensions >= 4.16,
#      newer than the image may hold, so that travels too. About 2.5 MB together.
#   2. The caption table (.whl/captions.pt, about 1 MB): the sentence encoder's package is 88 MB, over the 64 MiB
#      that travels, so the embeddings of every clip of the size (and of its enhancer pairs) are computed here.
# Usage: sh package-config/accelerator-wheels.sh [SIZE]   (default large; a few minutes)
set -eu
SIZE=${1:-large}
grep -qx '/.whl/' .git/info/exclude 2>/dev/null || echo /.whl/ >> .git/info/exclude
mkdir -p .whl
PY=${PYTHON:-.venv/bin/python}
"$PY" -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
  --platform manylinux_2_28_x86_64 --platform manylinux_2_27_x86_64 --platform manylinux_2_17_x86_64 \
  --platform manylinux2014_x86_64 --platform manylinux1_x86_64 -d .whl \
  pydantic==2.14.3 pydantic_core==2.50.4 annotated-types==0.8.0 typing-inspection==0.4.5 typing_extensions==4.16.0
nice -n 10 .venv/bin/worldsplat train-stack --size "$SIZE" --write-captions .whl/captions.pt --workers 2
ls -la .whl
du -sh .whl
