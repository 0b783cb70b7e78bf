"""v13: refinement at the playground size (default preset, 200x112, 4 frames, 6 cameras) for the oracle and the decoder
scene at +2 / +4 m: raw, full output, holes, the up-sampled mix and the detail-preserving mix (the served one, as
`pixel_mix.mix` makes it) against the exact view (refinement.md "v13 pixel mix"). Run from the repository root.
Usage: python display_size.py"""
import torch, numpy as np, torch.nn.functional as F
import worldsplat_models.conditions as cond
from worldsplat.core.scenario import default_scenario
from worldsplat.core.metrics import psnr
from worldsplat.pipeline.inference import load_models, reconstruct, to_scene4d
from worldsplat.pipeline.refine import load_refiner, refine_track, WEIGHTS
from worldsplat.pipeline.render import render_scene_track
from worldsplat.pipeline.scene import oracle_scene
from worldsplat.world import build_world, simulate
from worldsplat_models.enhancer import finish, _resize
from worldsplat_models.pixel_mix import mix_gate
cond.encode_captions = lambda caps: torch.zeros(len(caps), 384)
model, _ = load_refiner(str(WEIGHTS))
sc = default_scenario().with_updates(clip={"frames": 4})
world = build_world(sc)
src = simulate(world, 0.0)
meta = {"scenario": sc.model_dump(mode="json")}
def t(x):
    H, W = x.shape[-3:-1]
    return torch.from_numpy(np.ascontiguousarray(x)).float().reshape(-1, H, W, 3).permute(0, 3, 1, 2)
for name, scene in (("oracle", oracle_scene(src, meta)), ("decoder", to_scene4d(reconstruct(src, load_models()), meta))):
    for s in (2.0, 4.0):
        low = render_scene_track(scene, s, size=(112, 64))
        full = render_scene_track(scene, s)
        E = refine_track(scene, s, blend="none", render=low)
        truth = simulate(world, s).rgb
        T, V, H, W, _ = truth.shape
        g = lambda x: psnr(x.reshape(-1, H, W, 3), truth.reshape(-1, H, W, 3))
        holes = finish(E, full.rgb, full.alpha, "holes")
        gate_full = mix_gate(model.mix, low.rgb, E, low.alpha)  # the up-sampled mix (the alternative)
        gu = torch.from_numpy(gate_full).reshape(-1, 1, 64, 112)
        gu = F.interpolate(gu, (H, W), mode="bilinear", align_corners=False).numpy().reshape(T, V, H, W)
        wu = (np.clip(full.alpha, 0, 1) * gu)[..., None]
        E_up = finish(E, full.rgb, full.alpha, "none")
        mixed = np.round(wu * full.rgb + (1 - wu) * E_up).astype(np.uint8)
        served = finish(E, full.rgb, full.alpha, "mix", model.mix, (low.rgb, low.alpha))
        # detail-preserving: the mix at the model image, up-sampled, plus the render's detail above that band
        gate = mix_gate(model.mix, low.rgb, E, low.alpha)
        w = (np.clip(low.alpha, 0, 1) * gate)[..., None]
        out_low = w * low.rgb + (1 - w) * E
        up = lambda x: _resize(t(x), (H, W), "bilinear").permute(0, 2, 3, 1).numpy().reshape(T, V, H, W, 3)
        detail = full.rgb.astype(np.float32) - up(low.rgb.astype(np.float32))
        a = np.clip(full.alpha, 0, 1)[..., None]
        dp = np.clip(np.round(up(out_low) + a * detail), 0, 255).astype(np.uint8)
        print(name, s, "raw", round(g(full.rgb), 3), "none", round(g(finish(E, full.rgb, full.alpha, "none")), 3), "holes", round(g(holes), 3), "mix", round(g(mixed), 3), "detail-mix", round(g(dp), 3), "served", round(g(served), 3), flush=True)
        if name == "oracle" and s == 4.0:
            from PIL import Image
            rows = [np.concatenate([x[2, v] for x in (full.rgb, holes, mixed, dp, truth)], 1) for v in (0, 1)]
            Image.fromarray(np.concatenate(rows, 0)).resize((5 * W * 2, 2 * H * 2), Image.NEAREST).save("mixcmp.png")
