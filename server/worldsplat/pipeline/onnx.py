"""ONNX export of the serving graphs and an onnxruntime runner, with parity and speed helpers.

Graphs (shapes of the trained geometry, batch 1 window of T frames x V views; the VAE's at any N, H, W, the DiT
step's and the layout prior's at any window of t frames: DYNAMIC_AXES):
    vae_encoder   image (N,3,H,W) in [-1,1]                         -> posterior mean (N,c,H/d,W/d), d its down-sampling
    vae_decoder   latent (N,c,h,w)                                  -> image (N,3,d h,d w)
    dit_step      z, s, box_corners, box_cls, box_moving, box_mask, traj, caption, control, drop -> velocity
    gs_decoder    L (1,T,V,C,h,w), intrinsics (1,T,V,4), cam_to_world (1,T,V,4,4) -> means, quats, scales,
                  opacities, colors, depth, dynamic_logit
    layout_prior  control (1,T,V,7,H,W), caption (1,384) -> mu (1,T,V,C,h,w)   (residual-DiT models only)
    gs_decoder_reconstruct   as gs_decoder, for reconstruct mode's own decoder where one is shipped
Parity tolerance (documented in web/docs/models.md): max |ORT - torch| <= 1e-3 (absolute) on every output at
float32, checked by tests/python/test_models_onnx.py; `speed_ratio` times both side by side.

The graphs are derived files, like web/pkg: `ensure_exported` writes <weights>/onnx from the committed fp16
safetensors and records the weights' version in onnx/VERSION, so set-up (`worldsplat export-onnx`, run by
package-config/setup.sh) and the onnx backend re-export only when the weights change. `compact` stores them at
about half the bytes of the traced float32 graphs and computes the same numbers (see its docstring).
"""

from __future__ import annotations

import logging
import os
import time
import warnings
from pathlib import Path

import numpy as np
import torch

from worldsplat.core.camera import default_rig
from worldsplat.core.io import atomic_path, atomic_write_bytes
from worldsplat.pipeline.conditions import rig_tensors

log = logging.getLogger(__name__)
PARITY_ATOL = 1e-3
# Bumped when the exported files change form (not the weights): ensure_exported re-exports a folder stamped otherwise.
EXPORT_REVISION = "compact-3"
GRAPHS = (
    "vae_encoder",
    "vae_decoder",
    "dit_step",
    "gs_decoder",
    "layout_prior",
    "gs_decoder_reconstruct",
)
# the Gaussian decoder graphs and the Models field each one exports
DECODER_GRAPHS = {"gs_decoder": "decoder", "gs_decoder_reconstruct": "decoder_reconstruct"}


class _Enc(torch.nn.Module):
    def __init__(self, vae):
        super().__init__()
        self.vae = vae

    def forward(self, image):
        return self.vae.encode(image)


class _Dec(torch.nn.Module):
    def __init__(self, vae):
        super().__init__()
        self.vae = vae

    def forward(self, latent):
        return self.vae.decode(latent)


class _DiTStep(torch.nn.Module):
    KEYS = ("box_corners", "box_cls", "box_moving", "box_mask", "traj", "caption", "control", "drop")

    def __init__(self, dit):
        super().__init__()
        self.dit = dit

    def forward(self, z, s, box_corners, box_cls, box_moving, box_mask, traj, caption, control, drop):
        cond = dict(
            box_corners=box_corners,
            box_cls=box_cls,
            box_moving=box_moving,
            box_mask=box_mask,
            traj=traj,
            caption=caption,
            control=control,
            drop=drop,
        )
        return self.dit(z, s, cond)


class _Prior(torch.nn.Module):
    def __init__(self, prior):
        super().__init__()
        self.prior = prior

    def forward(self, control, caption):
        return self.prior.clip(control, caption)


class _GSDec(torch.nn.Module):
    def __init__(self, dec, image_hw):
        super().__init__()
        self.dec, self.image_hw = dec, image_hw

    def forward(self, L, intrinsics, cam_to_world, guide=None):
        out = self.dec(L, intrinsics, cam_to_world, self.image_hw, guide=guide)
        return tuple(out[k] for k in OUT_KEYS)


OUT_KEYS = ("means", "quats", "scales", "opacities", "colors", "depth", "dynamic_logit")
_T = {1: "t"}
# The VAE is convolutional: any batch and image size (reconstruct runs it at the clip's own image). The DiT step and
# the layout prior take a window of any t <= T frames (generate's first window has 1 frame, a clip's last may be
# short). The Gaussian decoders stay at the exported shapes (their adaptive pooling needs a constant size): other
# shapes run in torch (`_Served`).
DYNAMIC_AXES = {
    "vae_encoder": {"image": {0: "n", 2: "H", 3: "W"}, "mean": {0: "n", 2: "h", 3: "w"}},
    "vae_decoder": {"latent": {0: "n", 2: "h", 3: "w"}, "image": {0: "n", 2: "H", 3: "W"}},
    "dit_step": {k: _T for k in ("z", "box_corners", "box_cls", "box_moving", "box_mask", "traj", "control")}
    | {"velocity": _T},
    "layout_prior": {"control": _T, "mu": _T},
}


def example_inputs(models, kind: str, seed: int = 0) -> dict[str, torch.Tensor]:
    """Representative inputs for graph `kind` at the models' trained geometry."""
    d = models.data
    g = torch.Generator().manual_seed(seed)
    T, V, H, W = d.frames, d.views, d.height, d.width
    ds = models.vae.cfg.downsample if models.vae is not None else 8
    h, w = H // ds, W // ds
    if kind == "vae_encoder":
        return {"image": torch.rand(2, 3, H, W, generator=g) * 2 - 1}
    if kind == "vae_decoder":
        vae = models.vae
        return {
            "latent": torch.randn(
                2, vae.cfg.latent_channels, H // vae.cfg.downsample, W // vae.cfg.downsample, generator=g
            )
        }
    if kind == "dit_step":
        c = models.dit.cfg
        N = d.max_boxes
        return {
            "z": torch.randn(1, T, V, c.in_channels, h, w, generator=g),
            "s": torch.tensor([0.4]),
            "box_corners": torch.randn(1, T, N, 8, 3, generator=g) * 10,
            "box_cls": torch.randint(0, d.num_classes, (1, T, N), generator=g),
            "box_moving": torch.rand(1, T, N, generator=g) > 0.5,
            "box_mask": torch.rand(1, T, N, generator=g) > 0.5,
            "traj": torch.eye(4).repeat(1, T, 1, 1),
            "caption": torch.nn.functional.normalize(torch.randn(1, 384, generator=g), dim=-1),
            "control": torch.rand(1, T, V, c.control_channels, H, W, generator=g)
            if c.control_hint
            else torch.randn(1, T, V, c.control_channels, h, w, generator=g),
            "drop": torch.tensor([False]),
        }
    if kind in DECODER_GRAPHS:
        dec = getattr(models, DECODER_GRAPHS[kind])
        rig = default_rig(W, H)[:V]
        ego = np.stack([np.eye(4)] * T)
        ego[:, 0, 3] = np.arange(T) * 2.0
        intr, c2w = rig_tensors(rig, ego, (H, W))
        out = {
            "L": torch.randn(1, T, V, dec.cfg.in_channels, h, w, generator=g),
            "intrinsics": intr[None],
            "cam_to_world": c2w[None],
        }
        if dec.cfg.guide_channels:
            out["guide"] = torch.rand(1, T, V, dec.cfg.guide_channels, H, W, generator=g) * 2 - 1
        return out
    if kind == "layout_prior":
        return {
            "control": torch.rand(1, T, V, models.prior.cfg.in_channels, H, W, generator=g),
            "caption": torch.nn.functional.normalize(torch.randn(1, 384, generator=g), dim=-1),
        }
    raise ValueError(f"unknown graph {kind!r}; expected one of {', '.join(GRAPHS)}")


def wrapper(models, kind: str) -> torch.nn.Module:
    d = models.data
    return {
        "vae_encoder": lambda: _Enc(models.vae),
        "vae_decoder": lambda: _Dec(models.vae),
        "dit_step": lambda: _DiTStep(models.dit),
        "gs_decoder": lambda: _GSDec(models.decoder, (d.height, d.width)),
        "layout_prior": lambda: _Prior(models.prior),
        "gs_decoder_reconstruct": lambda: _GSDec(models.decoder_reconstruct, (d.height, d.width)),
    }[kind]().eval()


def output_names(kind: str) -> list[str]:
    return {
        "vae_encoder": ["mean"],
        "vae_decoder": ["image"],
        "dit_step": ["velocity"],
        "gs_decoder": list(OUT_KEYS),
        "layout_prior": ["mu"],
        "gs_decoder_reconstruct": list(OUT_KEYS),
    }[kind]


def export(models, out_dir: str | Path, kinds=GRAPHS, compact_graphs: bool = True) -> dict[str, Path]:
    """Write <out_dir>/<kind>.onnx for each graph whose model is loaded (`compact`ed unless told not to)."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    loaded = set(needed_graphs(models))
    paths = {}
    for kind in kinds:
        if kind not in loaded:
            continue
        inputs = example_inputs(models, kind)
        path = out_dir / f"{kind}.onnx"
        with atomic_path(path, suffix=".onnx") as tmp, torch.no_grad(), warnings.catch_warnings():
            # the shape checks in the models' forward are constants at the fixed export shapes, as intended
            warnings.simplefilter("ignore", torch.jit.TracerWarning)
            dyn = DYNAMIC_AXES.get(kind)
            torch.onnx.export(
                wrapper(models, kind),
                tuple(inputs.values()),
                str(tmp),
                input_names=list(inputs),
                output_names=output_names(kind),
                opset_version=18,
                dynamo=False,
                dynamic_axes=dyn,
            )
        if compact_graphs:
            compact(path)
        paths[kind] = path
    return paths


def compact(path: str | Path, min_elements: int = 1024) -> dict:
    """Rewrite an exported graph in place so it stores fewer bytes and computes the same numbers:
    - a float32 initializer whose every value is exactly a float16 (all weights are: they come from the fp16
      safetensors) is stored as float16 behind a Cast to float32, which onnxruntime folds once when the session
      is created, so the graph runs in float32 on exactly the values it had;
    - a Constant tensor of one repeated value (the tracer bakes zeros / ones of the full activation shape: 7.6 MB in
      dit_step, 3.2 MB in gs_decoder) becomes a ConstantOfShape.
    Returns the counts and the file's bytes before and after (tests/python/test_onnx_backend.py checks the outputs)."""
    import onnx  # noqa: PLC0415 - only for the onnx backend
    from onnx import TensorProto, helper, numpy_helper  # noqa: PLC0415

    path = Path(path)
    before = path.stat().st_size
    m = onnx.load(str(path))
    g = m.graph
    inits, casts, n_half = [], [], 0
    for init in g.initializer:
        if init.data_type == TensorProto.FLOAT and int(np.prod(init.dims)) >= 16:
            w = numpy_helper.to_array(init)
            h = w.astype(np.float16)
            if np.array_equal(h.astype(np.float32), w):
                half = numpy_helper.from_array(h, init.name + "__fp16")
                inits.append(half)
                casts.append(helper.make_node("Cast", [half.name], [init.name], to=TensorProto.FLOAT))
                n_half += 1
                continue
        inits.append(init)
    nodes, n_fill = [], 0
    for node in g.node:
        t = next((a.t for a in node.attribute if a.name == "value"), None) if node.op_type == "Constant" else None
        if t is not None and int(np.prod(t.dims)) >= min_elements:
            a = numpy_helper.to_array(t)
            if a.size and np.all(a == a.flat[0]):
                shape = node.output[0] + "__shape"
                inits.append(numpy_helper.from_array(np.asarray(a.shape, np.int64), shape))
                value = numpy_helper.from_array(a.flat[:1].copy())
                nodes.append(helper.make_node("ConstantOfShape", [shape], list(node.output), value=value))
                n_fill += 1
                continue
        nodes.append(node)
    del g.initializer[:]
    g.initializer.extend(inits)
    del g.node[:]
    g.node.extend(casts + nodes)
    with atomic_path(path, suffix=".onnx") as tmp:
        onnx.save(m, str(tmp))
    return {
        "fp16_initializers": n_half,
        "filled_constants": n_fill,
        "bytes_before": before,
        "bytes": path.stat().st_size,
    }


# Appended to Models.version by `use_onnx`: the scene cache keys on the version (pipeline.scene.model_version) and
# onnxruntime's scenes equal torch's within float noise, not bit for bit (a Gaussian or two of ~250,000 fall on the
# other side of a threshold: web/docs/models.md, "ONNX serving"), so the two backends never share a cached scene.
ONNX_VERSION_SUFFIX = "-onnx"


def weights_version(models) -> str:
    """The weights' hash (Models.version without the onnx backend's suffix): what onnx/VERSION records."""
    return models.version.removesuffix(ONNX_VERSION_SUFFIX)


def ensure_exported(models, onnx_dir: str | Path | None = None) -> dict[str, Path]:
    """The serving graphs of `models` in onnx_dir (default <weights>/onnx), exported unless onnx/VERSION already
    names these weights' version (a half-written export leaves no VERSION, so it is redone)."""
    onnx_dir = Path(onnx_dir) if onnx_dir is not None else Path(models.weights_dir) / "onnx"
    stamp = onnx_dir / "VERSION"
    want = f"{weights_version(models)} {EXPORT_REVISION}"
    if stamp.exists() and stamp.read_text().strip() == want:
        return {k: onnx_dir / f"{k}.onnx" for k in GRAPHS if (onnx_dir / f"{k}.onnx").exists()}
    if models.version != weights_version(models):
        raise RuntimeError(
            f"{onnx_dir}: re-export from the torch models (load_models(backend='torch')), not served ones"
        )
    stamp.unlink(missing_ok=True)
    paths = export(models, onnx_dir)
    atomic_write_bytes(stamp, (want + "\n").encode())
    return paths


# --- which backend serves (inference.load_models) -------------------------------------------------------------------

BACKEND_ENV = "WORLDSPLAT_BACKEND"  # `worldsplat serve --backend` sets it for the server's load_models()
BACKENDS = ("auto", "onnx", "torch")


def requested_backend(backend: str | None = None) -> str:
    """`backend`, else $WORLDSPLAT_BACKEND, else "auto" (checked against BACKENDS)."""
    backend = backend or os.environ.get(BACKEND_ENV) or "auto"
    if backend not in BACKENDS:
        raise ValueError(f"backend must be one of {', '.join(BACKENDS)} (or ${BACKEND_ENV}), got {backend!r}")
    return backend


def needed_graphs(models) -> list[str]:
    """The graphs of the models that are loaded: what `export` writes and `use_onnx` serves."""
    have = {
        "vae_encoder": models.vae,
        "vae_decoder": models.vae,
        "dit_step": models.dit,
        "gs_decoder": models.decoder,
        "layout_prior": getattr(models, "prior", None),
        "gs_decoder_reconstruct": getattr(models, "decoder_reconstruct", None),
    }
    return [k for k in GRAPHS if have[k] is not None]


def graphs_state(models, onnx_dir: str | Path | None = None) -> str:
    """The graphs' state: "current" (onnx/VERSION names these weights and this EXPORT_REVISION, and every needed
    graph is there), "stale" (a VERSION of other weights or another revision, or a graph missing) or "missing" (no
    VERSION: never or half exported)."""
    onnx_dir = Path(onnx_dir) if onnx_dir is not None else Path(models.weights_dir) / "onnx"
    stamp = onnx_dir / "VERSION"
    if not stamp.exists():
        return "missing"
    if stamp.read_text().strip() != f"{weights_version(models)} {EXPORT_REVISION}":
        return "stale"
    return "current" if all((onnx_dir / f"{k}.onnx").exists() for k in needed_graphs(models)) else "stale"


def serving_backend(models, onnx_dir: str | Path | None = None) -> str:
    """load_models' "auto": "onnx" where the graphs are current, or stale and re-exported here (the weights changed
    since set-up); "torch" where they are missing (set-up's `worldsplat export-onnx` has not run), stale and not
    writable, or onnxruntime is not installed: then one log line (warning) says so."""
    onnx_dir = Path(onnx_dir) if onnx_dir is not None else Path(models.weights_dir) / "onnx"
    if not needed_graphs(models):
        return "torch"  # no weights: nothing to serve either way
    why = None
    try:
        import onnxruntime  # noqa: F401, PLC0415 - only for the onnx backend
    except ImportError:
        why = "onnxruntime is not installed"
    state = graphs_state(models, onnx_dir) if why is None else None
    if state == "missing":
        why = f"no graphs in {onnx_dir} (`worldsplat export-onnx` writes them)"
    elif state == "stale":
        try:
            ensure_exported(models, onnx_dir)
        except (OSError, ImportError) as e:  # a read-only install, or the onnx package missing
            why = f"the graphs in {onnx_dir} are not these weights' and could not be re-exported ({e})"
    if why is None:
        return "onnx"
    log.warning("worldsplat: serving the models with torch eager, not onnxruntime: %s", why)
    return "torch"


def session(path: str | Path, threads: int = 2):
    import onnxruntime as ort  # noqa: PLC0415 - only for the onnx backend

    so = ort.SessionOptions()
    so.intra_op_num_threads = threads
    so.inter_op_num_threads = 1
    if os.environ.get("OMP_WAIT_POLICY", "").upper() == "PASSIVE":
        # onnxruntime's own pool waits passively too where torch's does (`worldsplat serve` sets it): on 2 shared
        # cores a spinning thread starves its sibling (web/docs/playground.md, "Threads")
        so.add_session_config_entry("session.intra_op.allow_spinning", "0")
    return ort.InferenceSession(str(path), so, providers=["CPUExecutionProvider"])


def run_ort(sess, inputs: dict[str, torch.Tensor]) -> list[np.ndarray]:
    feed = {k: v.numpy() for k, v in inputs.items() if k in {i.name for i in sess.get_inputs()}}
    return sess.run(None, feed)


def run_torch(models, kind: str, inputs: dict[str, torch.Tensor]) -> list[np.ndarray]:
    with torch.no_grad():
        out = wrapper(models, kind)(*inputs.values())
    out = out if isinstance(out, tuple) else (out,)
    return [o.numpy() for o in out]


def parity(models, onnx_dir: str | Path, kind: str, seed: int = 0) -> float:
    """max |ORT - torch| over all outputs of graph `kind` for representative inputs."""
    inputs = example_inputs(models, kind, seed)
    a = run_torch(models, kind, inputs)
    b = run_ort(session(Path(onnx_dir) / f"{kind}.onnx"), inputs)
    return max(float(np.max(np.abs(x - y))) for x, y in zip(a, b))


def speed_ratio(models, onnx_dir: str | Path, kind: str, repeats: int = 5, threads: int = 2) -> dict:
    """Time torch eager and onnxruntime side by side (interleaved, best of `repeats`) on the same inputs.
    Returns {"torch_s", "ort_s", "ratio" (= torch_s / ort_s, > 1 means ORT is faster), "max_abs_diff"}."""
    torch.set_num_threads(threads)
    inputs = example_inputs(models, kind)
    sess = session(Path(onnx_dir) / f"{kind}.onnx", threads)
    mod = wrapper(models, kind)
    tt, to = [], []
    with torch.no_grad():
        mod(*inputs.values())
        run_ort(sess, inputs)
        for _ in range(repeats):
            t0 = time.perf_counter()
            mod(*inputs.values())
            tt.append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            run_ort(sess, inputs)
            to.append(time.perf_counter() - t0)
    a = run_torch(models, kind, inputs)
    b = run_ort(sess, inputs)
    diff = max(float(np.max(np.abs(x - y))) for x, y in zip(a, b))
    return {"graph": kind, "torch_s": min(tt), "ort_s": min(to), "ratio": min(tt) / min(to), "max_abs_diff": diff}


# --- serving with onnxruntime (inference.load_models(backend="onnx")) ------------------------------------------------


def fits(sess, feed: dict[str, torch.Tensor]) -> bool:
    """Whether every input of `feed` has the shape the graph was exported at (its fixed dimensions; the VAE's named
    dynamic ones match anything)."""
    shapes = {i.name: i.shape for i in sess.get_inputs()}
    for k, v in feed.items():
        want = shapes.get(k)
        if want is None:
            continue
        if len(want) != v.dim() or any(isinstance(w, int) and w != n for w, n in zip(want, v.shape)):
            return False
    return True


class _Served:
    """A graph served by onnxruntime at the shapes it was exported for (DYNAMIC_AXES) and by the torch module it was
    traced from at any other: the Gaussian decoders' graphs take one window of the trained T frames, so generate's
    first window of 1 frame and a clip's short last window decode in torch, as the torch backend does. `ort_calls`
    and `torch_calls` count which one ran."""

    def __init__(self, torch_module, sess):
        self.cfg, self.sess, self.torch = torch_module.cfg, sess, torch_module
        self.ort_calls = self.torch_calls = 0

    def _run(self, feed: dict[str, torch.Tensor]) -> list[torch.Tensor] | None:
        if not fits(self.sess, feed):
            self.torch_calls += 1
            return None
        self.ort_calls += 1
        return [torch.from_numpy(o) for o in run_ort(self.sess, feed)]


class OrtDiT(_Served):
    """Callable like DiT4D(z, s, cond), backed by dit_step.onnx (a window of any t <= T frames)."""

    def __call__(self, z, s, cond):
        return self.forward(z, s, cond)  # as a torch module calls its forward (a test may wrap it)

    def forward(self, z, s, cond):
        feed = {
            "z": z.float(),
            "s": s.float().reshape(1),
            **{k: cond[k] for k in _DiTStep.KEYS if k != "drop"},
            "drop": cond.get("drop", torch.tensor([False])),
        }
        out = self._run(feed)
        return out[0] if out is not None else self.torch(z, s, cond)


class OrtPrior(_Served):
    """Callable like LayoutPrior.clip(control, caption), backed by layout_prior.onnx (a window of any t <= T frames)."""

    def clip(self, control, caption):
        out = self._run({"control": control.float(), "caption": caption.float()})
        return out[0] if out is not None else self.torch.clip(control, caption)


class OrtGSDecoder(_Served):
    """Callable like GaussianDecoder(L, intrinsics, cam_to_world, image_hw), backed by gs_decoder.onnx for a window
    of T frames at the trained image."""

    def __init__(self, torch_dec, sess, image_hw: tuple[int, int]):
        super().__init__(torch_dec, sess)
        self.image_hw = tuple(image_hw)

    def __call__(self, L, intrinsics, cam_to_world, image_hw, guide=None):
        return self.forward(L, intrinsics, cam_to_world, image_hw, guide=guide)

    def forward(self, L, intrinsics, cam_to_world, image_hw, guide=None):
        feed = {"L": L.float(), "intrinsics": intrinsics.float(), "cam_to_world": cam_to_world.float()}
        if guide is not None:
            feed["guide"] = guide.float()
        out = self._run(feed) if tuple(image_hw) == self.image_hw else None
        if out is None:
            if tuple(image_hw) != self.image_hw:
                self.torch_calls += 1
            return self.torch(L, intrinsics, cam_to_world, image_hw, guide=guide)
        return dict(zip(OUT_KEYS, out))


def use_onnx(models, onnx_dir: str | Path, threads: int | None = None):
    """Swap the VAE's encode/decode, the DiT step, the Gaussian decoders and the layout prior of `models` for
    onnxruntime sessions (in place; the torch modules keep their configs and latent statistics and run the shapes
    the graphs were not exported at). threads: each session's intra-op threads (default torch's own,
    `torch.get_num_threads()`, so OMP_NUM_THREADS / torch.set_num_threads set both backends). Models.version gets
    ONNX_VERSION_SUFFIX (the scene cache keeps the backends apart). Returns models."""
    onnx_dir = Path(onnx_dir)
    threads = threads or torch.get_num_threads()
    if models.vae is not None:
        enc, dec = session(onnx_dir / "vae_encoder.onnx", threads), session(onnx_dir / "vae_decoder.onnx", threads)
        models.vae.encode = lambda x: torch.from_numpy(run_ort(enc, {"image": x.float()})[0])
        models.vae.decode = lambda z: torch.from_numpy(run_ort(dec, {"latent": z.float()})[0])
    if models.dit is not None:
        models.dit = OrtDiT(models.dit, session(onnx_dir / "dit_step.onnx", threads))
    d = models.data
    for kind, role in DECODER_GRAPHS.items():
        if getattr(models, role, None) is not None:
            sess = session(onnx_dir / f"{kind}.onnx", threads)
            setattr(models, role, OrtGSDecoder(getattr(models, role), sess, (d.height, d.width)))
    if getattr(models, "prior", None) is not None:
        models.prior = OrtPrior(models.prior, session(onnx_dir / "layout_prior.onnx", threads))
    models.version = weights_version(models) + ONNX_VERSION_SUFFIX
    return models
