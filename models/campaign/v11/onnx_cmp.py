import time, numpy as np, torch
from worldsplat.pipeline import onnx as ox
from worldsplat.pipeline.inference import load_models
m = load_models()
for kind in ("vae_encoder", "vae_decoder", "dit_step", "gs_decoder", "layout_prior"):
    inp = ox.example_inputs(m, kind, 3)
    a, b = ox.session(f"/tmp/onnx_old/{kind}.onnx", 2), ox.session(f"models/weights/onnx/{kind}.onnx", 2)
    ya, yb = ox.run_ort(a, inp), ox.run_ort(b, inp)
    d = max(float(np.max(np.abs(x - y))) for x, y in zip(ya, yb))
    ta, tb = [], []
    for _ in range(15):
        t0 = time.perf_counter(); ox.run_ort(a, inp); ta.append(time.perf_counter() - t0)
        t0 = time.perf_counter(); ox.run_ort(b, inp); tb.append(time.perf_counter() - t0)
    print(f"{kind}: max|compact - traced| {d:.3g}  parity vs torch {ox.parity(m, 'models/weights/onnx', kind, 3):.3g}  time compact/traced {min(tb)/min(ta):.3f} ({min(tb)*1e3:.1f} / {min(ta)*1e3:.1f} ms)")
