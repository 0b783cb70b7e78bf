"""A world's appearance drawn again, its geometry kept: what a scenario leaves to chance besides the layout.

A scenario states the road, the agents, the weather and the time of day; the world then draws, from the seed, the
facade and house paints, the tree greens, the sign faces, each object's key (lit windows, patterns), the sun's
direction and the rain's streaks. None of these is in a generator's conditions (`layout_maps`: "colours and lighting
are absent"). `redraw_appearance` draws them again from their own distributions (`layout.FACADES`, `HOUSES`,
`tree_green`, `SIGN_COLOURS`, `lighting.make_lighting`), so a set of redraws is a sample of the images a scenario's
conditions allow: the ground truth is one of them, and no generator of these conditions can be nearer to it, on
average, than their mean is (`worldsplat.evaluation.appearance_ceiling`).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from worldsplat.world.layout import FACADES, HOUSES, SIGN_COLOURS, World, tree_green
from worldsplat.world.lighting import make_lighting
from worldsplat.world.prims import M_BUILDING, M_FOLIAGE, M_HOUSE, M_SIGN, M_TRAFFIC_LIGHT, Prims

# what a redraw may change: the static objects' paints and keys, and the light (the sun's direction, the rain)
PARTS = ("materials", "light")


def redraw_appearance(world: World, seed: int, parts: tuple[str, ...] = PARTS) -> World:
    """`world` with the appearance its seed drew drawn again by `seed`: "materials", each static object's paint
    from its palette and its key; "light", the sun's direction and the scenario seed the rain's streaks come from.
    The geometry, the agents (their paint is the scenario's when asked, and generate draws them itself), the
    caption and the conditions are the world's."""
    unknown = set(parts) - set(PARTS)
    if unknown:
        raise ValueError(f"redraw_appearance: unknown parts {sorted(unknown)}; parts are {', '.join(PARTS)}")
    rng = np.random.default_rng(seed)
    out = dataclasses.replace(world)
    if "materials" in parts:
        out.static = _materials(world.static, rng)
    if "light" in parts:
        L = world.lighting
        out.lighting = make_lighting(L.time_of_day, L.weather, rng)
        out.scenario = world.scenario.model_copy(update={"seed": int(rng.integers(2**31))})
    return out


def _materials(prims: Prims, rng: np.random.Generator) -> Prims:
    colour, key = prims.color.copy(), prims.key.copy()
    for i, m in enumerate(prims.material):
        if m == M_BUILDING:
            colour[i] = FACADES[int(rng.integers(len(FACADES)))]
        elif m == M_HOUSE:
            colour[i] = HOUSES[int(rng.integers(len(HOUSES)))]
        elif m == M_FOLIAGE:
            colour[i] = tree_green(float(rng.random()), float(rng.random()))
        elif m == M_SIGN:
            colour[i] = SIGN_COLOURS[int(rng.integers(len(SIGN_COLOURS)))]
        if m in (M_BUILDING, M_HOUSE, M_FOLIAGE, M_SIGN, M_TRAFFIC_LIGHT):
            key[i] = rng.random()
    return dataclasses.replace(prims, color=colour, key=key)
