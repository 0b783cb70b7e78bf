#!/usr/bin/env bash
# v11: the served (v9) DiT trained on the v11 prior's residual.
set -euo pipefail
cd /work/campaign/v11
WS=/work/main/.venv/bin/worldsplat
W=/work/main/models/weights
OUT=/work/campaign/v11/run_dit
export OMP_NUM_THREADS=2
$WS train-campaign dit --vae $W/vae_small.safetensors --out $OUT --steps ${DIT_STEPS:-600} --batch 2 --lr 3e-4 \
   --threads 2 --ckpt-every 100 --init $W/dit_small.safetensors --prior /work/campaign/v11/run/prior_v2.safetensors
echo DIT DONE
