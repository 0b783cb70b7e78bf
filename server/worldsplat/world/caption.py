"""Captions and the world: a caption composed from the layout (weather, time, road, traffic counts and notable
objects), and the colour words of a scenario's own caption given to its agents."""

from __future__ import annotations

import dataclasses
import math
import re

from worldsplat.world.classes import BUS, CAR, CYCLIST, PEDESTRIAN, TRUCK
from worldsplat.world.colours import COLOUR_WORDS

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


# -- colour words of a scenario's caption -------------------------------------------------------------------------
_CLASS_WORDS = {
    **dict.fromkeys(("car", "cars"), (CAR,)),
    **dict.fromkeys(("vehicle", "vehicles"), (CAR, BUS, TRUCK)),
    **dict.fromkeys(("bus", "buses"), (BUS,)),
    **dict.fromkeys(("truck", "trucks", "lorry", "lorries"), (TRUCK,)),
    **dict.fromkeys(("pedestrian", "pedestrians", "person", "people", "man", "woman", "walker"), (PEDESTRIAN,)),
    **dict.fromkeys(("cyclist", "cyclists", "bike", "bicycle", "rider"), (CYCLIST,)),
}
_NOT_AN_ADJECTIVE = {"a", "an", "the", "and", "or", "of", "to", "with", "is", "are", "was", "in", "on", "at"}


def caption_colours(text: str | None) -> list[tuple[str, tuple[int, ...]]]:
    """The (colour word, classes) pairs a caption names, in caption order: a colour word followed by a class word,
    with at most one other word between them ("a red car", "a blue delivery truck"); not across punctuation."""
    out = []
    for clause in re.split(r"[.,;:!?()]", (text or "").lower()):
        words = re.findall(r"[a-z]+", clause)
        for i, word in enumerate(words):
            if word not in COLOUR_WORDS:
                continue
            for j in (i + 1, i + 2):
                if j < len(words) and words[j] in _CLASS_WORDS:
                    out.append((word, _CLASS_WORDS[words[j]]))
                    break
                if j < len(words) and (words[j] in _NOT_AN_ADJECTIVE or words[j] in COLOUR_WORDS):
                    break
    return out


def apply_caption_colours(agents: list, caption: str | None) -> list:
    """The agents with the caption's colour words given to them: each (colour, class) phrase in caption order colours
    the nearest agent of that class at frame 0 that carries no asked colour yet (no `agents[i].colour`, no earlier
    phrase), ahead of the ego before behind it ("a red car ahead" colours the nearest car ahead red). A phrase
    without such an agent is left unused. The world draws the colour as if `agents[i].colour` had asked for it."""
    out = list(agents)
    for word, classes in caption_colours(caption):
        free = [i for i, a in enumerate(out) if a.cls in classes and not a.colour_asked]
        if not free:
            continue
        i = min(free, key=lambda i: _ahead_then_nearest(out[i]))
        out[i] = dataclasses.replace(out[i], color=COLOUR_WORDS[word], color_name=word, colour_asked=True)
    return out


def _ahead_then_nearest(agent) -> tuple:
    """Sort key: agents ahead of the ego at frame 0 (the ego starts at the origin facing +x) first, then by distance."""
    x, y = float(agent.poses[0, 0]), float(agent.poses[0, 1])
    return (x <= 0.0, math.hypot(x, y), agent.track_id)
