"""Agent colours: the world's palettes, the colour words captions use, and scenario colours ("#rrggbb").

An agent's colour is the albedo of its paint (a vehicle's body) or clothing (a person's or cyclist's top): the
renderer multiplies it by the light. The palettes are what the world draws when the scenario asks for no colour;
`agents[i].colour` or a colour word of the caption (`world.caption.apply_caption_colours`) asks for one.
"""

from __future__ import annotations

import math

Rgb = tuple[float, float, float]

VEHICLE_COLOURS: tuple[tuple[str, Rgb], ...] = (
    ("white", (0.82, 0.83, 0.84)),
    ("black", (0.05, 0.05, 0.06)),
    ("silver", (0.58, 0.6, 0.63)),
    ("grey", (0.32, 0.33, 0.35)),
    ("red", (0.62, 0.07, 0.06)),
    ("blue", (0.1, 0.2, 0.55)),
    ("green", (0.12, 0.34, 0.16)),
    ("yellow", (0.86, 0.68, 0.1)),
    ("brown", (0.36, 0.22, 0.12)),
)
BUS_COLOURS: tuple[tuple[str, Rgb], ...] = (
    ("red", (0.7, 0.08, 0.06)),
    ("yellow", (0.9, 0.7, 0.08)),
    ("blue", (0.1, 0.25, 0.6)),
    ("white", (0.85, 0.86, 0.88)),
)
TRUCK_COLOURS: tuple[tuple[str, Rgb], ...] = (
    ("white", (0.85, 0.85, 0.86)),
    ("orange", (0.85, 0.4, 0.08)),
    ("green", (0.15, 0.4, 0.2)),
    ("blue", (0.12, 0.22, 0.5)),
)
CLOTHES: tuple[Rgb, ...] = (
    (0.7, 0.1, 0.1),
    (0.1, 0.3, 0.7),
    (0.9, 0.9, 0.85),
    (0.15, 0.15, 0.15),
    (0.85, 0.65, 0.1),
    (0.2, 0.5, 0.3),
    (0.6, 0.3, 0.5),
)

# The colour words a caption may use, as the car paint the world draws for them (plus three it has no paint for).
COLOUR_WORDS: dict[str, Rgb] = {
    **dict(VEHICLE_COLOURS),
    "gray": dict(VEHICLE_COLOURS)["grey"],
    "orange": dict(TRUCK_COLOURS)["orange"],
    "purple": (0.4, 0.16, 0.5),
    "pink": (0.9, 0.5, 0.62),
}


def hex_rgb(text: str) -> Rgb:
    """ "#rrggbb" as RGB in [0, 1]."""
    return tuple(int(text[i : i + 2], 16) / 255.0 for i in (1, 3, 5))


def colour_word(rgb: Rgb) -> str:
    """The colour word nearest to an RGB colour (what a composed caption calls it)."""
    return min(COLOUR_WORDS, key=lambda w: (math.dist(COLOUR_WORDS[w], rgb), w))
