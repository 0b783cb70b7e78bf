"""GET /api/scenes/{scene_id}/export: a ready scene as a file to download, in a format `worldsplat export` writes,
one frame or the whole clip (exports.py builds it, once, into the cache)."""

from __future__ import annotations

import asyncio
from typing import Annotated

from fastapi import APIRouter, Query, Request
from fastapi.responses import StreamingResponse

from .. import exports
from ..errors import ApiError
from ..openapi import ERROR_TEXT, errors, stream_responses
from ..schemas import ErrorBody
from ..state import Pg
from ..streaming import file_response

router = APIRouter(tags=["scenes"])
FRAME_PATTERN = r"^(all|0|[1-9][0-9]{0,3})$"
MEDIA = tuple(dict.fromkeys([*(m for _, m in exports.EXPORTS.values()), exports.ZIP_MEDIA]))
FORMAT_TEXT = (
    "ply: 3DGS PLY; glb: glTF 2.0 KHR_gaussian_splatting (with the frame's rig and ego pose); spz: Niantic SPZ; "
    "sog: PlayCanvas SOG bundle (with the rig and pose); splat: antimatter15 .splat; wsplat: the playground's "
    "streamable 4D format"
)


@router.get(
    "/api/scenes/{scene_id}/export",
    response_class=StreamingResponse,
    responses={
        **stream_responses(MEDIA, "file (`Content-Disposition: attachment` names it)"),
        **errors(409, 416),
        404: {
            "model": ErrorBody,
            "description": f"{ERROR_TEXT[404]}; or no such frame in the scene: `frame` is 0 .. frames - 1 (GET "
            "/api/scenes/{scene_id} says `frames`), the answer's `field` is `frame`",
        },
    },
)
async def scene_export(
    scene_id: str,
    request: Request,
    pg: Pg,
    fmt: Annotated[exports.ExportFormat, Query(alias="format", description=FORMAT_TEXT)],
    frame: Annotated[
        str,
        Query(
            pattern=FRAME_PATTERN,
            description="a frame number: that frame's dynamic Gaussians join the static base (a frame's file, as "
            "`worldsplat export --frame N` writes it); or `all`: the whole clip, a zip of every frame's file named as "
            "`worldsplat export --frame all` names them (STEM.fNNN.EXT); for `wsplat`, the scene's own 4D .wsplat",
        ),
    ] = "0",
):
    """The scene of a finished job as a file to download, byte-identical to `worldsplat export` of the scene's
    .wsplat with the same format and frame. Built on the first request (seconds; a clip of PLY frames can be
    hundreds of MB) and then served from the cache. 404: no such scene, or no such frame in it; 409: the scene is still being generated."""
    meta = pg.ready_scene(scene_id)
    one = None if frame == "all" else int(frame)
    frames = int(meta.get("frames") or 1)
    if one is not None and one >= frames:
        raise ApiError(
            404, f"frame: no frame {one} in this scene: it has {frames} frame(s), 0 .. {frames - 1}", field="frame"
        )
    if one is None and fmt == "wsplat":
        opened = pg.cache.open_artifact("scenes", scene_id)
    else:
        try:
            opened = await asyncio.to_thread(exports.build, pg.cache, scene_id, fmt, one)
        except FileNotFoundError as e:
            raise ApiError(404, str(e)) from None
    if opened is None:
        raise ApiError(404, "the artifact was evicted from the cache; request it again")
    name = exports.file_name(scene_id, fmt, one)
    return file_response(opened[0], exports.media_type(fmt, one), request, name, disposition="attachment")
