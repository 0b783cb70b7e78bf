#!/usr/bin/env bash
# v11: the v9 layout prior trained on from its step-250 checkpoint (the cosine schedule of 1400 steps).
set -euo pipefail
cd /work/campaign/v11
WS=/work/main/.venv/bin/worldsplat
W=/work/main/models/weights
OUT=/work/campaign/v11/run
export OMP_NUM_THREADS=2
$WS train-campaign prior --vae $W/vae_small.safetensors --out $OUT --steps ${PRIOR_STEPS:-1400} --batch 16 --lr 5e-4 \
   --threads 2 --ckpt-every 50 --init $W/prior_small.safetensors
echo PRIOR DONE
