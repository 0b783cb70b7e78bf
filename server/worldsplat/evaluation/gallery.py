"""The gallery: what each mode makes of a scenario, next to the exact ground truth.

    worldsplat gallery [--weights DIR] [--data DATA --split test] [--random 4] [--presets a,b,c,d] [--frame 1]
                       [--steps 8] [--out web/docs/img/gallery]

One PNG per case (presets and random scenarios of a held-out split), columns the three front cameras
(CAM_FRONT_LEFT, CAM_FRONT, CAM_FRONT_RIGHT) at one frame, rows:

    ground truth      the world's exact render at the models' resolution
    VAE decode        the clip through the VAE (encode -> decode), the ceiling of every learned row below it
    reconstruct       reconstruct mode: ground-truth video -> VAE -> Gaussian decoder -> served scene, rendered
    layout map        what the generator was given: the per-camera layout maps, or the sketch for a sketch-control DiT
    generate          generate mode: conditions -> DiT (`steps` Euler steps, the scenario's seed) -> Gaussian
                      decoder -> served scene, rendered

Every rendered row is the scene the product serves: decoded frames aggregated by `to_scene4d` (paper eq. 3 +
economy, `gaussians.aggregate.aggregate_4d`) and drawn by the one track renderer (`pipeline.render.
render_scene_track`) at the rig camera. Preset cases are built as the server builds a generate scene
(`pipeline.scene.generate_scene`: `world.conditions` with the layout maps at the models' size, the scenario's seed),
with the world itself at the models' resolution; random cases are dataset clips (`world.dataset.clip_arrays` of a
split seed, or the shards of `--data`), the same clip either way.
Row labels carry the PSNR against the ground truth row; `overview.png` tiles every case and `gallery.json` lists them.
"""

from __future__ import annotations

import random
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw, ImageFont

from worldsplat.core.io import write_json_atomic
from worldsplat.core.metrics import psnr
from worldsplat.core.paths import source_root
from worldsplat.core.scenario import resolve_scenario
from worldsplat.evaluation.models import clip_view, rig_of, shard_condition_dict, vae_decode_rgb
from worldsplat.pipeline.inference import Models, encode_clip, generate, layout_size, reconstruct, to_scene4d
from worldsplat.pipeline.render import render_scene_track
from worldsplat.training.data import ShardDataset, sample_from_shard
from worldsplat.world import Clip, build_world, simulate
from worldsplat.world.dataset import clip_arrays, clip_scenario
from worldsplat.world.io import layout_image, save_png

DEFAULT_PRESETS = ("urban_straight", "highway", "cut_in", "crossing_pedestrian")
VIEWS = ("CAM_FRONT_LEFT", "CAM_FRONT", "CAM_FRONT_RIGHT")
RANDOM_POOL = 1000  # random cases without --data: clip indices 0..999 of the split
LABEL_W = 150  # left margin (row labels), pixels
HEADER_H = 18  # column titles
LINE_H = 15  # one title line
PAD = 4
GAP = 2  # white between tiles


@dataclass
class Case:
    """One gallery entry: ground truth at the models' resolution and the conditions generate reads."""

    name: str  # file stem
    title: str
    clip: Clip
    conditions: dict  # world.conditions() form
    seed: int  # the sampler's seed (the scenario's, as the server uses)


def preset_case(models: Models, preset: str) -> Case:
    """A preset (or scenario file) as the server builds its generate scene, with the world at the models' size."""
    d = models.data
    sc = resolve_scenario(preset).with_updates(image={"width": d.width, "height": d.height})
    world = build_world(sc)
    clip = simulate(world)
    cond = world.conditions(layout_size=layout_size(models))
    name = Path(preset).stem
    return Case(f"preset_{name}", f"{name} (preset, seed {sc.seed})", clip, cond, int(sc.seed))


def shard_case(models: Models, z: dict, name: str, title: str) -> Case:
    """A dataset clip (a loaded shard or `clip_arrays` output) with the conditions stored in it."""
    if layout_size(models) is not None and "layout" not in z:
        raise ValueError(f"{name}: these models read layout maps and the shard has none (written before they existed)")
    s = sample_from_shard(z, models.data.max_boxes)
    clip = clip_view(s, rig_of(s))
    return Case(name, f"{title}, seed {int(z['seed'])}", clip, shard_condition_dict(s, z), int(z["seed"]))


def random_cases(
    models: Models, count: int, split: str = "test", data: Path | None = None, seed: int = 0
) -> list[Case]:
    """`count` random clips of a split: from the shards in `data` when given, else made here from the split's seeds
    with the dataset code (the same clip `worldsplat dataset` writes, at the models' resolution)."""
    rng = random.Random(seed)
    if data is not None:
        ds = ShardDataset(data, split, models.data.max_boxes)
        picks = sorted(rng.sample(range(len(ds)), min(count, len(ds))))
        return [
            shard_case(models, ds.load(i), f"{split}_{ds.files[i].stem}", f"{split} {ds.files[i].stem}") for i in picks
        ]
    d = models.data
    out = []
    for i in sorted(rng.sample(range(RANDOM_POOL), count)):
        z = clip_arrays(clip_scenario(split, i, width=d.width, height=d.height))
        out.append(shard_case(models, z, f"{split}_clip_{i:06d}", f"{split} clip {i}"))
    return out


def case_rows(
    models: Models, case: Case, t: int = 1, views=VIEWS, steps: int = 8, caption_embedding=None
) -> list[tuple[str, list]]:
    """(label, [image per view]) rows of one case at frame t; the learned rows' labels carry PSNR vs the ground truth.
    caption_embedding: None encodes the caption as the server does (tests pass a fixed one)."""
    clip = case.clip
    T = clip.rgb.shape[0]
    if not 0 <= t < T:
        raise ValueError(f"--frame {t} outside the clip's frames 0..{T - 1} ({case.title})")
    vi = [clip.camera_names.index(n) for n in views]
    gt = [clip.rgb[t, v] for v in vi]

    def scored(label: str, imgs: list) -> tuple[str, list]:
        imgs = [_fit(x, gt[0].shape) for x in imgs]
        return f"{label}\n{psnr(np.stack(imgs), np.stack(gt)):.1f} dB", imgs

    rows = [("ground truth", gt)]
    vae = vae_decode_rgb(models, encode_clip(models, clip.rgb, clip.depth, clip.dynamic), t)
    rows.append(scored("VAE decode", [vae[v] for v in vi]))
    scene = to_scene4d(reconstruct(clip, models))
    rows.append(scored("reconstruct", list(render_scene_track(scene, 0.0, views=vi, frames=[t]).rgb[0])))
    if "generate" not in models.modes:
        return rows
    cond = case.conditions
    if layout_size(models) is not None:
        rows.append(("layout map\n(generate's input)", [layout_image(cond["layout"][t, v]) for v in vi]))
    else:
        rows.append(("sketch\n(generate's input)", [_u8(cond["sketch"][t, v]) for v in vi]))
    dec = generate(
        cond,
        steps=steps,
        seed=case.seed,
        models=models,
        rig=clip.rig,
        frame_times=clip.frame_times,
        caption_embedding=caption_embedding,
    )
    g = to_scene4d(dec)
    rows.append(
        scored(
            f"generate\n({steps} step{'s' * (steps != 1)})",
            list(render_scene_track(g, 0.0, views=vi, frames=[t]).rgb[0]),
        )
    )
    return rows


def _u8(x: np.ndarray) -> np.ndarray:
    return np.round(np.clip(np.asarray(x, np.float32), 0, 1) * 255).astype(np.uint8)


def _fit(img: np.ndarray, shape) -> np.ndarray:
    """A tile at the ground truth's size (the models' decodings are at their own size when a shard is not)."""
    if img.shape[:2] == tuple(shape[:2]):
        return img
    return np.asarray(Image.fromarray(img).resize((shape[1], shape[0]), Image.BILINEAR))


def _font(size: int = 12):
    try:
        return ImageFont.load_default(size=size)
    except TypeError:  # Pillow without FreeType: the fixed bitmap font
        return ImageFont.load_default()


def _clipped(text: str, font, width: int) -> str:
    """text, shortened with an ellipsis to fit `width` pixels."""
    if font.getlength(text) <= width:
        return text
    while text and font.getlength(text + "...") > width:
        text = text[:-1]
    return text + "..."


@dataclass
class Panel:
    image: np.ndarray  # (H, W, 3) uint8
    origin: tuple[int, int]  # (x, y) of the first tile
    tile: tuple[int, int]  # (width, height) of one tile, scale included
    labels: list[str]  # row labels, top to bottom

    def tile_at(self, row: int, col: int) -> np.ndarray:
        x, y = self.origin[0] + col * (self.tile[0] + GAP), self.origin[1] + row * (self.tile[1] + GAP)
        return self.image[y : y + self.tile[1], x : x + self.tile[0]]


def panel(rows: list[tuple[str, list]], titles: list[str], views=VIEWS, scale: int = 2) -> Panel:
    """The rows as one labelled grid: title lines on top, then the camera names, row labels on the left margin."""
    h, w = rows[0][1][0].shape[:2]
    tw, th = w * scale, h * scale
    x0, y0 = LABEL_W, PAD + LINE_H * len(titles) + HEADER_H
    size = (x0 + (tw + GAP) * len(views) - GAP, y0 + (th + GAP) * len(rows) - GAP)
    img = Image.new("RGB", size, (255, 255, 255))
    draw = ImageDraw.Draw(img)
    font = _font()
    for i, line in enumerate(titles):
        draw.text((PAD, PAD + i * LINE_H), _clipped(line, font, img.width - 2 * PAD), fill=(0, 0, 0), font=font)
    for c, name in enumerate(views):
        label = _clipped(name, font, tw - 4)
        draw.text((x0 + c * (tw + GAP) + tw // 2, y0 - HEADER_H // 2), label, fill=(0, 0, 0), font=font, anchor="mm")
    for r, (label, imgs) in enumerate(rows):
        draw.multiline_text((PAD, y0 + r * (th + GAP) + th // 2), label, fill=(0, 0, 0), font=font, anchor="lm")
        for c, tile in enumerate(imgs):
            img.paste(Image.fromarray(tile).resize((tw, th), Image.NEAREST), (x0 + c * (tw + GAP), y0 + r * (th + GAP)))
    return Panel(np.asarray(img), (x0, y0), (tw, th), [r[0] for r in rows])


def overview(panels: list[Panel], columns: int = 4) -> np.ndarray:
    """Panels tiled `columns` wide (rows of panels top-aligned, white between)."""
    ph = max(p.image.shape[0] for p in panels)
    pw = max(p.image.shape[1] for p in panels)
    n_rows = -(-len(panels) // columns)
    cols = min(columns, len(panels))
    out = np.full((n_rows * (ph + PAD) - PAD, cols * (pw + PAD) - PAD, 3), 255, np.uint8)
    for i, p in enumerate(panels):
        r, c = divmod(i, columns)
        hh, ww = p.image.shape[:2]
        out[r * (ph + PAD) : r * (ph + PAD) + hh, c * (pw + PAD) : c * (pw + PAD) + ww] = p.image
    return out


def write_gallery(
    models: Models,
    cases: list[Case],
    out: Path,
    t: int = 1,
    steps: int = 8,
    scale: int = 2,
    progress=print,
    caption_embedding=None,
) -> dict:
    """One PNG per case (at `scale`x the models' resolution) and `overview.png` (every case at 1x) in `out`, plus
    `gallery.json`. Returns that summary, with each case's Panel under "panels" (not written)."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    # the weights folder as the checkout names it (the images and gallery.json are committed: no machine's path)
    where = Path(models.weights_dir).resolve()
    shown = where.relative_to(source_root()).as_posix() if where.is_relative_to(source_root()) else where.name
    version = f"weights {shown} ({models.version})"
    summary = {"weights": shown, "version": models.version, "frame": t, "steps": steps, "cases": []}
    small, panels = [], {}
    for case in cases:
        rows = case_rows(models, case, t=t, steps=steps, caption_embedding=caption_embedding)
        titles = [f"{case.title} - frame {t}", str(case.clip.caption), version]
        p = panel(rows, titles, scale=scale)
        path = out / f"{case.name}.png"
        save_png(path, p.image)
        panels[case.name] = p
        small.append(panel(rows, titles[:2], scale=1))
        summary["cases"].append({"name": case.name, "title": case.title, "png": path.name, "rows": p.labels})
        progress(f"wrote {path}")
    if small:
        save_png(out / "overview.png", overview(small))
        progress(f"wrote {out / 'overview.png'}")
    write_json_atomic(out / "gallery.json", summary)
    return {**summary, "panels": panels}


def default_cases(
    models: Models,
    presets=DEFAULT_PRESETS,
    random_count: int = 4,
    split: str = "test",
    data: Path | None = None,
    seed: int = 0,
) -> list[Case]:
    return [preset_case(models, p) for p in presets] + random_cases(models, random_count, split, data, seed)
