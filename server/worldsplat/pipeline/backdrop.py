"""Generate's backdrop: what stands behind each agent, drawn where the agent hides it.

The generated pixels inside an agent's box go onto the box and move with the agent (`snaps.snap_agents_to_layout`),
so a keyframe leaves nothing behind its agents: another frame, a shifted track, or a car that drives beside the ego
the whole clip then shows a hole, black where the road should be. The layout maps without the boxes
(`world.layout_maps.layout_map(agents=False)`) state exactly what stands behind, the road plane with its markings,
the sidewalk, the facades and trees at their depth; the colour of each such surface is continued from where the
same view shows it (`fill_behind`: push-pull over the pixels of the same class; the road, the markings and the
sidewalk are plain paint in this world, which is why the open road is served at the layout prior's mean). The box's
pixels are then lifted static on the maps' exact depth (`lift_behind`). The backdrop stands behind the agent in its
own frame, so the keyframe's image barely changes; elsewhere it closes the hole. Measured in web/docs/agents.md
("The backdrop").
"""

from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F

from worldsplat.gaussians.lift import lift
from worldsplat.gaussians.types import Gaussians
from worldsplat.world.layout_maps import LAYOUT_CHANNELS, SKY_DEPTH, layout_depth_m

# The box's pixels grown by this many served pixels: the agent's snapped pixels blur over its silhouette's edge.
BACKDROP_GROW_PX = 1
# Surface classes of the layout maps, in the order a pixel takes them (the map layer stands before the ground; a
# marking before the road it is painted on); 0: nothing in range.
SURFACES = ("building", "vegetation", "furniture", "markings", "drivable", "sidewalk", "ground")


def box_pixels(control: torch.Tensor, grow: int = BACKDROP_GROW_PX) -> torch.Tensor:
    """Layout maps (N,C,H,W) at the served image -> (N,H,W) bool: where a box is the nearest surface (vehicle or
    vulnerable cover > 0.5, the snaps' rule), grown by `grow` pixels."""
    ch = {k: i for i, k in enumerate(LAYOUT_CHANNELS)}
    box = (control[:, ch["vehicle"]] + control[:, ch["vulnerable"]]) > 0.5
    if grow > 0:
        box = F.max_pool2d(box[:, None].float(), 2 * grow + 1, stride=1, padding=grow)[:, 0] > 0.5
    return box


def surface_classes(control: torch.Tensor) -> torch.Tensor:
    """Layout maps (N,C,H,W) -> (N,H,W) int: 1 + the index in SURFACES of the surface each pixel shows ("ground":
    any other ground in range, terrain), 0 where nothing is in range. The map layer's channels count where the maps
    carry them."""
    names = LAYOUT_CHANNELS[: control.shape[1]]
    out = torch.zeros(control.shape[0], *control.shape[2:], dtype=torch.long)
    depth = control[:, names.index("depth")]
    for k in range(len(SURFACES), 0, -1):  # the first in SURFACES written last: it wins
        name = SURFACES[k - 1]
        if name == "ground":
            on = depth < SKY_DEPTH
        elif name in names:
            on = control[:, names.index(name)] > 0.5
        else:
            continue
        out = torch.where(on, torch.full_like(out, k), out)
    return out


def push_pull(img: torch.Tensor, known: torch.Tensor) -> torch.Tensor:
    """(B,3,H,W) colours, (B,1,H,W) weights in [0,1] (0: unknown) -> every pixel's colour: the known ones kept, the
    rest from the nearest known ones (averaged down a pyramid until every cell holds one, then brought back up, each level
    filling only where the finer one has nothing). A view without a known pixel comes back 0."""
    levels = [(img * known, known)]
    while min(levels[-1][1].shape[-2:]) > 1 and bool((levels[-1][1].flatten(1).amin(1) == 0).any()):
        num, den = levels[-1]
        levels.append((F.avg_pool2d(num, 2, ceil_mode=True), F.avg_pool2d(den, 2, ceil_mode=True)))
    num, den = levels[-1]
    # a coarsest cell with nothing known takes the view's mean of the known pixels (not 0, which the bilinear step
    # up would blend into its neighbours)
    mean = (img * known).sum((2, 3), keepdim=True) / known.sum((2, 3), keepdim=True).clamp_min(1e-6)
    fill = torch.where(den > 0, num / den.clamp_min(1e-6), mean)
    for num, den in reversed(levels[:-1]):
        up = F.interpolate(fill, size=num.shape[-2:], mode="bilinear", align_corners=False)
        own = num / den.clamp_min(1e-6)
        fill = torch.where(den > 0, own, up)
    return fill


def fill_behind(images: np.ndarray, control: torch.Tensor, control_behind: torch.Tensor, boxes: torch.Tensor):
    """N views at the served image: their images (N,H,W,3) in [0, 1], layout maps with and without the boxes
    (N,C,H,W), the box pixels (N,H,W) bool -> (N,H,W,3) colours where the boxes are: each box pixel the colour the
    same view shows its surface behind (`surface_classes` of the maps without the boxes) with, continued from those
    pixels (`push_pull`); where the view shows none of that surface, from everything it shows outside the boxes."""
    img = torch.as_tensor(images, dtype=torch.float32).permute(0, 3, 1, 2)
    seen = torch.where(boxes, torch.zeros_like(boxes, dtype=torch.long), surface_classes(control))
    behind = surface_classes(control_behind)
    kinds = [k for k in torch.unique(behind[boxes]).tolist() if k > 0]
    # every surface at once (and the fallback, all that the view shows, first): one push-pull over (views x kinds)
    # at half the image (the fill is smooth; a marking's pixels still average only with each other), then back up
    known = torch.stack([seen > 0] + [seen == k for k in kinds], 1).float()  # (N, K, H, W)
    N, K = known.shape[:2]
    num = F.avg_pool2d((img[:, None] * known[:, :, None]).flatten(0, 1), 2, ceil_mode=True)
    den = F.avg_pool2d(known.flatten(0, 1)[:, None], 2, ceil_mode=True)
    half = push_pull(num / den.clamp_min(1e-6), den)
    fill = F.interpolate(half, size=img.shape[-2:], mode="bilinear", align_corners=False).reshape(
        N, K, 3, *img.shape[-2:]
    )
    out = fill[:, 0]
    has = known.flatten(2).amax(2) > 0  # (N, K): views that show this surface outside the boxes
    for j, k in enumerate(kinds, start=1):
        take = (boxes & (behind == k) & has[:, j, None, None])[:, None]
        out = torch.where(take, fill[:, j], out)
    return out.permute(0, 2, 3, 1).numpy()


def behind_depth(control_behind: torch.Tensor) -> np.ndarray:
    """Layout maps without the boxes (N,C,H,W) at the served image -> (N,H,W) camera z in metres of what stands
    behind (the map layer's depth where the maps carry it, else the road's), +inf where nothing is in range."""
    names = LAYOUT_CHANNELS[: control_behind.shape[1]]
    c = control_behind[:, names.index("map_depth" if "map_depth" in names else "depth")]
    z = layout_depth_m(c.clamp(-1.0, 1.0))
    return torch.where(c >= SKY_DEPTH, torch.full_like(z, float("inf")), z).numpy().astype(np.float64)


def lift_behind(rgb: np.ndarray, control_behind: torch.Tensor, boxes: torch.Tensor, cameras: list) -> list[Gaussians]:
    """N views: the colours of what stands behind the agents (N,H,W,3) in [0, 1] (`fill_behind`), the layout maps
    without the boxes (N,C,H,W) and the box pixels (N,H,W) bool at the served image, and their world cameras -> per
    view the static Gaussians of the box pixels on the maps' exact depth."""
    depth = behind_depth(control_behind)
    out = []
    for i, cam in enumerate(cameras):
        z = np.where(boxes[i].numpy(), depth[i], np.inf)
        out.append(lift(rgb[i], z, None, cam, sky=False) if np.isfinite(z).any() else Gaussians.empty())
    return out
