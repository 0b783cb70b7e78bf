"""A caption composed from the layout: weather, time, road, traffic counts and notable objects."""

from __future__ import annotations

import math

from worldsplat.world.classes import BUS, CAR, CYCLIST, PEDESTRIAN, TRUCK

_CLASS_WORD = {CAR: "car", BUS: "bus", TRUCK: "truck", PEDESTRIAN: "pedestrian", CYCLIST: "cyclist"}
_NUM = ("no", "one", "two", "three", "four", "five", "six", "seven", "eight", "nine", "ten")


def _count(n: int, word: str) -> str:
    plural = word + ("es" if word.endswith("s") else "s")
    return f"{_NUM[n] if n < len(_NUM) else n} {word if n == 1 else plural}"


def _article(word: str) -> str:
    return "an" if word[0] in "aeiou" else "a"


def _lane_phrase(world, agent) -> str | None:
    """Where an agent is relative to the ego at frame 0 ("ahead in the left lane", "oncoming", ...)."""
    x, y, _ = agent.poses[0]
    where = agent.where
    if where[0] == "parked":
        return "parked on the " + ("right" if where[2] < 0 else "left")
    if where[0] == "sidewalk":
        return "on the sidewalk"
    _, road_name, direction, lane = where
    if road_name == "cross":
        return "on the crossing road"
    if direction < 0:
        return "oncoming"
    rel = lane - world.scenario.ego.start_lane
    pos = "ahead" if x > 0 else "behind"
    if rel == 0:
        return f"{pos} in the ego lane"
    side = "left" if rel > 0 else "right"
    return f"{pos} in the {side} lane" if abs(rel) == 1 else f"{pos}, {abs(rel)} lanes to the {side}"


def compose_caption(world) -> str:
    sc = world.scenario
    env, road = sc.environment, sc.road
    weather = {"clear": "clear", "overcast": "overcast", "rain": "rainy", "fog": "foggy"}[env.weather]
    time = {"day": "day", "dusk": "dusk", "night": "night"}[env.time_of_day]
    shape = {
        "straight": "straight",
        "curve": ("left-curving" if road.curvature > 0 else "right-curving") if road.curvature != 0 else "straight",
        "intersection": "four-way intersection",
    }[road.kind]
    if road.kind == "intersection":
        road_text = f"{_article(road.setting)} {road.setting} road at a four-way intersection"
    elif road.setting == "highway":
        road_text = f"{_article(shape)} {shape} highway"
    else:
        road_text = f"{_article(shape)} {shape} {road.setting} road"
    lanes = _count(road.lanes_per_direction, "lane")
    first = f"{_article(weather).capitalize()} {weather} {time} on {road_text} with {lanes} in each direction."
    man = {
        "keep_lane": "keeps its lane",
        "lane_change_left": "changes lane to the left",
        "lane_change_right": "changes lane to the right",
        "turn_left": "turns left",
        "turn_right": "turns right",
    }
    kmh = round(sc.ego.speed * 3.6)
    second = f"The ego car {man[sc.ego.manoeuvre]} at {kmh} km/h." if kmh > 0 else "The ego car is stopped."
    agents = world.agents
    moving_veh = sum(1 for a in agents if a.moving and a.cls in (CAR, BUS, TRUCK))
    parked = sum(1 for a in agents if not a.moving and a.cls == CAR)
    peds = sum(1 for a in agents if a.cls == PEDESTRIAN)
    cyc = sum(1 for a in agents if a.cls == CYCLIST)
    parts = []
    if moving_veh:
        parts.append(_count(moving_veh, "moving vehicle"))
    if parked:
        parts.append(_count(parked, "parked car"))
    if peds:
        parts.append(_count(peds, "pedestrian"))
    if cyc:
        parts.append(_count(cyc, "cyclist"))
    if parts:
        third = (
            "There "
            + ("is " if parts[0].startswith("one ") else "are ")
            + (", ".join(parts[:-1]) + " and " + parts[-1] if len(parts) > 1 else parts[0])
            + "."
        )
    else:
        third = "There is no other traffic."
    # Notable objects: big vehicles first, then the nearest vehicles in front of the ego.
    scored = []
    for a in agents:
        if a.cls not in (CAR, BUS, TRUCK, CYCLIST):
            continue
        x, y, _ = a.poses[0]
        dist = math.hypot(x, y)
        if dist > 60:
            continue
        score = (
            dist - (40 if a.cls in (BUS, TRUCK) else 0) - (10 if x > 0 and a.moving else 0) + (0 if a.moving else 30)
        )
        scored.append((score, a.track_id, a))
    scored.sort(key=lambda t: (t[0], t[1]))
    notes = []
    for _, _, a in scored[:2]:
        word = _CLASS_WORD[a.cls]
        desc = f"{a.color_name} {word}" if a.color_name else word
        phrase = _lane_phrase(world, a)
        notes.append(f"{_article(desc)} {desc} {phrase}")
    text = " ".join([first, second, third])
    if notes:
        text += " Notable: " + "; ".join(notes) + "."
    if world.lighting.lights_on:
        text += " Street lights are on."
    return text
