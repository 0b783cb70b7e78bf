"""Environment lighting from time of day and weather: sun direction and colour, sky, ambient, fog, rain."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Lighting:
    time_of_day: str
    weather: str
    sun_dir: np.ndarray  # (3,) unit vector towards the sun (or moon at night)
    sun_color: np.ndarray  # (3,) direct light
    ambient: np.ndarray  # (3,) sky light
    sky_zenith: np.ndarray
    sky_horizon: np.ndarray
    fog_color: np.ndarray
    fog_distance: float  # metres for 1/e extinction
    shadows: bool  # direct light strong enough to cast shadows

    @property
    def night(self) -> bool:
        return self.time_of_day == "night"

    @property
    def lights_on(self) -> bool:
        return self.time_of_day in ("night", "dusk")

    @property
    def rain(self) -> bool:
        return self.weather == "rain"


def make_lighting(time_of_day: str, weather: str, rng: np.random.Generator) -> Lighting:
    azimuth = float(rng.uniform(-math.pi, math.pi))
    elevation = {
        "day": math.radians(float(rng.uniform(35, 60))),
        "dusk": math.radians(float(rng.uniform(4, 10))),
        "night": math.radians(40),
    }[time_of_day]
    sun_dir = np.array(
        [math.cos(elevation) * math.cos(azimuth), math.cos(elevation) * math.sin(azimuth), math.sin(elevation)]
    )
    if time_of_day == "day":
        sun, amb = np.array([1.0, 0.96, 0.88]) * 0.95, np.array([0.42, 0.46, 0.55])
        zen, hor = np.array([0.22, 0.42, 0.78]), np.array([0.68, 0.8, 0.92])
    elif time_of_day == "dusk":
        sun, amb = np.array([1.0, 0.55, 0.28]) * 0.9, np.array([0.3, 0.26, 0.34])
        zen, hor = np.array([0.16, 0.2, 0.42]), np.array([0.95, 0.55, 0.3])
    else:
        sun, amb = np.array([0.5, 0.55, 0.7]) * 0.12, np.array([0.07, 0.08, 0.11])
        zen, hor = np.array([0.01, 0.015, 0.04]), np.array([0.06, 0.07, 0.11])
    fog_distance = {"clear": 900.0, "overcast": 450.0, "rain": 140.0, "fog": 38.0}[weather]
    shadows = weather == "clear" and time_of_day != "night"
    if weather in ("overcast", "rain", "fog"):
        # Clouds: diffuse light, grey sky, weak direct sun.
        grey = np.array([0.62, 0.64, 0.67]) * (1.0 if time_of_day == "day" else 0.55 if time_of_day == "dusk" else 0.1)
        zen, hor = 0.6 * grey + 0.15 * zen, grey + 0.1 * hor
        amb = amb * 0.5 + sun * 0.45
        sun = sun * (0.25 if weather == "overcast" else 0.15)
        if weather == "rain":
            zen, hor, amb = zen * 0.7, hor * 0.75, amb * 0.8
    fog_color = hor * (0.95 if weather != "fog" else 1.05)
    return Lighting(time_of_day, weather, sun_dir, sun, amb, zen, hor, np.clip(fog_color, 0, 1), fog_distance, shadows)
