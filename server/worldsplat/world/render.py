"""Ground-truth renderer: vectorized numpy ray casting against the world's analytic primitives.

Per camera: primary rays (unit camera-z directions, so the ray parameter IS the camera-z depth) hit the ground
plane z = 0 analytically, then every primitive that survives frustum culling is tested only on the pixels of its
projected screen rectangle (box slab test / sphere quadratic) with a z-test. Shading is then done once for all
views of a frame: procedural textures (asphalt noise, lane paint, paving, facade windows, car lights), Lambert
sun + sky ambient, shadows from a sun shadow map, street lights and headlights at night, wet roads and rain
streaks, and exponential fog by depth. Sky pixels have depth +inf and class SKY.
"""

from __future__ import annotations

import contextlib
import math
from dataclasses import dataclass

import numpy as np

from worldsplat.core.camera import Camera
from worldsplat.world.classes import CROSSWALK, CURB, LANE_MARKING, SIDEWALK, SKY, TERRAIN
from worldsplat.world.lighting import Lighting
from worldsplat.world.prims import (
    BOX,
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

NEAR = 0.05
FAR = 250.0
PID_SKY, PID_GROUND = -1, -2


def single_threaded_blas():
    """Context: one BLAS thread. The renderer's matrix products are tall and skinny ((N,3) x (3,k)); a
    multi-threaded OpenBLAS spin-waits on them and runs ~25x slower when the cores are busy. We parallelise over
    frames instead (worldsplat.world.simulate)."""
    try:
        from threadpoolctl import threadpool_limits  # noqa: PLC0415 - optional BLAS thread control
    except ImportError:  # pragma: no cover - threadpoolctl ships with the pinned environment
        return contextlib.nullcontext()
    return threadpool_limits(limits=1, user_api="blas")


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


# -- visibility ---------------------------------------------------------------------------------------------------
@dataclass
class Hits:
    t: np.ndarray  # (H,W) float64 depth (camera z), inf for sky
    pid: np.ndarray  # (H,W) int32 primitive index, PID_GROUND or PID_SKY


def _box_hit(o: np.ndarray, d: np.ndarray, center, yaw, half) -> np.ndarray:
    """Entry distance of rays (o + t d) into a yaw-oriented box; inf where missed or behind."""
    c, s = math.cos(yaw), math.sin(yaw)
    ox, oy, oz = o - center
    olx, oly = c * ox + s * oy, -s * ox + c * oy
    dx, dy, dz = d[..., 0], d[..., 1], d[..., 2]
    dlx, dly = c * dx + s * dy, -s * dx + c * dy
    tmin = np.full(dx.shape, -np.inf)
    tmax = np.full(dx.shape, np.inf)
    for ol, dl, h in ((olx, dlx, half[0]), (oly, dly, half[1]), (oz, dz, half[2])):
        dl = np.where(np.abs(dl) < 1e-12, 1e-12, dl)
        inv = 1.0 / dl
        t1 = (-h - ol) * inv
        t2 = (h - ol) * inv
        tmin = np.maximum(tmin, np.minimum(t1, t2))
        tmax = np.minimum(tmax, np.maximum(t1, t2))
    return np.where((tmax >= tmin) & (tmin > NEAR), tmin, np.inf)


def _sphere_hit(o: np.ndarray, d: np.ndarray, center, radius) -> np.ndarray:
    oc = o - center
    a = np.einsum("...k,...k->...", d, d)
    b = 2.0 * (d @ oc)
    c = float(oc @ oc) - radius * radius
    disc = b * b - 4 * a * c
    t = (-b - np.sqrt(np.maximum(disc, 0.0))) / (2 * a)
    return np.where((disc >= 0) & (t > NEAR), t, np.inf)


def cull(prims: Prims, cam: Camera, far: float = FAR) -> np.ndarray:
    """Indices of primitives whose bounding sphere touches the view frustum (near..far)."""
    if not len(prims):
        return np.zeros(0, np.int64)
    w2c = cam.world_to_camera
    pc = prims.center @ w2c[:3, :3].T + w2c[:3, 3]
    r = prims.radius
    x, y, z = pc[:, 0], pc[:, 1], pc[:, 2]
    keep = (z + r > NEAR) & (z - r < far)
    for tan_, coord in (
        ((cam.width - cam.cx) / cam.fx, x),
        (cam.cx / cam.fx, -x),
        ((cam.height - cam.cy) / cam.fy, y),
        (cam.cy / cam.fy, -y),
    ):
        keep &= (coord - z * tan_) / math.sqrt(1 + tan_ * tan_) < r
    return np.nonzero(keep)[0]


_CORNERS = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], np.float64)


def screen_rects(prims: Prims, idx: np.ndarray, cam: Camera) -> np.ndarray:
    """(n,4) pixel rectangles i0, i1, j0, j1 (exclusive ends) bounding each primitive's projection."""
    if len(idx) == 0:
        return np.zeros((0, 4), np.int64)
    c = prims.center[idx]
    h = prims.half[idx]
    cy, sy = np.cos(prims.yaw[idx]), np.sin(prims.yaw[idx])
    loc = _CORNERS[None] * h[:, None, :]
    wx = c[:, None, 0] + cy[:, None] * loc[..., 0] - sy[:, None] * loc[..., 1]
    wy = c[:, None, 1] + sy[:, None] * loc[..., 0] + cy[:, None] * loc[..., 1]
    wz = c[:, None, 2] + loc[..., 2]
    m = cam.world_to_camera
    px = m[0, 0] * wx + m[0, 1] * wy + m[0, 2] * wz + m[0, 3]
    py = m[1, 0] * wx + m[1, 1] * wy + m[1, 2] * wz + m[1, 3]
    pz = m[2, 0] * wx + m[2, 1] * wy + m[2, 2] * wz + m[2, 3]
    behind = np.any(pz <= NEAR, axis=1)
    zs = np.maximum(pz, NEAR)
    u = cam.fx * px / zs + cam.cx
    v = cam.fy * py / zs + cam.cy
    rect = np.stack([np.floor(u.min(1)), np.ceil(u.max(1)), np.floor(v.min(1)), np.ceil(v.max(1))], -1)
    rect[behind] = [0, cam.width, 0, cam.height]
    rect[:, 0:2] = np.clip(rect[:, 0:2], 0, cam.width)
    rect[:, 2:4] = np.clip(rect[:, 2:4], 0, cam.height)
    return rect.astype(np.int64)


def trace(cam: Camera, prims: Prims, far: float = FAR) -> tuple[Hits, np.ndarray, np.ndarray]:
    """Closest hit per pixel; also returns the ray origin (3,) and directions (H,W,3)."""
    o, d = cam.pixel_rays()
    dz = d[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        tg = np.where(dz < -1e-12, -o[2] / dz, np.inf)
    ground = (tg > NEAR) & (tg < far) & (o[2] > 0)
    t = np.where(ground, tg, np.inf)
    pid = np.where(ground, PID_GROUND, PID_SKY).astype(np.int32)
    idx = cull(prims, cam, far)
    rects = screen_rects(prims, idx, cam)
    for k, (i0, i1, j0, j1) in zip(idx, rects):
        if i1 <= i0 or j1 <= j0:
            continue
        dsub = d[j0:j1, i0:i1]
        if prims.shape[k] == BOX:
            tk = _box_hit(o, dsub, prims.center[k], prims.yaw[k], prims.half[k])
        else:
            tk = _sphere_hit(o, dsub, prims.center[k], prims.half[k, 0])
        tsub = t[j0:j1, i0:i1]
        closer = tk < tsub
        if closer.any():
            t[j0:j1, i0:i1] = np.where(closer, tk, tsub)
            pid[j0:j1, i0:i1] = np.where(closer, k, pid[j0:j1, i0:i1])
    return Hits(t, pid), o, d


# -- shadows: an orthographic depth map seen from the sun ---------------------------------------------------------
@dataclass
class ShadowMap:
    origin: np.ndarray  # (3,) centre of the map plane
    axes: np.ndarray  # (2,3) map u, v axes (unit, orthogonal to the light)
    light: np.ndarray  # (3,) unit vector towards the light
    extent: float  # half size in metres
    depth: np.ndarray  # (N,N) distance along -light from the map plane to the first occluder

    def lit(self, p: np.ndarray, normal_offset: np.ndarray | None = None) -> np.ndarray:
        """1 where points (...,3) see the light, 0 where an occluder is between them and the light."""
        q = p if normal_offset is None else p + normal_offset
        rel = q - self.origin
        n = self.depth.shape[0]
        u = (rel @ self.axes[0] + self.extent) / (2 * self.extent) * n
        v = (rel @ self.axes[1] + self.extent) / (2 * self.extent) * n
        inside = (u >= 0) & (u < n) & (v >= 0) & (v < n)
        iu = np.clip(u.astype(np.int64), 0, n - 1)
        iv = np.clip(v.astype(np.int64), 0, n - 1)
        dist = -(rel @ self.light)
        occ = self.depth[iv, iu]
        return np.where(inside & (occ < dist - 0.3), 0.0, 1.0).astype(np.float32)


def shadow_map(prims: Prims, light: np.ndarray, center: np.ndarray, extent: float = 70.0, size: int = 384) -> ShadowMap:
    light = light / np.linalg.norm(light)
    up = np.array([0.0, 0.0, 1.0])
    a0 = np.cross(up, light)
    if np.linalg.norm(a0) < 1e-6:
        a0 = np.array([1.0, 0.0, 0.0])
    a0 /= np.linalg.norm(a0)
    a1 = np.cross(light, a0)
    origin = center + light * 80.0
    depth = np.full((size, size), np.inf)
    cell = 2 * extent / size
    for k in range(len(prims)):
        rel = prims.center[k] - origin
        r = prims.radius[k]
        cu, cv = rel @ a0, rel @ a1
        i0 = int(max(0, math.floor((cu - r + extent) / cell)))
        i1 = int(min(size, math.ceil((cu + r + extent) / cell)))
        j0 = int(max(0, math.floor((cv - r + extent) / cell)))
        j1 = int(min(size, math.ceil((cv + r + extent) / cell)))
        if i1 <= i0 or j1 <= j0:
            continue
        uu = (np.arange(i0, i1) + 0.5) * cell - extent
        vv = (np.arange(j0, j1) + 0.5) * cell - extent
        o = origin + uu[None, :, None] * a0 + vv[:, None, None] * a1  # (h,w,3) ray origins
        dvec = -light
        if prims.shape[k] == BOX:
            tk = _box_hit_many(o, dvec, prims.center[k], prims.yaw[k], prims.half[k])
        else:
            oc = o - prims.center[k]
            b = 2.0 * (oc @ dvec)
            c = np.einsum("...k,...k->...", oc, oc) - prims.half[k, 0] ** 2
            disc = b * b - 4 * c
            tk = np.where(disc >= 0, (-b - np.sqrt(np.maximum(disc, 0))) / 2, np.inf)
        depth[j0:j1, i0:i1] = np.minimum(depth[j0:j1, i0:i1], tk)
    return ShadowMap(origin, np.stack([a0, a1]), light, extent, depth)


def _box_hit_many(o: np.ndarray, d: np.ndarray, center, yaw, half) -> np.ndarray:
    """Like `_box_hit` but with many origins and one direction (entry t may be negative: not needed here)."""
    c, s = math.cos(yaw), math.sin(yaw)
    rel = o - center
    olx, oly, oz = c * rel[..., 0] + s * rel[..., 1], -s * rel[..., 0] + c * rel[..., 1], rel[..., 2]
    dlx, dly, dz = c * d[0] + s * d[1], -s * d[0] + c * d[1], d[2]
    tmin = np.full(olx.shape, -np.inf)
    tmax = np.full(olx.shape, np.inf)
    for ol, dl, h in ((olx, dlx, half[0]), (oly, dly, half[1]), (oz, dz, half[2])):
        if abs(dl) < 1e-12:
            inside = np.abs(ol) <= h
            tmin = np.where(inside, tmin, np.inf)
            continue
        t1, t2 = (-h - ol) / dl, (h - ol) / dl
        tmin = np.maximum(tmin, np.minimum(t1, t2))
        tmax = np.minimum(tmax, np.maximum(t1, t2))
    return np.where(tmax >= tmin, tmin, np.inf)


# -- shading ------------------------------------------------------------------------------------------------------
@dataclass
class ShadeInput:
    t: np.ndarray  # (N,) depth
    pid: np.ndarray  # (N,)
    p: np.ndarray  # (N,3) world hit points (garbage for sky)
    d: np.ndarray  # (N,3) ray directions
    ego_to_world: np.ndarray


def shade(world, prims: Prims, si: ShadeInput, smap: ShadowMap | None) -> tuple[np.ndarray, np.ndarray]:
    """Colour (N,3) float32 in [0,1] and semantic class (N,) uint8 for every ray."""
    L: Lighting = world.lighting
    road = world.road
    n = si.t.shape[0]
    rgb = np.zeros((n, 3), np.float32)
    sem = np.full(n, SKY, np.uint8)
    albedo = np.zeros((n, 3), np.float32)
    emissive = np.zeros((n, 3), np.float32)
    normal = np.zeros((n, 3), np.float32)
    wet = L.weather == "rain"

    # Ground.
    g = np.nonzero(si.pid == PID_GROUND)[0]
    if len(g):
        x, y = si.p[g, 0], si.p[g, 1]
        cls, u, v = road.ground(x, y)
        sem[g] = cls
        fine = hash01(np.floor(x * 8), np.floor(y * 8), 1)
        coarse = value_noise(x, y, 3.0, 2)
        alb = np.zeros((len(g), 3), np.float32)
        base = (0.2 + 0.05 * coarse + 0.05 * fine)[:, None]
        asphalt = base * np.array([1.0, 1.0, 1.04], np.float32)
        if wet:
            asphalt *= 0.6
        alb[:] = asphalt
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
            fu, fv = np.mod(u[sw], 1.2), np.mod(v[sw], 1.2)
            joint = (fu < 0.05) | (fv < 0.05)
            tile = 0.5 + 0.06 * hash01(np.floor(u[sw] / 1.2), np.floor(v[sw] / 1.2), 3)
            tile = np.where(joint, tile * 0.7, tile)
            alb[sw] = tile[:, None] * np.array([1.0, 0.97, 0.92], np.float32)
        ter = cls == TERRAIN
        if ter.any():
            gn = 0.75 + 0.25 * value_noise(x[ter], y[ter], 1.5, 4) + 0.1 * fine[ter]
            alb[ter] = gn[:, None] * np.array([0.26, 0.38, 0.15], np.float32)
        albedo[g] = alb
        normal[g] = (0.0, 0.0, 1.0)
        if wet:
            # Wet road: a dim reflection of the sky, stronger at grazing angles.
            dn = si.d[g] / np.linalg.norm(si.d[g], axis=1, keepdims=True)
            fres = (0.08 + 0.5 * (1 + dn[:, 2]) ** 5).astype(np.float32)
            emissive[g] += fres[:, None] * L.sky_horizon.astype(np.float32) * 0.6

    # Primitives.
    h = np.nonzero(si.pid >= 0)[0]
    if len(h):
        k = si.pid[h]
        sem[h] = prims.cls[k]
        c, s = np.cos(prims.yaw[k]).astype(np.float32), np.sin(prims.yaw[k]).astype(np.float32)
        rel = (si.p[h] - prims.center[k]).astype(np.float32)  # small offsets: float32 is exact enough
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
        normal[h] = nw
        col = prims.color[k].copy()
        em = np.zeros_like(col)
        mat = prims.material[k]
        key = prims.key[k]
        z = si.p[h, 2].astype(np.float32)
        side_face = axis < 2
        along = np.where(axis == 0, ly, lx)  # horizontal coordinate on a vertical face
        face_half = np.where(axis == 0, half[:, 1], half[:, 0])

        def windows(sel, floor_h, col_w, win_w, ground_floor):
            a = along[sel]
            zz = z[sel]
            fz = np.mod(zz, floor_h) / floor_h
            fa = np.mod(a + 100.0, col_w) / col_w
            inner = np.abs(a) < face_half[sel] - 0.6
            win = (
                side_face[sel]
                & inner
                & (fz > 0.3)
                & (fz < 0.78)
                & (np.abs(fa - 0.5) < win_w / 2)
                & (zz > ground_floor)
                & (zz < 2 * half[sel, 2] - 0.8)
            )
            return win, np.floor(zz / floor_h), np.floor((a + 100.0) / col_w)

        b = (mat == M_BUILDING) | (mat == M_HOUSE)
        if b.any():
            bi = np.nonzero(b)[0]
            house = mat[bi] == M_HOUSE
            win, fl, cl = windows(
                bi,
                np.where(house, 2.9, 3.3),
                np.where(house, 3.6, 2.6),
                np.where(house, 0.35, 0.55),
                np.where(house, 0.6, 3.0),
            )
            shop = (
                (~house)
                & side_face[bi]
                & (z[bi] > 0.4)
                & (z[bi] < 2.7)
                & (np.mod(along[bi] + 100.0, 5.0) > 0.6)
                & (np.abs(along[bi]) < face_half[bi] - 0.5)
            )
            glass = win | shop
            roof = axis[bi] == 2
            cb = col[bi]
            cb = cb * (0.95 + 0.05 * hash01(np.floor(z[bi] * 2), np.floor(along[bi] * 2), 5))[:, None]
            cb[roof] = np.where(
                house[roof, None], np.array([0.42, 0.2, 0.15], np.float32), np.array([0.36, 0.36, 0.37], np.float32)
            )
            reflect = 0.1 + 0.25 * hash01(fl, cl, (key[bi] * 1000).astype(np.int64))
            cb[glass] = (
                np.array([0.08, 0.1, 0.13], np.float32) + reflect[glass, None] * L.sky_horizon.astype(np.float32) * 0.8
            )
            col[bi] = cb
            if L.lights_on:
                lit = glass & (hash01(fl, cl, (key[bi] * 7919).astype(np.int64) + 11) < (0.45 if L.night else 0.25))
                lit |= shop & L.night & (hash01(np.floor(along[bi] / 5.0), fl, 23) < 0.35)
                e = em[bi]
                e[lit] = np.array([1.0, 0.82, 0.5], np.float32) * (0.6 if L.night else 0.35)
                em[bi] = e
        veh = mat == M_CAR_BODY
        if veh.any():
            vi = np.nonzero(veh)[0]
            cv = col[vi]
            lxv, lyv, hv = lx[vi], ly[vi], half[vi]
            wheel = (z[vi] < 0.62) & (np.abs(np.abs(lxv) - (hv[:, 0] - 0.85)) < 0.38) & side_face[vi]
            sill = z[vi] < 0.3
            cv[sill] *= 0.35
            cv[wheel] = (0.03, 0.03, 0.03)
            front = (axis[vi] == 0) & (sign[vi] > 0)
            rear = (axis[vi] == 0) & (sign[vi] < 0)
            lamp_zone = (np.abs(lyv) > hv[:, 1] - 0.45) & (np.abs(z[vi] - (z[vi] - lz[vi] + hv[:, 2] * 0.55)) < 0.14)
            head = front & lamp_zone
            tail = rear & lamp_zone
            grille = front & ~lamp_zone & (np.abs(lz[vi]) < hv[:, 2] * 0.5)
            cv[grille] *= 0.4
            cv[head] = (0.92, 0.92, 0.85)
            cv[tail] = (0.7, 0.05, 0.05)
            col[vi] = cv
            ev = em[vi]
            if L.lights_on:
                ev[head] = (1.6, 1.5, 1.2)
                ev[tail] = (1.2, 0.05, 0.03)
            em[vi] = ev
        cab = mat == M_CABIN
        if cab.any():
            ci = np.nonzero(cab)[0]
            # Windows on every vertical face, framed by a thin band of body colour (pillars, sills).
            a_ci = np.abs(along[ci])
            glass = (
                side_face[ci]
                & (a_ci < face_half[ci] - 0.12)
                & (lz[ci] > -0.75 * half[ci, 2])
                & (lz[ci] < 0.8 * half[ci, 2])
            )
            cc = col[ci]
            cc[glass] = np.array([0.12, 0.15, 0.19], np.float32) + 0.3 * L.sky_horizon.astype(np.float32)
            col[ci] = cc
        bus = mat == M_BUS
        if bus.any():
            bi2 = np.nonzero(bus)[0]
            zz = z[bi2]
            band = side_face[bi2] & (zz > 1.25) & (zz < 2.5) & (np.mod(along[bi2] + 100, 1.6) > 0.12)
            cb2 = col[bi2]
            cb2[band] = np.array([0.06, 0.08, 0.1], np.float32) + 0.2 * L.sky_horizon.astype(np.float32)
            cb2[zz < 0.6] *= 0.3
            col[bi2] = cb2
        fol = mat == M_FOLIAGE
        if fol.any():
            fi = np.nonzero(fol)[0]
            pf = si.p[h[fi]]
            nz = hash01(np.floor(pf[:, 0] * 3) + np.floor(pf[:, 2] * 3) * 131, np.floor(pf[:, 1] * 3), 9)
            col[fi] *= (0.7 + 0.6 * nz)[:, None]
        per = mat == M_PERSON
        if per.any():
            pi = np.nonzero(per)[0]
            legs = lz[pi] < -0.1 * half[pi, 2]
            cp = col[pi]
            cp[legs] = (0.12, 0.12, 0.18)
            col[pi] = cp
        lamp = mat == M_LAMP
        if lamp.any() and L.lights_on:
            em[lamp] = (2.0, 1.8, 1.3)
        tl = mat == M_TRAFFIC_LIGHT
        if tl.any():
            ti = np.nonzero(tl)[0]
            disc = side_face[ti] & (np.abs(along[ti]) < 0.1) & (np.abs(np.mod(lz[ti] + 0.45, 0.3) - 0.15) < 0.09)
            slot = np.floor((lz[ti] + 0.45) / 0.3)  # 0 bottom (green) .. 2 top (red)
            on = np.where(key[ti] < 0.5, 2, 0)
            colour = np.where(
                (slot == 2)[:, None],
                np.array([1.0, 0.1, 0.05], np.float32),
                np.where(
                    (slot == 1)[:, None], np.array([1.0, 0.7, 0.1], np.float32), np.array([0.1, 1.0, 0.4], np.float32)
                ),
            )
            lit = disc & (slot == on)
            et = em[ti]
            et[lit] = colour[lit] * 1.5
            ct = col[ti]
            ct[disc & ~lit] = colour[disc & ~lit] * 0.2
            col[ti] = ct
            em[ti] = et
        albedo[h] = col
        emissive[h] += em

    hit = si.pid != PID_SKY
    hi = np.nonzero(hit)[0]
    if len(hi):
        nrm = normal[hi]
        sun = L.sun_dir.astype(np.float32)
        lambert = np.clip(nrm @ sun, 0.0, None)
        if smap is not None and L.shadows:
            # Only sunlit-facing points need the lookup; a normal offset of about one shadow-map texel avoids
            # self-shadowing ("acne") at grazing light.
            facing = np.nonzero(lambert > 0)[0]
            lambert[facing] *= smap.lit(si.p[hi[facing]], 0.4 * nrm[facing])
        light = (
            L.ambient.astype(np.float32)[None] * (0.75 + 0.25 * nrm[:, 2:3])
            + lambert[:, None] * L.sun_color.astype(np.float32)[None]
        )
        if L.lights_on:
            light = light + _artificial_light(world, si.p[hi], nrm, si.ego_to_world)
        rgb[hi] = albedo[hi] * light + emissive[hi]

    # Sky.
    sk = np.nonzero(~hit)[0]
    if len(sk):
        dn = si.d[sk] / np.linalg.norm(si.d[sk], axis=1, keepdims=True)
        el = np.clip(dn[:, 2], 0.0, 1.0).astype(np.float32)
        w = np.sqrt(el)[:, None]
        sky = L.sky_horizon[None].astype(np.float32) * (1 - w) + L.sky_zenith[None].astype(np.float32) * w
        if L.weather in ("clear",) and L.time_of_day != "night":
            cosang = np.clip(dn @ L.sun_dir, 0, 1).astype(np.float32)
            sky = sky + L.sun_color.astype(np.float32)[None] * (0.5 * cosang**48 + (cosang > 0.9995))[:, None]
            # A few fair-weather clouds on a virtual plane above the scene.
            px, py = dn[:, 0] / (dn[:, 2] + 0.05), dn[:, 1] / (dn[:, 2] + 0.05)
            cl = 0.65 * value_noise(px, py, 0.9, 31) + 0.35 * value_noise(px, py, 0.3, 32)
            cover = (np.clip((cl - 0.58) * 4.0, 0, 1) * np.clip(el * 8.0, 0, 1))[:, None]
            cloud = np.float32(0.92) * (L.ambient.astype(np.float32) + L.sun_color.astype(np.float32) * 0.6)
            sky = sky * (1 - cover) + np.clip(cloud, 0, 1)[None] * cover
        elif L.weather in ("overcast", "rain"):
            cl = value_noise(dn[:, 0] / (dn[:, 2] + 0.08), dn[:, 1] / (dn[:, 2] + 0.08), 0.6, 21)
            sky = sky * (0.88 + 0.2 * cl)[:, None]
        if L.night:
            stars = (
                (
                    hash01(np.floor(dn[:, 0] * 400), np.floor(dn[:, 1] * 400) + np.floor(dn[:, 2] * 400) * 977, 17)
                    > 0.9985
                )
                & (el > 0.05)
                & (L.weather == "clear")
            )
            sky = sky + stars[:, None] * 0.6
        rgb[sk] = sky

    # Fog / aerial perspective.
    if len(hi):
        f = np.exp(-si.t[hi] / L.fog_distance).astype(np.float32)[:, None]
        rgb[hi] = rgb[hi] * f + L.fog_color.astype(np.float32)[None] * (1 - f)
    if L.weather == "fog" and len(sk):
        rgb[sk] = rgb[sk] * 0.15 + L.fog_color.astype(np.float32)[None] * 0.85
    return rgb, sem


def _artificial_light(world, p: np.ndarray, nrm: np.ndarray, ego_to_world: np.ndarray) -> np.ndarray:
    """Street lights (warm pools under lamps) and the ego's headlights."""
    out = np.zeros((p.shape[0], 3), np.float32)
    lamps = world.lamps
    ego_xyz = ego_to_world[:3, 3]
    rel = (p - ego_xyz).astype(np.float32)  # small magnitudes: float32 is plenty for lighting
    if len(lamps):
        dist = np.linalg.norm(lamps[:, :2] - ego_xyz[:2], axis=1)
        near = lamps[np.argsort(dist, kind="stable")[:10]]  # the 10 nearest lamps light the scene
        near = near[np.linalg.norm(near[:, :2] - ego_xyz[:2], axis=1) < 70.0]
        if len(near):
            lrel = (near - ego_xyz).astype(np.float32)  # (L,3)
            strength = np.float32(40.0 if world.lighting.night else 15.0)
            dist2 = (
                np.einsum("ij,ij->i", rel, rel)[:, None] - 2 * rel @ lrel.T + np.einsum("ij,ij->i", lrel, lrel)[None]
            )  # (N,L)
            dist2 = np.maximum(dist2, 1e-4)
            vdotn = nrm @ lrel.T - np.einsum("ij,ij->i", rel, nrm)[:, None]
            inv_len = 1.0 / np.sqrt(dist2)
            cosn = np.clip(vdotn * inv_len, 0, 1)
            # Lamps shine downwards: a spot factor on the angle below the lamp.
            down = np.clip((lrel[None, :, 2] - rel[:, 2:3]) * inv_len, 0, 1)
            total = (strength * cosn * down * down / (dist2 + 12.0)).sum(axis=1)
            out += total[:, None] * np.array([1.0, 0.78, 0.5], np.float32)
    if world.lighting.night:
        r = ego_to_world[:3, :3]
        pe = rel @ r.astype(np.float32)  # world offset -> ego axes
        xe, ye = pe[:, 0] - 2.0, pe[:, 1]
        width = 0.3 * np.maximum(xe, 0) + 1.0
        soft = np.clip(1.0 - np.abs(ye) / width, 0, 1)
        inten = np.where(xe > 0, 1.4 * soft * np.exp(-xe / 22.0) * np.clip(xe / 3.0, 0, 1), 0.0)
        out += inten[:, None].astype(np.float32) * np.array([1.0, 0.97, 0.9], np.float32)
    return out


def rain_streaks(rgb: np.ndarray, rng: np.random.Generator, count: int = 0) -> None:
    """Draw short, light, slanted streaks into (H,W,3) float32 in place."""
    hgt, wid, _ = rgb.shape
    count = count or max(20, hgt * wid // 300)
    x0 = rng.uniform(0, wid, count)
    y0 = rng.uniform(-10, hgt, count)
    length = rng.uniform(0.06, 0.16, count) * hgt
    slant = rng.uniform(0.15, 0.3)
    steps = np.linspace(0, 1, 16)
    xs = (x0[:, None] + slant * length[:, None] * steps[None]).astype(np.int64).ravel()
    ys = (y0[:, None] + length[:, None] * steps[None]).astype(np.int64).ravel()
    ok = (xs >= 0) & (xs < wid) & (ys >= 0) & (ys < hgt)
    rgb[ys[ok], xs[ok]] = rgb[ys[ok], xs[ok]] * 0.7 + 0.3 * 0.85


def render_frame(
    world, t: int, cams: list[Camera], view_ids: list[int], ego_to_world: np.ndarray, smap: ShadowMap | None = None
) -> dict:
    """Render all `cams` at frame t. Returns rgb (V,H,W,3) uint8, depth (V,H,W) float32, dynamic, semantic."""
    prims = world.prims_at(t)
    ts, pids, ps, ds, shapes = [], [], [], [], []
    for cam in cams:
        hits, o, d = trace(cam, prims)
        p = o + hits.t[..., None] * d
        p = np.where(np.isfinite(hits.t)[..., None], p, 0.0)
        ts.append(hits.t.ravel())
        pids.append(hits.pid.ravel())
        ps.append(p.reshape(-1, 3))
        ds.append(d.reshape(-1, 3))
        shapes.append(hits.t.shape)
    si = ShadeInput(np.concatenate(ts), np.concatenate(pids), np.concatenate(ps), np.concatenate(ds), ego_to_world)
    if smap is None and world.lighting.shadows:
        smap = shadow_map(prims, world.lighting.sun_dir, ego_to_world[:3, 3])
    rgb, sem = shade(world, prims, si, smap)
    out_rgb, out_depth, out_dyn, out_sem = [], [], [], []
    moving = np.array([a.moving for a in world.agents] + [False], bool)
    off = 0
    for cam, vid, shp in zip(cams, view_ids, shapes):
        npx = shp[0] * shp[1]
        img = rgb[off : off + npx].reshape(shp[0], shp[1], 3)
        if world.lighting.rain:
            ss = np.random.SeedSequence([world.scenario.seed, 104729, t, vid])
            rain_streaks(img, np.random.Generator(np.random.PCG64(ss)))
        out_rgb.append(np.round(np.clip(img, 0, 1) * 255).astype(np.uint8))
        tt = si.t[off : off + npx].reshape(shp)
        out_depth.append(tt.astype(np.float32))
        pid = si.pid[off : off + npx].reshape(shp)
        agent = np.where(pid >= 0, prims.agent[np.maximum(pid, 0)], -1)
        out_dyn.append(moving[agent])  # agent -1 indexes the trailing False
        out_sem.append(sem[off : off + npx].reshape(shp))
        off += npx
    return {
        "rgb": np.stack(out_rgb),
        "depth": np.stack(out_depth),
        "dynamic": np.stack(out_dyn),
        "semantic": np.stack(out_sem),
    }
