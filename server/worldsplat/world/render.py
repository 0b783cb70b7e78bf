"""Ground-truth renderer: vectorized numpy ray casting against the world's analytic primitives.

Per camera: primary rays (unit camera-z directions, so the ray parameter IS the camera-z depth) hit the ground
plane z = 0 analytically, then every primitive that survives frustum culling is tested only on the pixels of its
projected screen rectangle (box slab test / sphere quadratic) with a z-test. Shading is then done once for all
views of a frame: each surface's procedural texture (`world.surfaces`: asphalt noise, lane paint, paving, facade
windows, car lights), Lambert sun + sky ambient, shadows from a sun shadow map, street lights and headlights at night, wet roads and rain
streaks, and exponential fog by depth. Sky pixels have depth +inf and class SKY.
"""

from __future__ import annotations

import contextlib
import math
from dataclasses import dataclass

import numpy as np

from worldsplat.core.camera import Camera
from worldsplat.world.classes import SKY
from worldsplat.world.lighting import Lighting
from worldsplat.world.prims import BOX, Prims
from worldsplat.world.surfaces import ground_albedo, prim_hits, shade_prims, sky_colour, wet_reflection

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
    """Colour (N,3) float32 in [0,1] and semantic class (N,) uint8 for every ray: each surface's albedo and
    emission (`world.surfaces`), then light, the sky and fog."""
    L: Lighting = world.lighting
    n = si.t.shape[0]
    rgb = np.zeros((n, 3), np.float32)
    sem = np.full(n, SKY, np.uint8)
    albedo = np.zeros((n, 3), np.float32)
    emissive = np.zeros((n, 3), np.float32)
    normal = np.zeros((n, 3), np.float32)
    g = np.nonzero(si.pid == PID_GROUND)[0]
    if len(g):
        albedo[g], sem[g] = ground_albedo(world.road, si.p[g, 0], si.p[g, 1], L.weather == "rain")
        normal[g] = (0.0, 0.0, 1.0)
        if L.weather == "rain":
            emissive[g] += wet_reflection(si.d[g], L.sky_horizon)
    h = np.nonzero(si.pid >= 0)[0]
    if len(h):
        ph = prim_hits(prims, si.pid[h], si.p[h])
        sem[h] = prims.cls[ph.k]
        normal[h] = ph.normal
        shade_prims(ph, prims, si.p[h], L)
        albedo[h] = ph.col
        emissive[h] += ph.em
    hi = np.nonzero(si.pid != PID_SKY)[0]
    if len(hi):
        rgb[hi] = albedo[hi] * _light(world, si.p[hi], normal[hi], si.ego_to_world, smap) + emissive[hi]
    sk = np.nonzero(si.pid == PID_SKY)[0]
    if len(sk):
        rgb[sk] = sky_colour(L, si.d[sk])
    _fog(L, rgb, si.t, hi, sk)
    return rgb, sem


def _light(world, p: np.ndarray, nrm: np.ndarray, ego_to_world: np.ndarray, smap: ShadowMap | None) -> np.ndarray:
    """Light (n,3) arriving at surface points p with normals nrm: sky ambient, the sun (Lambert, shadowed), and
    street lights and headlights when the lights are on."""
    L: Lighting = world.lighting
    sun = L.sun_dir.astype(np.float32)
    lambert = np.clip(nrm @ sun, 0.0, None)
    if smap is not None and L.shadows:
        # Only sunlit-facing points need the lookup; a normal offset of about one shadow-map texel avoids
        # self-shadowing ("acne") at grazing light.
        facing = np.nonzero(lambert > 0)[0]
        lambert[facing] *= smap.lit(p[facing], 0.4 * nrm[facing])
    light = (
        L.ambient.astype(np.float32)[None] * (0.75 + 0.25 * nrm[:, 2:3])
        + lambert[:, None] * L.sun_color.astype(np.float32)[None]
    )
    if L.lights_on:
        light = light + artificial_light(world, p, nrm, ego_to_world)
    return light


def _fog(L: Lighting, rgb: np.ndarray, t: np.ndarray, hi: np.ndarray, sk: np.ndarray) -> None:
    """Aerial perspective by depth on surfaces (hi), and a fog-veiled sky (sk), in place."""
    if len(hi):
        f = np.exp(-t[hi] / L.fog_distance).astype(np.float32)[:, None]
        rgb[hi] = rgb[hi] * f + L.fog_color.astype(np.float32)[None] * (1 - f)
    if L.weather == "fog" and len(sk):
        rgb[sk] = rgb[sk] * 0.15 + L.fog_color.astype(np.float32)[None] * 0.85


def artificial_light(world, p: np.ndarray, nrm: np.ndarray, ego_to_world: np.ndarray) -> np.ndarray:
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
