"""v12: an enhancer checkpoint of train_dec.py as a weight file (for evaluating a run midway).
Usage: python ckpt_to_weights.py CKPT OUT.safetensors"""
import sys

import torch

from worldsplat_models.enhancer import load_enhancer, save_enhancer
from worldsplat_models.weights import weights_dir

model, vae = load_enhancer(weights_dir() / "enhancer_small.safetensors")
state = torch.load(sys.argv[1], map_location="cpu", weights_only=False)
model.load_state_dict(state["model"])
save_enhancer(model, vae, sys.argv[2], {"provenance": {"step": int(state["step"])}})
print("step", state["step"])
