"""v12: ship the enhancer trained by `train_dec.py`: provenance in the fields the model card reads, held-out val
figures as `worldsplat train-enhancer` computes them, the card re-written.
Usage: python ship_enhancer.py TRAINED.safetensors PAIRS WEIGHTS_DIR STEPS WALL_S NOTE
"""
import sys
from pathlib import Path

from worldsplat.training.enhancer import complete_seeds, heldout_metrics, make_val_pairs, write_model_card
from worldsplat.training.pairs import load_sample
from worldsplat_models.enhancer import load_enhancer, save_enhancer

trained, pairs, wdir = Path(sys.argv[1]), Path(sys.argv[2]), Path(sys.argv[3])
steps, wall, note = int(sys.argv[4]), int(float(sys.argv[5])), sys.argv[6]
old, _ = load_enhancer(wdir / "enhancer_small.safetensors")
model, vae = load_enhancer(trained)
files = sorted((pairs / "train").glob("seed*.npz"))
seeds = complete_seeds(pairs, sorted({int(f.name[4:12]) for f in files}), True, 1)
names = {f.name for f in files if int(f.name[4:12]) in set(seeds)}
prov = dict(old.meta["provenance"])
prov.update(
    steps=prov["steps"] + steps,
    steps_target=prov["steps"] + steps,
    train_clips=len(seeds),
    train_seeds=f"{seeds[0]}-{seeds[-1]} ({len(seeds)} seeds)",
    degraded_pairs=sum(not n.endswith("_clean.npz") for n in names),
    decoder_pairs=sum(n.endswith("_dec.npz") for n in names),
    clean_pairs=sum(n.endswith("_clean.npz") for n in names),
    lr=float(model.meta["provenance"]["lr"]),
    seed=12,
    wall_s_this_run=wall,
    grow=True,
    command="python models/campaign/v12/train_dec.py PAIRS WORK 3000 2e-4 OUT (pairs: make_dec_pairs.py PAIRS 0 600)",
    note=note,
)
val = [load_sample(p) for p in make_val_pairs(pairs)]
prov["heldout_val"] = {"seeds": old.meta["provenance"]["heldout_val"]["seeds"], "shifts": [2.0, 4.0], **heldout_metrics(model, vae, val)}
save_enhancer(model, vae, wdir / "enhancer_small.safetensors", {"provenance": prov})
print(write_model_card(wdir))
