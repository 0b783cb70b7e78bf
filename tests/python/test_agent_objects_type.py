"""Scene4D's agent objects: one canonical set per agent in its box frame, posed per frame by its track."""

import math

import numpy as np
import pytest
import torch

from worldsplat.core.camera import default_rig
from worldsplat.gaussians.types import AgentObject, Gaussians, Scene4D


def _pose(x: float, yaw: float) -> np.ndarray:
    m = np.eye(4)
    c, s = math.cos(yaw), math.sin(yaw)
    m[:2, :2] = [[c, -s], [s, c]]
    m[0, 3] = x
    return m


def _object(present=(True, True, False)) -> AgentObject:
    g = Gaussians.from_numpy(
        [[1.0, 0.0, 0.5], [-1.0, 0.0, 0.5]], [[1, 0, 0, 0]] * 2, [[0.1] * 3] * 2, [1, 1], [[1, 0, 0], [0, 1, 0]]
    )
    poses = np.stack([_pose(0, 0), _pose(5, math.pi / 2), _pose(9, 0)])
    return AgentObject(7, 1, [4.0, 2.0, 1.5], g, poses, np.array(present))


def test_posed_object_moves_and_turns_with_its_track():
    o = _object()
    np.testing.assert_allclose(o.at_frame(0).means.numpy(), [[1, 0, 0.5], [-1, 0, 0.5]], atol=1e-6)
    # frame 1: translated to x=5 and turned 90 degrees: the box's forward point lands at +y
    np.testing.assert_allclose(o.at_frame(1).means.numpy(), [[5, 1, 0.5], [5, -1, 0.5]], atol=1e-6)
    assert len(o.at_frame(2)) == 0  # absent


def test_scene_bakes_objects_into_per_frame_sets():
    rig = default_rig(64, 32)
    empty = Gaussians.empty()
    sc = Scene4D(empty, [empty] * 3, np.arange(3) / 10, rig, np.stack([np.eye(4)] * 3), {}, [_object()])
    assert [len(sc.at_frame(t)) for t in range(3)] == [2, 2, 0]
    baked = sc.baked()
    assert baked.objects == [] and [len(d) for d in baked.dynamic] == [2, 2, 0]
    assert torch.equal(baked.dynamic[1].means, sc.dynamic_at(1).means)


def test_object_pose_count_must_match_the_scene():
    rig = default_rig(64, 32)
    empty = Gaussians.empty()
    with pytest.raises(ValueError, match="agent object 7 has 3 poses"):
        Scene4D(empty, [empty] * 2, np.arange(2) / 10, rig, np.stack([np.eye(4)] * 2), {}, [_object()])
    with pytest.raises(ValueError, match="3 poses but 2 flags"):
        _object(present=(True, False))
