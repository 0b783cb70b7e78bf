"""The API's request and response bodies (pydantic models): what the OpenAPI document shows and the routes check."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, StrictBool, field_validator

from worldsplat.core.camera import CAMERA_NAMES
from worldsplat.core.limits import MAX_SHIFT_M
from worldsplat.core.scenario import Scenario, list_presets

PresetName = Literal[tuple(p["name"] for p in list_presets())]  # type: ignore[valid-type]
CameraName = Literal[tuple(CAMERA_NAMES)]  # type: ignore[valid-type]


# -- requests ------------------------------------------------------------------------------------------------------
class SceneRequest(BaseModel):
    model_config = ConfigDict(
        extra="forbid", json_schema_extra={"examples": [{"preset": "urban_straight", "mode": "oracle"}, {}]}
    )
    scenario: Scenario | None = Field(
        None, description="the scenario (see GET /api/schema); default: the default preset, or `preset` if given"
    )
    preset: PresetName | None = Field(None, description="start from this preset when `scenario` is absent")
    mode: Literal["oracle", "reconstruct", "generate"] | None = Field(
        None,
        description="oracle | reconstruct | generate; a mode whose weights this server lacks is 409 (GET "
        "/api/modes lists those it has); default: the best mode whose weights exist",
    )
    strict: StrictBool = Field(
        False,
        description="refuse agents that overlap (a 422 naming them); default: accept them, as they are, and list "
        "them in the answer's `overlaps`",
    )


class RoadRequest(BaseModel):
    model_config = ConfigDict(
        extra="forbid", json_schema_extra={"examples": [{"scenario": {"road": {"kind": "intersection"}, "seed": 7}}]}
    )
    scenario: Scenario = Field(
        description="the scenario (see GET /api/schema); its agents play no part in the road, only in `motion`"
    )


class VideoRequest(BaseModel):
    model_config = ConfigDict(
        extra="forbid",
        strict=True,
        json_schema_extra={"examples": [{"shift_m": 2.0, "cameras": ["CAM_FRONT"], "format": "mp4"}]},
    )
    shift_m: float = Field(
        0.0,
        ge=-MAX_SHIFT_M,
        le=MAX_SHIFT_M,
        allow_inf_nan=False,
        description="lateral track shift in metres, left positive",
    )
    cameras: list[CameraName] | None = Field(
        None,
        min_length=1,
        max_length=6,
        description="cameras to render (default: the scene's whole rig); several make a 2x3 mosaic",
    )
    refine: bool = Field(False, description="run the enhanced-diffusion refinement on the renders")
    format: Literal["mp4", "webm"] = "mp4"

    @field_validator("cameras")
    @classmethod
    def _known(cls, v: list[str] | None) -> list[str] | None:
        if v is None:
            return v
        unknown = [c for c in v if c not in CAMERA_NAMES]
        if unknown:
            raise ValueError(f"unknown camera(s) {unknown}; choose from {list(CAMERA_NAMES)}")
        return [c for c in CAMERA_NAMES if c in v]


# -- answers -------------------------------------------------------------------------------------------------------
class FieldProblem(BaseModel):
    field: str = Field(description="dotted path of the bad field ('' for the body as a whole)")
    message: str
    offset: int | None = Field(None, description="a bad file's byte offset of the field (POST /api/scene-files)")
    format: str | None = Field(None, description="a bad file's format (POST /api/scene-files)")
    where: str | None = Field(None, description="what `offset` counts in, when not the file (a compressed stream)")


class ErrorBody(BaseModel):
    """Every error answer (4xx, 5xx): `error` is one readable line; `field` names the bad field where there is one."""

    detail: str | list[FieldProblem] = Field(description="the message, or one entry per bad field (422)")
    error: str = Field(description="one readable line")
    field: str | None = Field(None, description="the field the error names, if any")


class JobOut(BaseModel):
    model_config = ConfigDict(extra="allow")
    id: str
    kind: str
    target: str = Field(description="the artifact the job produces (scene id, video id)")
    status: Literal["queued", "running", "done", "failed", "cancelled"]
    stage: str
    fraction: float
    error: str | None = None
    result: dict = {}
    params: dict = {}
    created: float
    started: float | None = None
    finished: float | None = None
    version: int
    events: str = Field(description="SSE progress of this job")


class OverlapOut(BaseModel):
    """Two footprints that overlap: an explicit agent and another (or the ego), from `first_s` to `last_s`."""

    agent: str = Field(description="the agent's id")
    other: str = Field(description="the other agent's id, or `ego`")
    first_s: float = Field(description="the first frame time they overlap at (s)")
    last_s: float = Field(description="the last frame time they overlap at (s)")


class SceneState(BaseModel):
    model_config = ConfigDict(extra="allow")
    scene_id: str
    status: Literal["queued", "running", "ready", "failed", "missing"]
    mode: str | None = None
    model_version: str | None = None
    bytes: int | None = Field(None, description="size of the whole .wsplat (ready)")
    wsplat: str | None = Field(None, description="the stream: /api/scenes/{id}/wsplat")
    job: JobOut | None = None
    overlaps: list[OverlapOut] | None = Field(
        None, description="POST /api/scenes: the scenario's agents that overlap, and when (rendered as they are)"
    )
    warnings: list[str] | None = Field(None, description="POST /api/scenes: each overlap as one readable line")


class Footprint(BaseModel):
    id: str | None = Field(None, description="the agent's id (null: the ego)")
    length: float = Field(description="m")
    width: float = Field(description="m")
    poses: list[list[float]] = Field(description="[x, y, yaw] of the footprint's centre at each frame (m, m, rad)")


class MotionPreview(BaseModel):
    """Where the world puts the ego and each explicit agent at each frame (worldsplat.world.preview)."""

    times: list[float] = Field(description="the clip's frame times (s)")
    ego: Footprint
    agents: list[Footprint] = Field(description="the scenario's agents, in its order")


class RoadLayout(BaseModel):
    """The world's road for a scenario (worldsplat.world.road.RoadGeometry, as the world builds it): what the page's
    bird's-eye editor draws. World frame: the ego's rear axle starts at the origin facing +x, y left; the main road's
    centreline is at y = y0 (straight) or an arc of `curvature` through (0, y0); a cross road is straight along y."""

    kind: Literal["straight", "curve", "intersection"]
    setting: Literal["urban", "suburban", "highway"]
    lanes_per_direction: int
    lane_width: float = Field(description="m")
    median: float = Field(description="m between the two directions' inner lane edges (highway: 2.6, else 0)")
    curvature: float = Field(description="1/m, left positive (0 unless kind is curve)")
    y0: float = Field(description="world y of the main road's centreline at x = 0 (m)")
    lanes_edge: float = Field(description="m from a centreline to the outer lane edge")
    road_half: float = Field(description="m from a centreline to the edge of the drivable surface (lanes + shoulder)")
    curb_out: float = Field(description="m from a centreline to the kerb's outer edge")
    walk_out: float = Field(description="m from a centreline to the sidewalk's outer edge")
    junction_s: float | None = Field(
        description="kind intersection: m along the main road (world x) from the ego's start to the cross road's "
        "centreline, where the world puts it; null: no cross road"
    )
    junction_from: Literal["scenario", "manoeuvre", "seed"] | None = Field(
        description="where junction_s comes from: the scenario's road.junction_s, a turning ego (3 m + 25 % of its "
        "travel to the cross road's sidewalk) or the seed's draw; null: no cross road"
    )
    crosswalks_s: list[float] = Field(description="mid-block crosswalks on the main road (m along it)")
    motion: MotionPreview = Field(description="the ego and the agents at each frame, as the world moves them")


class VideoState(BaseModel):
    model_config = ConfigDict(extra="allow")
    video_id: str
    status: Literal["queued", "running", "ready", "failed", "cancelled", "done", "missing"]
    url: str
    job: JobOut | None = None
