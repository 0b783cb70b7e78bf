"""What each surface looks like: procedural textures (asphalt noise, lane paint, paving, grass, facade windows, car
lights, bus windows, foliage, clothes, traffic-light lamps) and the sky's colour, one function per surface.

`world.render.shade` finds which surface every ray hit and calls these; they fill albedo and emission arrays the
shading then lights (sun, sky, lamps, headlights) and fogs. Every texture is a hash of world or box-local
coordinates, so it is fixed to the surface and the same in every frame and view.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from worldsplat.world.classes import CROSSWALK, CURB, LANE_MARKING, SIDEWALK, TERRAIN
from worldsplat.world.lighting import Lighting
from worldsplat.world.prims import (
    M_BUILDING,
    M_BUS,
    M_CABIN,
    M_CAR_BODY,
    M_FOLIAGE,
    M_HOUSE,
    M_LAMP,
    M_PERSON,
    M_TRAFFIC_LIGHT,
    SPHERE,
    Prims,
)


# -- hashing noise (deterministic, vectorized) --------------------------------------------------------------------
def hash01(a: np.ndarray, b: np.ndarray, c: int | np.ndarray = 0) -> np.ndarray:
    """Integer lattice coordinates -> pseudo-random float32 in [0, 1)."""
    h = (
        np.asarray(a).astype(np.int64).astype(np.uint32) * np.uint32(374761393)
        + np.asarray(b).astype(np.int64).astype(np.uint32) * np.uint32(668265263)
        + np.asarray(c).astype(np.int64).astype(np.uint32) * np.uint32(2246822519)
    )
    h = (h ^ (h >> np.uint32(13))) * np.uint32(1274126177)
    h = h ^ (h >> np.uint32(16))
    return (h >> np.uint32(8)).astype(np.float32) * np.float32(1.0 / (1 << 24))


def value_noise(x: np.ndarray, y: np.ndarray, scale: float, seed: int = 0) -> np.ndarray:
    """Smooth 2D value noise in [0, 1) with cells of `scale` metres."""
    gx, gy = x / scale, y / scale
    ix, iy = np.floor(gx), np.floor(gy)
    fx, fy = (gx - ix).astype(np.float32), (gy - iy).astype(np.float32)
    fx, fy = fx * fx * (3 - 2 * fx), fy * fy * (3 - 2 * fy)
    a, b = hash01(ix, iy, seed), hash01(ix + 1, iy, seed)
    c, d = hash01(ix, iy + 1, seed), hash01(ix + 1, iy + 1, seed)
    return (a + (b - a) * fx) * (1 - fy) + (c + (d - c) * fx) * fy


# -- the ground: road, markings, kerbs, sidewalks, terrain ----------------------------------------------------------
def ground_albedo(road, x: np.ndarray, y: np.ndarray, wet: bool) -> tuple[np.ndarray, np.ndarray]:
    """Albedo (n,3) and semantic class (n,) of ground points (x, y)."""
    cls, u, v = road.ground(x, y)
    fine = hash01(np.floor(x * 8), np.floor(y * 8), 1)
    coarse = value_noise(x, y, 3.0, 2)
    alb = np.zeros((len(x), 3), np.float32)
    alb[:] = asphalt(coarse, fine, wet)
    paint = 0.78 + 0.08 * fine
    is_mark = cls == LANE_MARKING
    yellow = road.marking_colour_is_yellow(x, y) & is_mark
    alb[is_mark] = paint[is_mark, None] * np.array([1.0, 1.0, 1.0], np.float32)
    alb[yellow] = paint[yellow, None] * np.array([0.95, 0.75, 0.2], np.float32)
    cw = cls == CROSSWALK
    alb[cw] = paint[cw, None]
    curb = cls == CURB
    alb[curb] = np.array([0.62, 0.62, 0.6], np.float32) * (0.9 + 0.1 * fine[curb, None])
    sw = cls == SIDEWALK
    if sw.any():
        alb[sw] = paving(u[sw], v[sw])
    ter = cls == TERRAIN
    if ter.any():
        alb[ter] = grass(x[ter], y[ter], fine[ter])
    return alb, cls


def asphalt(coarse: np.ndarray, fine: np.ndarray, wet: bool) -> np.ndarray:
    """Asphalt albedo (n,3): grey with coarse and fine noise, darker when wet."""
    base = (0.2 + 0.05 * coarse + 0.05 * fine)[:, None]
    out = base * np.array([1.0, 1.0, 1.04], np.float32)
    if wet:
        out *= 0.6
    return out


def paving(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Sidewalk albedo (n,3): 1.2 m tiles of varying shade with darker joints (u, v: metres along the sidewalk)."""
    fu, fv = np.mod(u, 1.2), np.mod(v, 1.2)
    joint = (fu < 0.05) | (fv < 0.05)
    tile = 0.5 + 0.06 * hash01(np.floor(u / 1.2), np.floor(v / 1.2), 3)
    tile = np.where(joint, tile * 0.7, tile)
    return tile[:, None] * np.array([1.0, 0.97, 0.92], np.float32)


def grass(x: np.ndarray, y: np.ndarray, fine: np.ndarray) -> np.ndarray:
    """Terrain albedo (n,3): green with smooth and fine noise."""
    gn = 0.75 + 0.25 * value_noise(x, y, 1.5, 4) + 0.1 * fine
    return gn[:, None] * np.array([0.26, 0.38, 0.15], np.float32)


def wet_reflection(d: np.ndarray, sky_horizon: np.ndarray) -> np.ndarray:
    """Emission (n,3) of a wet road seen along rays d: a dim sky reflection, stronger at grazing angles."""
    dn = d / np.linalg.norm(d, axis=1, keepdims=True)
    fres = (0.08 + 0.5 * (1 + dn[:, 2]) ** 5).astype(np.float32)
    return fres[:, None] * sky_horizon.astype(np.float32) * 0.6


# -- primitives: boxes and spheres --------------------------------------------------------------------------------
@dataclass
class PrimHits:
    """Rays that hit primitives, in each primitive's box frame; the material functions write `col` and `em`."""

    k: np.ndarray  # (n,) primitive index
    lx: np.ndarray  # (n,) hit point in the box frame (x forward, y left, z up from the box centre)
    ly: np.ndarray
    lz: np.ndarray
    half: np.ndarray  # (n,3) half sizes
    axis: np.ndarray  # (n,) the face hit: 0 x, 1 y, 2 z
    sign: np.ndarray  # (n,) its side, +1 or -1
    normal: np.ndarray  # (n,3) world normal
    z: np.ndarray  # (n,) world height of the hit
    col: np.ndarray  # (n,3) albedo, from the primitive's colour
    em: np.ndarray  # (n,3) emission

    @property
    def side_face(self) -> np.ndarray:
        return self.axis < 2

    @property
    def along(self) -> np.ndarray:
        """Horizontal coordinate on a vertical face."""
        return np.where(self.axis == 0, self.ly, self.lx)

    @property
    def face_half(self) -> np.ndarray:
        return np.where(self.axis == 0, self.half[:, 1], self.half[:, 0])


def prim_hits(prims: Prims, k: np.ndarray, p: np.ndarray) -> PrimHits:
    """Box-frame coordinates, face and world normal of hit points p (n,3) on primitives k (n,)."""
    c, s = np.cos(prims.yaw[k]).astype(np.float32), np.sin(prims.yaw[k]).astype(np.float32)
    rel = (p - prims.center[k]).astype(np.float32)  # small offsets: float32 is exact enough
    lx, ly, lz = c * rel[:, 0] + s * rel[:, 1], -s * rel[:, 0] + c * rel[:, 1], rel[:, 2]
    half = prims.half[k].astype(np.float32)
    sphere = prims.shape[k] == SPHERE
    # Box normal: the local axis where the hit point is closest to the face.
    ax, ay, az = np.abs(lx) / half[:, 0], np.abs(ly) / half[:, 1], np.abs(lz) / half[:, 2]
    on_x = (ax >= ay) & (ax >= az)
    on_y = ~on_x & (ay >= az)
    axis = np.where(on_x, 0, np.where(on_y, 1, 2)).astype(np.int8)
    sign = np.where(on_x, np.sign(lx), np.where(on_y, np.sign(ly), np.sign(lz)))
    nlx, nly = np.where(on_x, sign, 0).astype(np.float32), np.where(on_y, sign, 0).astype(np.float32)
    nlz = np.where(axis == 2, sign, 0).astype(np.float32)
    nw = np.stack([c * nlx - s * nly, s * nlx + c * nly, nlz], -1)
    if sphere.any():
        nsph = rel / np.maximum(np.linalg.norm(rel, axis=1, keepdims=True), 1e-9)
        nw = np.where(sphere[:, None], nsph, nw)
    col = prims.color[k].copy()
    z = p[:, 2].astype(np.float32)
    return PrimHits(k, lx, ly, lz, half, axis, sign, nw, z, col, np.zeros_like(col))


def shade_prims(ph: PrimHits, prims: Prims, p: np.ndarray, L: Lighting) -> None:
    """Fill `ph.col` and `ph.em` per material (p: the world hit points, for the foliage noise)."""
    mat = prims.material[ph.k]
    key = prims.key[ph.k]
    for materials, surface in (
        ((M_BUILDING, M_HOUSE), lambda sel: facades(ph, sel, mat[sel] == M_HOUSE, key[sel], L)),
        ((M_CAR_BODY,), lambda sel: vehicle_body(ph, sel, L)),
        ((M_CABIN,), lambda sel: cabin_windows(ph, sel, L)),
        ((M_BUS,), lambda sel: bus_body(ph, sel, L)),
        ((M_FOLIAGE,), lambda sel: foliage(ph, sel, p[sel])),
        ((M_PERSON,), lambda sel: clothes(ph, sel)),
        ((M_LAMP,), lambda sel: street_lamp(ph, sel, L)),
        ((M_TRAFFIC_LIGHT,), lambda sel: traffic_light(ph, sel, key[sel])),
    ):
        on = np.isin(mat, materials) if len(materials) > 1 else mat == materials[0]
        if on.any():
            surface(np.nonzero(on)[0])


def _windows(ph: PrimHits, sel, floor_h, col_w, win_w, ground_floor):
    """Window panes on the vertical faces of boxes `sel`: a grid of floors and columns; returns the pane mask and
    each hit's floor and column index."""
    a = ph.along[sel]
    zz = ph.z[sel]
    fz = np.mod(zz, floor_h) / floor_h
    fa = np.mod(a + 100.0, col_w) / col_w
    inner = np.abs(a) < ph.face_half[sel] - 0.6
    win = (
        ph.side_face[sel]
        & inner
        & (fz > 0.3)
        & (fz < 0.78)
        & (np.abs(fa - 0.5) < win_w / 2)
        & (zz > ground_floor)
        & (zz < 2 * ph.half[sel, 2] - 0.8)
    )
    return win, np.floor(zz / floor_h), np.floor((a + 100.0) / col_w)


def facades(ph: PrimHits, bi: np.ndarray, house: np.ndarray, key: np.ndarray, L: Lighting) -> None:
    """Buildings and houses: windows (reflecting the sky; some lit at dusk and night), shop fronts on the ground
    floor of buildings, tiled roofs on houses and flat grey roofs on buildings."""
    z, along = ph.z[bi], ph.along[bi]
    win, fl, cl = _windows(
        ph,
        bi,
        np.where(house, 2.9, 3.3),
        np.where(house, 3.6, 2.6),
        np.where(house, 0.35, 0.55),
        np.where(house, 0.6, 3.0),
    )
    shop = (
        (~house)
        & ph.side_face[bi]
        & (z > 0.4)
        & (z < 2.7)
        & (np.mod(along + 100.0, 5.0) > 0.6)
        & (np.abs(along) < ph.face_half[bi] - 0.5)
    )
    glass = win | shop
    roof = ph.axis[bi] == 2
    cb = ph.col[bi]
    cb = cb * (0.95 + 0.05 * hash01(np.floor(z * 2), np.floor(along * 2), 5))[:, None]
    cb[roof] = np.where(
        house[roof, None], np.array([0.42, 0.2, 0.15], np.float32), np.array([0.36, 0.36, 0.37], np.float32)
    )
    reflect = 0.1 + 0.25 * hash01(fl, cl, (key * 1000).astype(np.int64))
    cb[glass] = np.array([0.08, 0.1, 0.13], np.float32) + reflect[glass, None] * L.sky_horizon.astype(np.float32) * 0.8
    ph.col[bi] = cb
    if L.lights_on:
        lit = glass & (hash01(fl, cl, (key * 7919).astype(np.int64) + 11) < (0.45 if L.night else 0.25))
        lit |= shop & L.night & (hash01(np.floor(along / 5.0), fl, 23) < 0.35)
        e = ph.em[bi]
        e[lit] = np.array([1.0, 0.82, 0.5], np.float32) * (0.6 if L.night else 0.35)
        ph.em[bi] = e


def vehicle_body(ph: PrimHits, vi: np.ndarray, L: Lighting) -> None:
    """Car and truck-cab bodies: dark wheels and sills, a grille, head and tail lamps (lit at dusk and night)."""
    cv = ph.col[vi]
    lxv, lyv, hv, zv = ph.lx[vi], ph.ly[vi], ph.half[vi], ph.z[vi]
    wheel = (zv < 0.62) & (np.abs(np.abs(lxv) - (hv[:, 0] - 0.85)) < 0.38) & ph.side_face[vi]
    sill = zv < 0.3
    cv[sill] *= 0.35
    cv[wheel] = (0.03, 0.03, 0.03)
    front = (ph.axis[vi] == 0) & (ph.sign[vi] > 0)
    rear = (ph.axis[vi] == 0) & (ph.sign[vi] < 0)
    lamp_zone = (np.abs(lyv) > hv[:, 1] - 0.45) & (np.abs(zv - (zv - ph.lz[vi] + hv[:, 2] * 0.55)) < 0.14)
    head = front & lamp_zone
    tail = rear & lamp_zone
    grille = front & ~lamp_zone & (np.abs(ph.lz[vi]) < hv[:, 2] * 0.5)
    cv[grille] *= 0.4
    cv[head] = (0.92, 0.92, 0.85)
    cv[tail] = (0.7, 0.05, 0.05)
    ph.col[vi] = cv
    ev = ph.em[vi]
    if L.lights_on:
        ev[head] = (1.6, 1.5, 1.2)
        ev[tail] = (1.2, 0.05, 0.03)
    ph.em[vi] = ev


def cabin_windows(ph: PrimHits, ci: np.ndarray, L: Lighting) -> None:
    """Car cabins: windows on every vertical face, framed by a thin band of body colour (pillars, sills)."""
    a_ci = np.abs(ph.along[ci])
    half = ph.half[ci]
    glass = ph.side_face[ci] & (a_ci < ph.face_half[ci] - 0.12) & (ph.lz[ci] > -0.75 * half[:, 2])
    glass &= ph.lz[ci] < 0.8 * half[:, 2]
    cc = ph.col[ci]
    cc[glass] = np.array([0.12, 0.15, 0.19], np.float32) + 0.3 * L.sky_horizon.astype(np.float32)
    ph.col[ci] = cc


def bus_body(ph: PrimHits, bi: np.ndarray, L: Lighting) -> None:
    """Buses: a band of windows along the sides, a dark skirt."""
    zz = ph.z[bi]
    band = ph.side_face[bi] & (zz > 1.25) & (zz < 2.5) & (np.mod(ph.along[bi] + 100, 1.6) > 0.12)
    cb = ph.col[bi]
    cb[band] = np.array([0.06, 0.08, 0.1], np.float32) + 0.2 * L.sky_horizon.astype(np.float32)
    cb[zz < 0.6] *= 0.3
    ph.col[bi] = cb


def foliage(ph: PrimHits, fi: np.ndarray, p: np.ndarray) -> None:
    """Tree crowns and hedges: leaf-sized brightness noise fixed in the world (p: the hit points)."""
    nz = hash01(np.floor(p[:, 0] * 3) + np.floor(p[:, 2] * 3) * 131, np.floor(p[:, 1] * 3), 9)
    ph.col[fi] *= (0.7 + 0.6 * nz)[:, None]


def clothes(ph: PrimHits, pi: np.ndarray) -> None:
    """People: their clothes' colour above the hips, dark trousers below."""
    legs = ph.lz[pi] < -0.1 * ph.half[pi, 2]
    cp = ph.col[pi]
    cp[legs] = (0.12, 0.12, 0.18)
    ph.col[pi] = cp


def street_lamp(ph: PrimHits, li: np.ndarray, L: Lighting) -> None:
    """Street-lamp heads glow when the lights are on."""
    if L.lights_on:
        ph.em[li] = (2.0, 1.8, 1.3)


def traffic_light(ph: PrimHits, ti: np.ndarray, key: np.ndarray) -> None:
    """Traffic-light heads: red, amber and green discs; the one the key selects (red or green) is lit."""
    along, lz = ph.along[ti], ph.lz[ti]
    disc = ph.side_face[ti] & (np.abs(along) < 0.1) & (np.abs(np.mod(lz + 0.45, 0.3) - 0.15) < 0.09)
    slot = np.floor((lz + 0.45) / 0.3)  # 0 bottom (green) .. 2 top (red)
    on = np.where(key < 0.5, 2, 0)
    colour = np.where(
        (slot == 2)[:, None],
        np.array([1.0, 0.1, 0.05], np.float32),
        np.where((slot == 1)[:, None], np.array([1.0, 0.7, 0.1], np.float32), np.array([0.1, 1.0, 0.4], np.float32)),
    )
    lit = disc & (slot == on)
    et = ph.em[ti]
    et[lit] = colour[lit] * 1.5
    ct = ph.col[ti]
    ct[disc & ~lit] = colour[disc & ~lit] * 0.2
    ph.col[ti] = ct
    ph.em[ti] = et


# -- the sky ----------------------------------------------------------------------------------------------------
def sky_colour(L: Lighting, d: np.ndarray) -> np.ndarray:
    """Colour (n,3) of the sky along rays d: a horizon-to-zenith gradient, the sun and fair-weather clouds on a
    clear day, a textured cloud deck when overcast or raining, stars on a clear night."""
    dn = d / np.linalg.norm(d, axis=1, keepdims=True)
    el = np.clip(dn[:, 2], 0.0, 1.0).astype(np.float32)
    w = np.sqrt(el)[:, None]
    sky = L.sky_horizon[None].astype(np.float32) * (1 - w) + L.sky_zenith[None].astype(np.float32) * w
    if L.weather in ("clear",) and L.time_of_day != "night":
        sky = _sun_and_clouds(L, dn, el, sky)
    elif L.weather in ("overcast", "rain"):
        cl = value_noise(dn[:, 0] / (dn[:, 2] + 0.08), dn[:, 1] / (dn[:, 2] + 0.08), 0.6, 21)
        sky = sky * (0.88 + 0.2 * cl)[:, None]
    if L.night:
        stars = (
            (hash01(np.floor(dn[:, 0] * 400), np.floor(dn[:, 1] * 400) + np.floor(dn[:, 2] * 400) * 977, 17) > 0.9985)
            & (el > 0.05)
            & (L.weather == "clear")
        )
        sky = sky + stars[:, None] * 0.6
    return sky


def _sun_and_clouds(L: Lighting, dn: np.ndarray, el: np.ndarray, sky: np.ndarray) -> np.ndarray:
    cosang = np.clip(dn @ L.sun_dir, 0, 1).astype(np.float32)
    sky = sky + L.sun_color.astype(np.float32)[None] * (0.5 * cosang**48 + (cosang > 0.9995))[:, None]
    # A few fair-weather clouds on a virtual plane above the scene.
    px, py = dn[:, 0] / (dn[:, 2] + 0.05), dn[:, 1] / (dn[:, 2] + 0.05)
    cl = 0.65 * value_noise(px, py, 0.9, 31) + 0.35 * value_noise(px, py, 0.3, 32)
    cover = (np.clip((cl - 0.58) * 4.0, 0, 1) * np.clip(el * 8.0, 0, 1))[:, None]
    cloud = np.float32(0.92) * (L.ambient.astype(np.float32) + L.sun_color.astype(np.float32) * 0.6)
    return sky * (1 - cover) + np.clip(cloud, 0, 1)[None] * cover
