"""Semantic classes of the world (one id per pixel in `clip.semantic`, one class per 3D box)."""

from __future__ import annotations

import numpy as np

(
    SKY,
    ROAD,
    LANE_MARKING,
    CROSSWALK,
    SIDEWALK,
    CURB,
    TERRAIN,
    BUILDING,
    VEGETATION,
    POLE,
    SIGN,
    BARRIER,
    CAR,
    BUS,
    TRUCK,
    PEDESTRIAN,
    CYCLIST,
) = range(17)

CLASS_NAMES: tuple[str, ...] = (
    "sky",
    "road",
    "lane_marking",
    "crosswalk",
    "sidewalk",
    "curb",
    "terrain",
    "building",
    "vegetation",
    "pole",
    "sign",
    "barrier",
    "car",
    "bus",
    "truck",
    "pedestrian",
    "cyclist",
)
AGENT_CLASSES = (CAR, BUS, TRUCK, PEDESTRIAN, CYCLIST)
VEHICLE_CLASSES = (CAR, BUS, TRUCK)

# A colour per class for semantic visualisations (not the rendered appearance).
PALETTE = np.array(
    [
        (70, 130, 180),
        (128, 64, 128),
        (255, 255, 255),
        (250, 250, 160),
        (244, 35, 232),
        (180, 165, 180),
        (152, 251, 152),
        (70, 70, 70),
        (107, 142, 35),
        (153, 153, 153),
        (220, 220, 0),
        (190, 153, 153),
        (0, 0, 142),
        (0, 60, 100),
        (0, 0, 70),
        (220, 20, 60),
        (119, 11, 32),
    ],
    dtype=np.uint8,
)
