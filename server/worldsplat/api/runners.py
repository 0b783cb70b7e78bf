"""The heavy work behind the server's jobs: scenario -> .wsplat scene, scene + track -> video. One home for how ids are
formed (content hashes) and for what the pipeline offers (modes, refinement), so the app only routes.

The pipeline (torch) is imported lazily: `worldsplat serve` starts in a fraction of a second and imports it in the
background while warming the default scene.
"""

from __future__ import annotations

import contextlib
import functools
import hashlib
import inspect
import struct
import time
from collections.abc import Iterator

import numpy as np

from worldsplat.core.camera import CAMERA_NAMES
from worldsplat.core.scenario import Scenario

from .cache import ArtifactCache
from .jobs import JobContext, JobError

VIDEO_FORMATS = {"mp4": ".mp4", "webm": ".webm"}
# The .wsplat version the server writes: `wsplat.SERVED_VERSION` (v4, tests/browser/wsplat-v4.test.mjs), repeated
# here so that the API starts without importing torch; tests/python/test_one_home.py pins the two equal. v1 files
# (older caches, dropped files) are still read everywhere.
WSPLAT_VERSION = 4


class Pipeline:
    """What the server needs from `worldsplat.pipeline.scene`: the modes, the version that enters a scene id, and
    `generate_scene`. The app factory takes another object with these methods (`create_app(pipeline=...)`), e.g. the
    fast test double the schemathesis run uses; this one imports the real pipeline (torch) on first use."""

    @staticmethod
    def module():
        import worldsplat.pipeline.scene as pipeline  # noqa: PLC0415 - heavy (torch), imported on first use

        return pipeline

    def available_modes(self) -> list[str]:
        return list(self.module().MODES)

    def default_mode(self) -> str:
        """`worldsplat.pipeline.scene.default_mode` (one definition, shared with `worldsplat generate`)."""
        return self.module().default_mode()

    def model_version(self, mode: str) -> str:
        """The version string that, with the scenario and mode, determines a scene (part of the content hash)."""
        p = self.module()
        fn = getattr(p, "model_version", None)
        if callable(fn):
            return str(fn(mode))
        if mode == "oracle":
            return str(p.ORACLE_VERSION)
        from worldsplat.pipeline.inference import load_models  # noqa: PLC0415 - the weights' hash (loaded once)

        return f"{mode}-{load_models().version}"

    def preload(self, mode: str) -> None:
        """Load what a `mode` request needs (the models, the caption encoder) now, not on the first request."""
        self.module().preload(mode)

    def generate_scene(self, scenario: Scenario, mode: str, progress, cancelled, sink=None):
        """`sink` (pipeline.scene.SceneSink) takes each window as it is done."""
        return self.module().generate_scene(scenario, mode=mode, progress=progress, cancelled=cancelled, sink=sink)

    def render_track(self, scene, shift_m: float, cameras: list[str], progress, cancelled):
        from worldsplat.pipeline.render import render_track  # noqa: PLC0415 - heavy (torch), imported on first use

        return render_track(scene, shift_m, cameras, progress=progress, cancelled=cancelled)

    def refinement_status(self) -> tuple[bool, str]:
        """(available, why not): refinement needs `worldsplat.pipeline.refine` and its enhancer weights."""
        try:
            from worldsplat.pipeline.refine import WEIGHTS, refine_available  # noqa: PLC0415
        except ImportError as e:
            return False, f"refinement is not available: worldsplat.pipeline.refine cannot be imported ({e})"
        if not refine_available():
            return False, f"refinement is not available: the enhancer weights ({WEIGHTS.name}) are not installed"
        return True, ""

    def refine_views(self) -> int:
        """How many rig views the enhancer reads at once (it refines a whole rig: scenes need all of them)."""
        from worldsplat.pipeline.refine import load_refiner  # noqa: PLC0415 - loaded once per process

        return int(load_refiner()[0].cfg.data.views)

    @functools.cache  # noqa: B019 - one instance per process
    def refiner_version(self) -> str:
        """The enhancer weights' content hash: a new model gives new video ids."""
        from worldsplat.pipeline.refine import WEIGHTS  # noqa: PLC0415

        h = hashlib.sha256()
        with open(WEIGHTS, "rb") as f:
            for block in iter(lambda: f.read(1 << 20), b""):
                h.update(block)
        return f"enhancer-{h.hexdigest()[:16]}"

    def refine_track(self, scene, shift_m: float, cameras: list[str], progress, cancelled, scenario):
        from worldsplat.pipeline.refine import refine_track  # noqa: PLC0415

        return refine_track(scene, shift_m, cameras, progress=progress, cancelled=cancelled, scenario=scenario)


PIPELINE = Pipeline()


def available_modes(pipe: Pipeline = PIPELINE) -> list[str]:
    return list(pipe.available_modes())


def default_mode(pipe: Pipeline = PIPELINE) -> str:
    return pipe.default_mode()


def model_version(mode: str, pipe: Pipeline = PIPELINE) -> str:
    return str(pipe.model_version(mode))


def preload(mode: str, pipe: Pipeline = PIPELINE) -> None:
    """`Pipeline.preload` when the pipeline has one (test doubles need not)."""
    fn = getattr(pipe, "preload", None)
    if callable(fn):
        fn(mode)


def refinement_status(pipe: Pipeline = PIPELINE) -> tuple[bool, str]:
    return pipe.refinement_status()


def refine_views(pipe: Pipeline = PIPELINE) -> int:
    return int(pipe.refine_views())


def content_id(*parts: str) -> str:
    return hashlib.sha256("\n".join(parts).encode()).hexdigest()[:32]


def scene_id_for(scenario: Scenario, mode: str, pipe: Pipeline = PIPELINE) -> str:
    """id = content hash of the normalized scenario + model version + mode."""
    return content_id("scene", scenario.normalized_json(), model_version(mode, pipe), mode)


def video_id_for(
    scene_id: str, shift_m: float, cameras: list[str], refine: bool, fmt: str, pipe: Pipeline = PIPELINE
) -> str:
    refine_version = pipe.refiner_version() if refine else "raw"
    return content_id("video", scene_id, f"{float(shift_m):.4f}", ",".join(cameras), refine_version, fmt)


# -- jobs ---------------------------------------------------------------------------------------------------------
def wsplat_pieces(data: bytes) -> Iterator[bytes]:
    """The .wsplat bytes as the stream delivers them: the preamble + HEAD, then each STAT / DYNA chunk, then END!
    (chunk framing: tag, u32 length, payload, u32 CRC; web/docs/wsplat-v1.md)."""
    pos = 12  # magic + version
    first = True
    while pos < len(data):
        (n,) = struct.unpack_from("<I", data, pos + 4)
        end = pos + 12 + n
        yield data[:end] if first else data[pos:end]
        first, pos = False, end


class StreamSink:
    """A `pipeline.scene.SceneSink` that writes a streamed .wsplat (web/docs/wsplat-v1.md, "Streamed files") through
    the cache's live writer as windows arrive: the preamble + HEAD with the first window (its Gaussians fix the
    layouts), then each window's STAT chunks (importance order) and its frames' DYNA chunks, flushed one by one; `end`
    writes END! with the totals and the meta known only at the end. The live file is opened with the first byte, so a
    job that fails before its first window leaves no file at all.

    Agent objects (web/docs/agents.md): a v1/v2 file gets each frame's dynamics with the objects built so far posed
    in (the pipeline bakes them for a sink without `takes_objects`). From .wsplat v3 the sink takes the objects: each
    window's new canonical Gaussians of an agent go out as an OBJC chunk (a new agent's object, or appended to the
    agent's object sent before: an object grows window by window and never changes what was sent), then one POSE
    chunk of the window's frames, one pose per agent."""

    def __init__(self, open_live, ctx: JobContext, pause: float = 0.0, version: int = WSPLAT_VERSION):
        from worldsplat.gaussians import wsplat  # noqa: PLC0415 - heavy (torch), imported on first use

        self.wsplat, self.open_live, self.ctx, self.pause, self.version = wsplat, open_live, ctx, pause, version
        self.takes_objects = version >= 3
        self.recolours = version >= 4  # SCOL chunks: a stream before .wsplat v4 cannot carry the whole-scene fit
        self.live = self.writer = self.skeleton = None
        self.head_meta: set[str] = set()
        self.objects_sent: list = []  # an AgentObject per OBJC chunk written (an agent's parts share its track)

    def _put(self, piece: bytes) -> None:
        self.ctx.check()
        if self.live is None:
            self.live = self.open_live()
        self.live.write(piece)
        if self.pause:  # test doubles slow the writer down to cut it mid-stream
            time.sleep(self.pause)

    def begin(self, skeleton) -> None:
        self.skeleton, self.head_meta = skeleton, set(skeleton.meta)

    def window(self, frames: list[int], static, dynamic: dict, objects: dict | None = None) -> None:
        parts = self._object_parts(objects or {})
        if self.writer is None:
            self.writer = self.wsplat.StreamWriter.for_window(
                self.skeleton, static, list(dynamic.values()), version=self.version
            )
            if self.takes_objects:
                self.writer.ol = self.wsplat.object_layout_for(parts)
            self._put(self.writer.head())
        for piece in self.writer.static(static):
            self._put(piece)
        if parts:
            for piece in self.writer.objects(parts):
                self._put(piece)
            self.objects_sent += parts
        if self.objects_sent and frames:  # a part with no frames (the track fill) poses nothing
            self._put(self.writer.poses(frames, self.objects_sent))
        for t in frames:
            for piece in self.writer.dynamic(t, dynamic[t]):
                self._put(piece)

    def _object_parts(self, added: dict) -> list:
        """The window's new canonical Gaussians per agent id as AgentObjects with the agent's track (skeleton)."""
        from worldsplat.gaussians.types import AgentObject  # noqa: PLC0415 - heavy (torch), imported on first use

        tracks = {o.agent_id: o for o in self.skeleton.objects}
        return [AgentObject(a, tracks[a].cls, tracks[a].size, g, tracks[a].poses, tracks[a].present)
                for a, g in added.items()]  # fmt: skip

    def recolour(self, colours) -> None:
        """New colours (N, 3) of every static handed over so far, in the order handed over (`SceneSink`): SCOL
        chunks, .wsplat v4 (web/docs/wsplat-v4.md): a mode whose joint colour fit is the whole scene's calls it before `end`."""
        if self.writer is None:
            raise RuntimeError("recolour before the first window")
        for piece in self.writer.recolour(colours):
            self._put(piece)

    def end(self, scene) -> None:
        if self.writer is None:  # no window at all (cannot happen: a clip has >= 1 frame)
            raise RuntimeError("the pipeline handed over no window")
        self._put(self.writer.end({k: v for k, v in scene.meta.items() if k not in self.head_meta}))


def _takes_sink(pipe) -> bool:
    try:
        return "sink" in inspect.signature(pipe.generate_scene).parameters
    except (TypeError, ValueError):
        return False


def run_scene(cache: ArtifactCache, ctx: JobContext, pipe: Pipeline = PIPELINE) -> dict:
    """Build the scene and write its .wsplat through the cache's live writer while it is generated: a stream opened
    while the job runs (GET .../wsplat?wait=true) receives each window's chunks as they are flushed (`StreamSink`;
    a pipeline without `sink` writes the whole file at the end, static chunks first). The file is renamed into the
    cache only when whole (END!); a cancel, a failure or a stop between chunks aborts it (deleted; open streams are
    cut without END!), and a server killed meanwhile leaves it in tmp/, which the next start empties."""
    from worldsplat.gaussians import wsplat  # noqa: PLC0415

    p = ctx.params
    scenario, mode, scene_id = Scenario.parse(p["scenario"]), p["mode"], ctx.job.target
    t0 = time.monotonic()
    ctx.progress("loading models", 0.0)
    pause = float(getattr(pipe, "chunk_pause_s", 0.0))
    with contextlib.ExitStack() as stack:

        def open_live():
            return stack.enter_context(cache.live_writer("scenes", scene_id, ".wsplat"))

        if _takes_sink(pipe):
            sink = StreamSink(open_live, ctx, pause)
            scene = pipe.generate_scene(scenario, mode, ctx.progress, ctx.cancelled, sink=sink)
            ctx.check()
            sink.end(scene)
        else:
            scene = pipe.generate_scene(scenario, mode, ctx.progress, ctx.cancelled)
            ctx.check()
            ctx.progress("writing .wsplat", 0.0)
            data = wsplat.encode(scene, version=WSPLAT_VERSION)
            live = open_live()
            for piece in wsplat_pieces(data):
                ctx.check()
                live.write(piece)
                ctx.progress("writing .wsplat", live.size / len(data))
                if pause:
                    time.sleep(pause)
    meta = cache.commit_meta(
        "scenes",
        scene_id,
        {
            "ext": ".wsplat",
            "mode": mode,
            "model_version": p["model_version"],
            "scenario": scenario.model_dump(mode="json"),
            "frames": int(scenario.clip.frames),
            "cameras": list(scenario.rig.cameras),
            "seconds": round(time.monotonic() - t0, 3),
        },
    )
    return {"scene_id": scene_id, "bytes": meta["bytes"], "mode": mode, "seconds": meta["seconds"]}


def run_video(cache: ArtifactCache, ctx: JobContext, pipe: Pipeline = PIPELINE) -> dict:
    from worldsplat.core.video import mosaic, write_video  # noqa: PLC0415
    from worldsplat.gaussians import wsplat  # noqa: PLC0415

    p = ctx.params
    scene_id, video_id = p["scene_id"], ctx.job.target
    with cache.pinned("scenes", scene_id):
        opened = cache.open_artifact("scenes", scene_id)
        if opened is None:
            raise JobError(f"scene {scene_id} is no longer in the cache; generate it again")
        ctx.progress("reading scene", 0.0)
        scene = wsplat.read(opened[0])
    cameras = [c for c in CAMERA_NAMES if c in p["cameras"]]
    if p["refine"]:
        ok, why = pipe.refinement_status()
        if not ok:
            raise JobError(why)
        frames = pipe.refine_track(
            scene, p["shift_m"], cameras, ctx.progress, ctx.cancelled, scenario=opened[1].get("scenario")
        )
    else:
        frames = pipe.render_track(scene, p["shift_m"], cameras, ctx.progress, ctx.cancelled)
    ctx.check()
    frames = np.asarray(frames)
    if frames.ndim != 5 or frames.dtype != np.uint8:
        raise RuntimeError(f"render_track returned {frames.dtype} {frames.shape}, expected uint8 (T,V,H,W,3)")
    video = mosaic(frames, cameras)
    ctx.progress("encoding video", 0.0)
    ext = VIDEO_FORMATS[p["format"]]
    fps = float(scene.fps)
    with cache.writer("videos", video_id, ext) as tmp:
        write_video(video, tmp, fps=fps)
    ctx.progress("encoding video", 1.0)
    meta = cache.commit_meta(
        "videos",
        video_id,
        {
            "ext": ext,
            "scene_id": scene_id,
            "shift_m": p["shift_m"],
            "cameras": cameras,
            "refine": p["refine"],
            # write_video pads odd sizes by one pixel (yuv420p)
            "frames": int(video.shape[0]),
            "width": int(video.shape[2] + video.shape[2] % 2),
            "height": int(video.shape[1] + video.shape[1] % 2),
            "fps": fps,
        },
    )
    return {
        "video_id": video_id,
        "bytes": meta["bytes"],
        "frames": meta["frames"],
        "width": meta["width"],
        "height": meta["height"],
        "format": p["format"],
    }
