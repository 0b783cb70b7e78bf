"""Agent appearance: the scenario's agent colour, the world drawing it, caption colour words, and the object generator
(an agent's canonical Gaussians from class, size, seed and colour) checked by rendering it."""

from __future__ import annotations

import hashlib
import math

import numpy as np
import pytest
import torch

from worldsplat.core.camera import Camera, yaw_pose
from worldsplat.core.scenario import Scenario, ScenarioError, load_preset, scenario_id
from worldsplat.evaluation.agent_appearance import (
    TARGET,
    asked_colour_in_world,
    colour_distance,
    fit,
    front_camera,
)
from worldsplat.gaussians.agent_appearance import agent_gaussians
from worldsplat.gaussians.raster import render_view
from worldsplat.gaussians.types import transform
from worldsplat.world.caption import caption_colours
from worldsplat.world.classes import BUS, CAR, CYCLIST, PEDESTRIAN, TRUCK
from worldsplat.world.colours import COLOUR_WORDS, hex_rgb
from worldsplat.world.layout import build_world
from worldsplat.world.lighting import make_lighting
from worldsplat.world.simulate import simulate

NO_TRAFFIC = {"moving_vehicles": 0, "parked_vehicles": 0, "pedestrians": 0, "cyclists": 0}


def _car(agent_id: str, s: float, colour: str | None = None, lane: int = 0) -> dict:
    spec = {"id": agent_id, "class": "car", "start": {"kind": "lane", "lane": lane, "s": s}}
    return spec if colour is None else {**spec, "colour": colour}


# -- the scenario field ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize("bad", ["red", "#12345", "#gg0000", "c81e1e", 12, [200, 30, 30]])
def test_a_bad_colour_is_refused_naming_the_agent_and_the_value(bad):
    with pytest.raises(ScenarioError) as e:
        Scenario.parse({"agents": [_car("a", 10.0), {**_car("b", 30.0), "colour": bad}]})
    assert e.value.errors == [
        f'agents[1].colour: {bad!r} is not a colour: give it as "#rrggbb" (hex, e.g. "#c81e1e" for red)'
    ]


def test_colour_is_kept_lower_case_and_left_out_of_the_canonical_json_when_unset():
    plain = Scenario.parse({"agents": [_car("a", 10.0)]})
    assert "colour" not in plain.normalized_json()
    assert scenario_id(plain) == scenario_id(Scenario.parse({"agents": [{**_car("a", 10.0), "colour": None}]}))
    red = Scenario.parse({"agents": [_car("a", 10.0, "#C81E1E")]})
    assert red.agents[0].colour == "#c81e1e" and '"colour":"#c81e1e"' in red.normalized_json()
    assert scenario_id(red) != scenario_id(plain)
    assert Scenario.parse(red.normalized_json()) == red  # round trip


# -- the world draws it ----------------------------------------------------------------------------------------------
def _pixels_hash(name: str) -> str:
    """The world's outputs for a preset, small (the same computation pinned before agent colours existed)."""
    world = build_world(load_preset(name).with_updates(image={"width": 96, "height": 64}, clip={"frames": 2}))
    clip = simulate(world)
    h = hashlib.sha256()
    for k in ("rgb", "depth", "semantic", "dynamic"):
        h.update(getattr(clip, k).tobytes())
    h.update(world.caption.encode())
    return h.hexdigest()[:16]


@pytest.mark.parametrize("name, pinned", [("urban_straight", "9bbd09163c09062a"), ("cut_in", "f0693dc529bf7534")])
def test_worlds_without_an_asked_colour_render_as_before(name, pinned):
    # Hashes of RGB, depth, semantics, dynamic masks and caption written by the world before agents could be given a
    # colour: scenarios without one (explicit agents included: cut_in) are bit-identical.
    assert _pixels_hash(name) == pinned


@pytest.mark.parametrize(
    "cls, start, colour",
    [
        ("car", {"kind": "lane", "s": 14.0}, "#c81e1e"),
        ("car", {"kind": "lane", "s": 14.0}, "#e8e8e0"),
        ("pedestrian", {"kind": "pose", "x": 9.0, "y": -4.0, "yaw_deg": 90.0}, "#2050d0"),
        ("cyclist", {"kind": "lane", "s": 12.0, "lateral": -1.0}, "#30a040"),
    ],
)
def test_the_world_draws_an_asked_colour_within_the_target(cls, start, colour):
    sc = Scenario.parse(
        {"seed": 3, "traffic": NO_TRAFFIC, "agents": [{"id": "x", "class": cls, "start": start, "colour": colour}]}
    )
    world = build_world(sc)
    assert world.agents[0].color == hex_rgb(colour) and world.agents[0].colour_asked
    r = asked_colour_in_world(sc, "x")
    assert r["pixels"] > 200  # paint or clothing pixels of that agent, not the image
    assert r["error"] <= TARGET, r
    other = asked_colour_in_world(
        sc.with_updates(agents=[{**sc.agents[0].model_dump(by_alias=True), "colour": "#808080"}]), "x"
    )
    assert colour_distance(other["lit"], r["lit"]) > 0.05  # the render follows the colour asked


# -- caption colour words --------------------------------------------------------------------------------------------
def test_caption_colour_phrases_are_a_colour_word_then_a_class_word():
    assert caption_colours("A red car ahead and a blue delivery truck; a man in yellow.") == [
        ("red", (CAR,)),
        ("blue", (TRUCK,)),
    ]
    assert caption_colours("The light is red, a car waits. A slow truck.") == []
    assert caption_colours("a red and white bus, a grey vehicle, a green cyclist") == [
        ("white", (BUS,)),
        ("grey", (CAR, BUS, TRUCK)),
        ("green", (CYCLIST,)),
    ]
    assert caption_colours(None) == []


def test_a_caption_colour_word_colours_the_nearest_agent_ahead_without_a_colour():
    agents = [_car("behind", -7.0), _car("near", 15.0, lane=1), _car("far", 35.0)]
    sc = Scenario.parse({"traffic": NO_TRAFFIC, "agents": agents, "caption": "A red car ahead of a blue car."})
    by_id = {a.agent_id: a for a in build_world(sc).agents}
    assert by_id["near"].color == COLOUR_WORDS["red"] and by_id["near"].color_name == "red"
    assert by_id["far"].color == COLOUR_WORDS["blue"]  # the second phrase takes the next nearest ahead
    assert not by_id["behind"].colour_asked and by_id["near"].colour_asked
    # An agent with its own colour keeps it; the word goes to the nearest one without.
    asked = Scenario.parse({**sc.to_json_dict(), "agents": [agents[0], _car("near", 15.0, "#00ff00", 1), agents[2]]})
    by_id = {a.agent_id: a for a in build_world(asked).agents}
    assert by_id["near"].color == hex_rgb("#00ff00") and by_id["far"].color == COLOUR_WORDS["red"]
    assert by_id["behind"].color == COLOUR_WORDS["blue"]  # nothing left ahead: behind it is


# -- the object generator --------------------------------------------------------------------------------------------
SIZES = {CAR: (4.5, 1.85, 1.5), BUS: (11.0, 2.55, 3.15), TRUCK: (7.5, 2.45, 3.3), PEDESTRIAN: (0.5, 0.6, 1.75)}
SIZES[CYCLIST] = (1.8, 0.6, 1.92)


def _look_at(cls: int, yaw_deg: float, distance: float, height: float = 1.5) -> tuple[Camera, np.ndarray]:
    """A 400x224 camera at the origin looking along +x, and the object's box_to_world `distance` m ahead."""
    cam = front_camera(2)
    size = SIZES[cls]
    return cam, yaw_pose(1.7 + distance, 0.0, size[2] / 2, math.radians(yaw_deg))


def _sample(view, cam: Camera, box_to_world: np.ndarray, point) -> np.ndarray:
    """The rendered colour (0..1) at the pixel a box-frame point projects to."""
    p = box_to_world @ np.array([*point, 1.0])
    c = cam.world_to_camera @ p
    u, v = int(cam.fx * c[0] / c[2] + cam.cx), int(cam.fy * c[1] / c[2] + cam.cy)
    assert view.alpha[v, u] > 0.9, f"no object at box point {point}"
    return view.rgb[v, u].astype(np.float64) / 255.0


def _render(cls: int, yaw_deg: float, distance: float, colour=None, seed: int = 0):
    cam, pose = _look_at(cls, yaw_deg, distance)
    g = agent_gaussians(cls, SIZES[cls], seed, colour)
    return render_view(transform(g, pose), cam), cam, pose


def _lum(c: np.ndarray) -> float:
    return float(c @ [0.299, 0.587, 0.114])


def test_a_generated_car_has_a_body_darker_glazing_wheels_and_lamps():
    l, w, h = SIZES[CAR]
    paint = hex_rgb("#e0c020")
    side, cam, pose = _render(CAR, 90.0, 8.0, "#e0c020")  # its right side faces the camera (it drives to the left)
    z = lambda world_z: world_z - h / 2  # noqa: E731 - footprint height -> box frame
    body = _sample(side, cam, pose, (0.0, -w / 2, z(0.5)))
    glazing = _sample(side, cam, pose, (-0.06 * l, -w / 2 * 0.44, z(0.78 * h)))
    wheel_front = _sample(side, cam, pose, (l / 2 - 0.85, -w / 2, z(0.35)))
    wheel_rear = _sample(side, cam, pose, (-(l / 2 - 0.85), -w / 2, z(0.35)))
    assert colour_distance(body, paint) < 0.05
    assert _lum(glazing) < 0.6 * _lum(body) and colour_distance(glazing, paint) > 0.3
    assert max(wheel_front) < 0.1 and max(wheel_rear) < 0.1
    lamp_z = z(0.12 + (0.56 * h - 0.12) * (0.5 + 0.55 / 2))
    front, cam, pose = _render(CAR, 180.0, 8.0, "#202060")  # facing the camera
    head = _sample(front, cam, pose, (l / 2, w / 2 - 0.2, lamp_z))
    rear, cam, pose = _render(CAR, 0.0, 8.0, "#202060")
    tail = _sample(rear, cam, pose, (-l / 2, -(w / 2 - 0.2), lamp_z))
    assert min(head) > 0.65 and max(head) - min(head) < 0.1  # white head lamps on a dark blue car
    assert tail[0] > 0.6 and tail[1] < 0.15 and tail[2] < 0.15  # red tail lamps


def test_a_generated_person_is_a_figure_and_a_cyclist_a_rider_on_a_bike():
    clothes = hex_rgb("#2050d0")
    h = SIZES[PEDESTRIAN][2]
    view, cam, pose = _render(PEDESTRIAN, 180.0, 5.0, "#2050d0")
    top = _sample(view, cam, pose, (0.14, 0.0, 0.7 * h - h / 2))
    legs = _sample(view, cam, pose, (0.14, 0.0, 0.2 * h - h / 2))
    head = _sample(view, cam, pose, (0.075 * h, 0.0, 0.92 * h - h / 2))
    assert colour_distance(top, clothes) < 0.05
    assert _lum(legs) < 0.2 and colour_distance(legs, clothes) > 0.2  # dark trousers
    assert head[0] > head[2] + 0.2  # skin, not clothing
    hc = SIZES[CYCLIST][2]
    view, cam, pose = _render(CYCLIST, 90.0, 6.0, "#30a040")
    bike = _sample(view, cam, pose, (0.5, -0.07, 0.5 - hc / 2))
    rider = _sample(view, cam, pose, (-0.1, -0.21, 1.3 - hc / 2))
    helmet = _sample(view, cam, pose, (-0.05, -0.1, 1.8 - hc / 2))
    assert max(bike) < 0.15 and colour_distance(rider, hex_rgb("#30a040")) < 0.05
    assert helmet[0] > 0.7 and helmet[1] > 0.7 and helmet[2] < 0.4  # the world's yellow helmet


@pytest.mark.parametrize(
    "cls, iou", [("car", 0.88), ("bus", 0.9), ("truck", 0.9), ("pedestrian", 0.75), ("cyclist", 0.7)]
)
def test_a_generated_object_matches_the_worlds_agent_from_the_same_camera(cls, iou):
    for yaw in (30.0, 120.0):
        r = fit(cls, 5, yaw)
        assert r["pixels"] > 1000
        assert r["iou"] >= iou, (yaw, r)
        assert r["colour_error"] <= 0.08, (yaw, r)
    asked = fit(cls, 5, 60.0, colour="#1e50c8")
    assert asked["paint_pixels"] > 300 and asked["asked_error"] <= TARGET, asked


def test_the_generator_is_seeded_and_a_colour_changes_only_the_colour():
    a, b = agent_gaussians(CAR, SIZES[CAR], 7), agent_gaussians(CAR, SIZES[CAR], 7)
    for k in ("means", "quats", "scales", "opacities", "colors"):
        assert torch.equal(getattr(a, k), getattr(b, k))
    paints = {tuple(agent_gaussians(CAR, SIZES[CAR], s).colors.mode(0).values.tolist()) for s in range(12)}
    assert len(paints) >= 4  # the seed draws the paint
    red = agent_gaussians(CAR, SIZES[CAR], 7, "#c81e1e")
    assert torch.equal(red.means, a.means) and not torch.equal(red.colors, a.colors)
    assert 1500 <= len(a) <= 5000  # a few thousand Gaussians, once
    with pytest.raises(ValueError, match="not an agent class"):
        agent_gaussians(3, (1.0, 1.0, 1.0), 0)


def test_lit_objects_follow_the_scenes_light():
    rng = lambda: np.random.Generator(np.random.PCG64(1))  # noqa: E731
    day = agent_gaussians(CAR, SIZES[CAR], 2, "#c81e1e", lighting=make_lighting("day", "clear", rng()))
    night = agent_gaussians(CAR, SIZES[CAR], 2, "#c81e1e", lighting=make_lighting("night", "clear", rng()))
    albedo = agent_gaussians(CAR, SIZES[CAR], 2, "#c81e1e")
    assert night.colors.mean() < 0.5 * day.colors.mean()
    assert day.colors.mean() < albedo.colors.mean()
    assert (night.colors.max(1).values > 0.95).sum() > 10  # the lamps still glow at night


def test_at_night_the_headlights_light_an_object_ahead_as_the_world_lights_its_agent():
    """Without the lamps a generated truck 19 m ahead at night was black (0.03) where the world draws it grey (0.54):
    the ego's headlights light its rear, less from farther, and the world's lights are off by day."""
    from types import SimpleNamespace

    from worldsplat.gaussians.agent_appearance import clip_lamps

    rng = lambda: np.random.Generator(np.random.PCG64(1))  # noqa: E731
    night = make_lighting("night", "clear", rng())
    world = SimpleNamespace(lighting=night, lamps=np.zeros((0, 3)), ego_to_world=np.stack([np.eye(4)] * 2))

    def rear(ahead: float | None) -> float:
        lamps = None if ahead is None else clip_lamps(world, np.array([[ahead, 0.0, 0.0], [ahead, 0.0, 0.0]]))
        g = agent_gaussians(CAR, SIZES[CAR], 2, "#c8c8c8", lighting=night, lamps=lamps)
        back = g.means[:, 0] < -SIZES[CAR][0] / 2 + 0.02  # the rear face, towards the ego
        return float(g.colors[back].mean())

    assert rear(10.0) > 4 * rear(None) and rear(10.0) > 1.5 * rear(30.0) > 1.5 * rear(None)
    day = SimpleNamespace(
        lighting=make_lighting("day", "clear", rng()), lamps=np.zeros((0, 3)), ego_to_world=world.ego_to_world
    )
    assert clip_lamps(day, np.zeros((2, 3))) is None


def test_the_sun_lights_the_side_of_an_object_it_lights_at_the_agents_own_heading():
    """A bus whose shaded side faced the camera was drawn lit by the sun averaged over every heading (0.28 where the
    world drew 0.16): with the agent's headings, the face turned to the sun is the lit one."""
    light = make_lighting("day", "clear", np.random.Generator(np.random.PCG64(3)))
    to_left = math.atan2(light.sun_dir[1], light.sun_dir[0]) - math.pi / 2  # the yaw that turns the left side sunwards
    w = SIZES[CAR][1]

    def sides(headings) -> tuple[float, float]:
        g = agent_gaussians(CAR, SIZES[CAR], 2, "#c8c8c8", lighting=light, headings=headings)
        y = g.means[:, 1]
        return float(g.colors[y > w / 2 - 0.02].mean()), float(g.colors[y < -w / 2 + 0.02].mean())

    left, right = sides(np.array([to_left]))
    flipped = sides(np.array([to_left + math.pi]))
    every = sides(None)
    assert left > 1.5 * right and flipped[1] > 1.5 * flipped[0]
    assert right < every[1] < left and abs(every[0] - every[1]) < 0.1 * every[0]
