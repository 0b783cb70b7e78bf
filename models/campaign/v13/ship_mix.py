"""v13: bundle the pixel mix fitted by `train_mix.py` into the served enhancer file and re-write the model card.
The enhancer's tensors are unchanged; the mix travels in it (tensors `mix.*`, config field `pixel_mix`) with its
provenance under provenance["pixel_mix"].
Usage: python ship_mix.py MIX.safetensors WEIGHTS_DIR
"""
import json
import sys
from pathlib import Path

from safetensors import safe_open

from worldsplat.training.enhancer import write_model_card
from worldsplat_models.enhancer import load_enhancer, save_enhancer
from worldsplat_models.pixel_mix import PixelMix, PixelMixConfig

mix_file, wdir = Path(sys.argv[1]), Path(sys.argv[2])
with safe_open(str(mix_file), framework="pt") as f:
    md = f.metadata()
    tensors = {k: f.get_tensor(k) for k in f.keys()}
cfg = json.loads(md["config"])
net = PixelMix(PixelMixConfig(**{**cfg, "dilations": tuple(cfg["dilations"])}))
net.load_state_dict(tensors)
model, vae = load_enhancer(wdir / "enhancer_small.safetensors")
model.attach_mix(net.eval())
prov = dict(model.meta["provenance"])
mp = json.loads(md["provenance"])
mp.pop("history", None)
prov["pixel_mix"] = {
    **mp,
    "params": sum(p.numel() for p in net.parameters()),
    "data": "val-split clips 6-85 (seeds 1000006-1000085) at (+1, -3) / (-2, +4) m: the served decoder's scene "
    "rendered on the shifted track, this enhancer's full output, the exact view; selected on val clips 0-5 at 2 / 4 m",
    "command": "python models/campaign/v13/make_mix_data.py CACHE val 6 80 alt; python models/campaign/v13/make_mix_data.py "
    "CACHE val 0 6 2,4; python models/campaign/v13/train_mix.py CACHE 3000 MIX",
}
save_enhancer(model, vae, wdir / "enhancer_small.safetensors", {"provenance": prov})
print(write_model_card(wdir))
