"""Instance masks: which agent each pixel of a camera sees, from the same ray caster as the ground truth.

    ids = instance_mask(world, t, cam)        # (H,W) int32: index into world.agents, -1 for no agent
    n = unoccluded_pixels(world, t, cam, k)   # pixels agent k would cover with nothing in front of it

Used by the nuScenes export (visibility of each box, worldsplat.scale.nuscenes) and by the tests that check an
exported box lands on its agent.
"""

from __future__ import annotations

import numpy as np

from worldsplat.core.camera import Camera
from worldsplat.world.agents import place_parts
from worldsplat.world.layout import World
from worldsplat.world.render import single_threaded_blas, trace


def instance_mask(world: World, t: int, cam: Camera) -> np.ndarray:
    """(H,W) int32 agent index (into `world.agents`) of the surface each pixel sees at frame t, -1 elsewhere."""
    prims = world.prims_at(t)
    with single_threaded_blas():
        hits, _, _ = trace(cam, prims)
    return np.where(hits.pid >= 0, prims.agent[np.maximum(hits.pid, 0)], -1).astype(np.int32)


def unoccluded_pixels(world: World, t: int, cam: Camera, k: int) -> int:
    """Pixels agent k covers in `cam` at frame t with every other primitive removed (the ground stays)."""
    parts = place_parts(world.agent_template, world.agent_poses(t))
    own = parts.take(np.nonzero(parts.agent == k)[0])
    if not len(own):
        return 0
    with single_threaded_blas():
        hits, _, _ = trace(cam, own)
    return int((hits.pid >= 0).sum())
