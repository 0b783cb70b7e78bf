"""The procedural driving world with exact ground truth (see web/docs/world.md).

world = build_world(scenario)        # deterministic by scenario.seed
clip = simulate(world, shift_m=0.0)  # RGB, depth, dynamic mask, semantics for every camera and frame
cond = world.conditions(shift_m)     # BEV, sketches, 3D boxes, ego trajectory, caption
"""

from worldsplat.world.layout import World, build_world
from worldsplat.world.simulate import Clip, render_views, simulate

__all__ = ["World", "build_world", "Clip", "simulate", "render_views"]
