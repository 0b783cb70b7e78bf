"""`worldsplat render SCENE.wsplat|SCENE.ply --shift-m M [--camera NAME|all] [--frame T] [--camera-json CAM.json]
--out DIR|FILE.png|FILE.mp4|FILE.webm`

- FILE.png: one image of frame T (default 0): the camera NAME (default CAM_FRONT), or a 2x3 mosaic for `all`,
  or the camera of `--camera-json` (the shared camera JSON; `--shift-m` does not apply to it).
- FILE.mp4 / FILE.webm: every frame (or just T) as a video at the scene's fps; a mosaic for `--camera all`.
- DIR: one PNG per frame and camera, `DIR/<frame:03d>_<camera>.png`.
- `--refine`: the enhanced diffusion model repairs the shifted-track render (`worldsplat.pipeline.refine`); needs
  the shipped enhancer and the scene's scenario (in the .wsplat header of `worldsplat generate`, or `--scenario`).
Every image comes from the one track renderer (`worldsplat.pipeline.render`, built on `gaussians.raster.render_view`).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np


def configure(p: argparse.ArgumentParser) -> None:
    p.add_argument("scene", help="a .wsplat, or a .ply / .glb / .spz / .sog / .splat (one frame)")
    p.add_argument("--shift-m", type=float, default=0.0, help="lateral track shift in metres (left positive)")
    p.add_argument("--camera", default=None, help="rig camera name or 'all' (default CAM_FRONT; 'all' for DIR)")
    p.add_argument("--frame", type=int, default=None, help="frame index (default: 0 for PNG, all for video/DIR)")
    p.add_argument("--camera-json", default=None, help="render at this camera (web/docs/conventions.md)")
    p.add_argument("--out", required=True, help="DIR, FILE.png, FILE.mp4 or FILE.webm")
    p.add_argument("--refine", action="store_true", help="refine the render with the enhanced diffusion model")
    p.add_argument(
        "--steps", type=int, default=None, help="--refine: rectified-flow sampler steps (default: the model's own)"
    )
    p.add_argument(
        "--scenario",
        default=None,
        help="--refine: the scene's scenario (JSON file or preset) when the scene does not carry it",
    )


def load_scene(path: str | Path):
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"scene {path} not found")
    if path.suffix.lower() in (".ply", ".glb", ".spz", ".sog", ".splat"):
        from worldsplat.gaussians.formats import scene_from_file

        return scene_from_file(path)
    from worldsplat.gaussians import wsplat

    return wsplat.read(path)


def save_png(img: np.ndarray, path: Path) -> None:
    from PIL import Image

    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(img).save(path)


def run(args) -> int:
    from worldsplat.core.camera import Camera
    from worldsplat.core.limits import check_shift
    from worldsplat.core.video import mosaic, write_video
    from worldsplat.gaussians.raster import render_view
    from worldsplat.pipeline.render import render_track

    scene = load_scene(args.scene)
    out = Path(args.out)
    kind = out.suffix.lower() if out.suffix.lower() in (".png", ".mp4", ".webm") else "dir"
    if args.frame is not None and not 0 <= args.frame < scene.num_frames:
        raise ValueError(f"--frame {args.frame} out of range 0..{scene.num_frames - 1}")
    args.shift_m = check_shift(args.shift_m, "--shift-m")
    if args.camera_json:
        if args.refine:
            raise ValueError("--refine repairs rig tracks; it does not apply to --camera-json")
        if kind not in (".png", "dir"):
            raise ValueError("--camera-json renders one image: use --out FILE.png or DIR")
        cam = Camera.from_json(args.camera_json)
        t = args.frame or 0
        img = render_view(scene.at_frame(t), cam).rgb
        dest = out if kind == ".png" else out / f"{t:03d}_camera_json.png"
        save_png(img, dest)
        print(f"wrote {dest}")
        return 0
    names = [c.name for c in scene.rig]
    cam = args.camera or ("all" if kind == "dir" else "CAM_FRONT" if "CAM_FRONT" in names else names[0])
    cameras = names if cam == "all" else [cam]
    if cam != "all" and cam not in names:
        raise ValueError(f"unknown camera {cam!r}; the scene's rig has {', '.join(names)} (or 'all')")
    if kind == ".png":
        frames = [args.frame or 0]
    else:
        frames = list(range(scene.num_frames)) if args.frame is None else [args.frame]
    if args.refine:
        from worldsplat.pipeline.refine import refine_available, refine_track

        if not refine_available():
            raise FileNotFoundError("--refine needs the enhancer weights (models/weights/enhancer_small.safetensors)")
        scenario = None
        if args.scenario:
            from worldsplat.core.scenario import resolve_scenario

            scenario = resolve_scenario(args.scenario)
        report = lambda stage, f: print(f"refine: {stage} {100 * f:.0f}%", flush=True)  # noqa: E731
        views = refine_track(scene, args.shift_m, cameras, steps=args.steps, scenario=scenario, progress=report)
        views = views[frames]
    else:
        views = render_track(scene, args.shift_m, cameras, frames=frames)  # (T,V,H,W,3)
    if kind == "dir":
        for i, t in enumerate(frames):
            for j, c in enumerate(cameras):
                save_png(views[i, j], out / f"{t:03d}_{c}.png")
        print(f"wrote {len(frames) * len(cameras)} PNGs to {out}")
        return 0
    seq = mosaic(views, cameras)
    if kind == ".png":
        save_png(seq[0], out)
    else:
        write_video(seq, out, fps=scene.fps)
    print(
        f"wrote {out} ({len(frames)} frame(s), {'mosaic' if len(cameras) > 1 else cameras[0]}, "
        f"shift {args.shift_m:+g} m{', refined' if args.refine else ''})"
    )
    return 0
