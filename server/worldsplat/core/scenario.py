"""The scenario: the user-facing, versioned JSON a person edits in the page and shares in a link.

Every field is bounded and every model forbids unknown keys, so bad input is rejected with a message naming the
field (`ScenarioError`, or pydantic's `ValidationError` whose `loc` names it). `Scenario.normalized_json()` is the
canonical form the server hashes (`scenario_id`). Presets live in `presets/*.json` as
`{"description": ..., "default": bool (optional), "scenario": {...}}`. See web/docs/world.md.
"""
from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from worldsplat.camera import CAMERA_NAMES

SCENARIO_VERSION = 1
PRESETS_DIR = Path(__file__).parent / "presets"
SCHEMA_PATH = Path(__file__).resolve().parents[2] / "web" / "docs" / "scenario.schema.json"

RoadKind = Literal["straight", "curve", "intersection"]
Setting = Literal["urban", "suburban", "highway"]
TimeOfDay = Literal["day", "dusk", "night"]
Weather = Literal["clear", "overcast", "rain", "fog"]
Manoeuvre = Literal["keep_lane", "lane_change_left", "lane_change_right", "turn_left", "turn_right"]


class ScenarioError(ValueError):
    """A scenario that does not validate; `errors` holds one "field.path: message" string per problem."""

    def __init__(self, errors: list[str]):
        self.errors = errors
        super().__init__("invalid scenario: " + "; ".join(errors))


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True, allow_inf_nan=False, frozen=True)


class Road(_Strict):
    kind: RoadKind = Field("straight", description="road shape: straight, curve (constant curvature) or a four-way "
                                                   "intersection ahead of the ego")
    setting: Setting = Field("urban", description="urban: buildings and sidewalks; suburban: houses, lawns and "
                                                  "trees; highway: verges, barriers and no buildings")
    lanes_per_direction: int = Field(2, ge=1, le=4, description="lanes in each direction")
    lane_width: float = Field(3.5, ge=2.75, le=4.5, description="lane width in metres")
    curvature: float = Field(0.0, ge=-0.015, le=0.015,
                             description="1/radius in 1/m, left positive; used when kind is curve")


class Traffic(_Strict):
    moving_vehicles: int = Field(6, ge=0, le=20, description="cars, buses and trucks driving in the lanes")
    parked_vehicles: int = Field(6, ge=0, le=24, description="cars parked along the kerbs (static)")
    pedestrians: int = Field(4, ge=0, le=24, description="people walking on the sidewalks")
    cyclists: int = Field(1, ge=0, le=8, description="cyclists riding at the right edge of the lanes")


class Environment(_Strict):
    time_of_day: TimeOfDay = "day"
    weather: Weather = "clear"


class Ego(_Strict):
    speed: float = Field(8.0, ge=0.0, le=30.0, description="ego speed in m/s")
    start_lane: int = Field(0, ge=0, le=3, description="lane index counted from the kerb (0 = rightmost)")
    manoeuvre: Manoeuvre = "keep_lane"


class Clip(_Strict):
    frames: int = Field(8, ge=1, le=32, description="number of frames")
    fps: float = Field(4.0, ge=1.0, le=30.0, description="frames per second")


class Image(_Strict):
    width: int = Field(200, ge=32, le=1600, description="image width in pixels")
    height: int = Field(112, ge=32, le=900, description="image height in pixels")


class Rig(_Strict):
    cameras: list[str] = Field(default_factory=lambda: list(CAMERA_NAMES), min_length=1, max_length=6,
                               description="a subset of the default 6-camera rig (stored in rig order)")

    @field_validator("cameras")
    @classmethod
    def _known_unique(cls, v: list[str]) -> list[str]:
        unknown = [c for c in v if c not in CAMERA_NAMES]
        if unknown:
            raise ValueError(f"unknown camera(s) {unknown}; choose from {list(CAMERA_NAMES)}")
        if len(set(v)) != len(v):
            raise ValueError("cameras must not repeat")
        return [c for c in CAMERA_NAMES if c in v]


class Scenario(_Strict):
    version: Literal[1] = Field(1, description="scenario format version")
    seed: int = Field(0, ge=0, le=2**31 - 1, description="world seed: the same scenario gives the same world")
    road: Road = Field(default_factory=Road)
    traffic: Traffic = Field(default_factory=Traffic)
    environment: Environment = Field(default_factory=Environment)
    ego: Ego = Field(default_factory=Ego)
    clip: Clip = Field(default_factory=Clip)
    image: Image = Field(default_factory=Image)
    rig: Rig = Field(default_factory=Rig)

    model_config = ConfigDict(extra="forbid", strict=True, allow_inf_nan=False, frozen=True,
                              title="WorldSplat scenario",
                              json_schema_extra={"$id": "https://worldsplat.local/scenario.schema.json"})

    @model_validator(mode="after")
    def _consistent(self) -> "Scenario":
        lanes, lane, m = self.road.lanes_per_direction, self.ego.start_lane, self.ego.manoeuvre
        if lane >= lanes:
            raise ValueError(f"ego.start_lane: lane {lane} does not exist on a road with {lanes} lane(s) per "
                             f"direction (0..{lanes - 1})")
        if m == "lane_change_left" and lane + 1 >= lanes:
            raise ValueError(f"ego.manoeuvre: lane_change_left needs a lane left of start_lane {lane} "
                             f"(road.lanes_per_direction is {lanes})")
        if m == "lane_change_right" and lane == 0:
            raise ValueError("ego.manoeuvre: lane_change_right needs a lane right of start_lane 0")
        if m in ("turn_left", "turn_right") and self.road.kind != "intersection":
            raise ValueError(f"ego.manoeuvre: {m} needs road.kind intersection (got {self.road.kind})")
        return self

    # -- canonical form -------------------------------------------------------------------------------------------
    def normalized_json(self) -> str:
        """Canonical JSON: every field present, keys sorted, no whitespace (what the server hashes)."""
        return json.dumps(self.model_dump(mode="json"), sort_keys=True, separators=(",", ":"), allow_nan=False)

    @property
    def duration(self) -> float:
        return (self.clip.frames - 1) / self.clip.fps

    @staticmethod
    def parse(obj: dict | str | bytes) -> "Scenario":
        """Validate a dict or JSON text; raises ScenarioError naming each bad field."""
        try:
            if isinstance(obj, (str, bytes)):
                return Scenario.model_validate_json(obj)
            return Scenario.model_validate(obj)
        except ValidationError as e:
            raise ScenarioError(format_errors(e)) from None

    @staticmethod
    def load(path: str | Path) -> "Scenario":
        return Scenario.parse(Path(path).read_text())

    def with_updates(self, **sections: dict) -> "Scenario":
        """A copy with some fields replaced, validated again, e.g. `s.with_updates(seed=3, clip={"frames": 2})`."""
        data = self.model_dump(mode="json")
        for key, value in sections.items():
            if isinstance(value, dict):
                data[key] = {**data[key], **value}
            else:
                data[key] = value
        return Scenario.parse(data)


def format_errors(e: ValidationError) -> list[str]:
    out = []
    for err in e.errors():
        loc = ".".join(str(p) for p in err["loc"])
        msg = err["msg"]
        if err["type"] == "extra_forbidden":
            msg = "unknown field"
        if msg.startswith("Value error, "):
            msg = msg[len("Value error, "):]
        out.append(f"{loc}: {msg}" if loc else msg)
    return out


def scenario_id(scenario: Scenario, length: int = 16) -> str:
    """Short hex sha256 of the normalized scenario JSON."""
    return hashlib.sha256(scenario.normalized_json().encode()).hexdigest()[:length]


# -- presets ----------------------------------------------------------------------------------------------------------
def _preset_files() -> dict[str, Path]:
    return {p.stem: p for p in sorted(PRESETS_DIR.glob("*.json"))}


def _read_preset(path: Path) -> dict:
    data = json.loads(path.read_text())
    extra = set(data) - {"description", "default", "scenario"}
    if extra or "scenario" not in data or "description" not in data:
        raise ValueError(f"preset {path.name}: expected keys description, scenario (optional default), "
                         f"got {sorted(data)}")
    return data


def list_presets() -> list[dict]:
    """[{name, description, default}] for every shipped preset, the default first, then by name."""
    items = []
    for name, path in _preset_files().items():
        data = _read_preset(path)
        items.append({"name": name, "description": data["description"], "default": bool(data.get("default"))})
    return sorted(items, key=lambda p: (not p["default"], p["name"]))


def default_preset_name() -> str:
    defaults = [p["name"] for p in list_presets() if p["default"]]
    if len(defaults) != 1:
        raise RuntimeError(f"exactly one preset must be marked default, found {defaults}")
    return defaults[0]


def load_preset(name: str) -> Scenario:
    """A shipped preset by name ("default" names the preset marked default)."""
    files = _preset_files()
    if name == "default" and "default" not in files:
        name = default_preset_name()
    if name not in files:
        raise ValueError(f"unknown preset {name!r}; choose from {sorted(files)}")
    try:
        return Scenario.parse(_read_preset(files[name])["scenario"])
    except ScenarioError as e:
        raise ScenarioError([f"preset {name}: {m}" for m in e.errors]) from None


def default_scenario() -> Scenario:
    return load_preset(default_preset_name())


def resolve_scenario(arg: str) -> Scenario:
    """A path to a scenario JSON file, or a preset name."""
    p = Path(arg)
    if p.suffix == ".json" or p.exists():
        if not p.exists():
            raise FileNotFoundError(f"scenario file {arg} not found")
        return Scenario.load(p)
    return load_preset(arg)


# -- random scenarios (dataset) -----------------------------------------------------------------------------------
def random_scenario(seed: int, width: int = 112, height: int = 64, frames: int = 4, fps: float = 4.0,
                    preset_mix: bool = False) -> Scenario:
    """A varied scenario for a dataset seed: road kind, setting, lanes, traffic, weather, time, ego manoeuvre.

    With `preset_mix`, a preset chosen by the seed is the starting point and only seed/traffic/weather vary.
    """
    rng = np.random.Generator(np.random.PCG64(seed))
    image = {"width": width, "height": height}
    clip = {"frames": frames, "fps": fps}
    if preset_mix:
        names = [p["name"] for p in list_presets()]
        base = load_preset(names[int(rng.integers(len(names)))])
        t = base.traffic
        traffic = {k: int(min(v_max, max(0, round(getattr(t, k) * rng.uniform(0.5, 1.5)))))
                   for k, v_max in (("moving_vehicles", 20), ("parked_vehicles", 24), ("pedestrians", 24),
                                    ("cyclists", 8))}
        env = base.environment.model_dump()
        if rng.random() < 0.3:
            env = {"time_of_day": str(rng.choice(["day", "dusk", "night"])),
                   "weather": str(rng.choice(["clear", "overcast", "rain", "fog"]))}
        return base.with_updates(seed=seed, traffic=traffic, environment=env, image=image, clip=clip)
    kind = str(rng.choice(["straight", "curve", "intersection"], p=[0.4, 0.3, 0.3]))
    setting = str(rng.choice(["urban", "suburban", "highway"], p=[0.5, 0.3, 0.2]))
    if kind == "intersection" and setting == "highway":
        setting = "suburban"
    lanes = int(rng.integers(1, 5)) if setting == "highway" else int(rng.integers(1, 4))
    curvature = float(rng.uniform(0.004, 0.015) * rng.choice([-1, 1])) if kind == "curve" else 0.0
    start_lane = int(rng.integers(lanes))
    options = ["keep_lane", "keep_lane"]
    if start_lane + 1 < lanes:
        options.append("lane_change_left")
    if start_lane > 0:
        options.append("lane_change_right")
    if kind == "intersection":
        options += ["turn_left", "turn_right"]
    highway = setting == "highway"
    speed_hi = 28.0 if highway else 14.0
    return Scenario.parse({
        "seed": seed,
        "road": {"kind": kind, "setting": setting, "lanes_per_direction": lanes,
                 "lane_width": round(float(rng.uniform(3.0, 3.8)), 2), "curvature": round(curvature, 4)},
        "traffic": {"moving_vehicles": int(rng.integers(0, 13)),
                    "parked_vehicles": 0 if highway else int(rng.integers(0, 13)),
                    "pedestrians": 0 if highway else int(rng.integers(0, 11)),
                    "cyclists": 0 if highway else int(rng.integers(0, 4))},
        "environment": {"time_of_day": str(rng.choice(["day", "dusk", "night"], p=[0.6, 0.2, 0.2])),
                        "weather": str(rng.choice(["clear", "overcast", "rain", "fog"], p=[0.45, 0.25, 0.15, 0.15]))},
        "ego": {"speed": round(float(rng.uniform(0.0, speed_hi)), 2), "start_lane": start_lane,
                "manoeuvre": str(rng.choice(options))},
        "clip": clip, "image": image,
    })


# -- JSON Schema for the page ---------------------------------------------------------------------------------------
def json_schema() -> dict:
    return Scenario.model_json_schema()


def schema_text() -> str:
    return json.dumps(json_schema(), indent=2, sort_keys=True) + "\n"


def write_schema(path: str | Path = SCHEMA_PATH) -> Path:
    """Regenerate web/docs/scenario.schema.json (`python -m worldsplat.scenario --write-schema`)."""
    path = Path(path)
    path.write_text(schema_text())
    return path


if __name__ == "__main__":
    import argparse

    ap = argparse.ArgumentParser(description="scenario utilities")
    ap.add_argument("--write-schema", nargs="?", const=str(SCHEMA_PATH), metavar="PATH",
                    help=f"write the JSON Schema (default {SCHEMA_PATH})")
    ap.add_argument("--validate", metavar="FILE", help="validate a scenario JSON file")
    a = ap.parse_args()
    if a.write_schema:
        print(write_schema(a.write_schema))
    if a.validate:
        print(Scenario.load(a.validate).normalized_json())
