"""`worldsplat serve [--host] [--port] [--cache-dir] [--backend]`: the playground (page, wasm viewer, API) with uvicorn."""

from __future__ import annotations

import argparse
import os
from pathlib import Path

from worldsplat.core.paths import cache_dir

BACKENDS = ("auto", "onnx", "torch")  # pipeline.onnx.BACKENDS (not imported here: it imports torch)


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--host", default="127.0.0.1", help="interface to bind (default 127.0.0.1: loopback only)")
    parser.add_argument("--port", type=int, default=8000, help="TCP port (default 8000)")
    parser.add_argument(
        "--cache-dir",
        type=Path,
        default=Path(os.environ.get("WORLDSPLAT_CACHE") or cache_dir()),
        help=f"scene/video store and job records (default $WORLDSPLAT_CACHE or {cache_dir()})",
    )
    parser.add_argument("--cache-max-mb", type=int, default=2048, help="cache size cap in MiB (LRU eviction)")
    parser.add_argument("--max-queued", type=int, default=16, help="queued jobs before 429 (default 16)")
    parser.add_argument(
        "--web-dir",
        type=Path,
        default=os.environ.get("WORLDSPLAT_WEB_DIR") or None,
        help="serve the page from here (default $WORLDSPLAT_WEB_DIR or the repository's web/)",
    )
    parser.add_argument(
        "--max-scene-mpix",
        type=float,
        default=None,
        help="largest scene accepted, in million pixels (frames x cameras x width x height; default 32: "
        "api.state.MAX_SCENE_PIXELS)",
    )
    parser.add_argument(
        "--backend",
        choices=BACKENDS,
        default=os.environ.get("WORLDSPLAT_BACKEND") or "auto",
        help="how the models run: onnxruntime from models/weights/onnx (onnx), torch eager (torch), or auto: onnx "
        "where those graphs are current, else torch with a log line (default $WORLDSPLAT_BACKEND or auto)",
    )
    parser.add_argument("--no-warm", action="store_true", help="do not generate the default scene at start-up")
    parser.add_argument(
        "--no-preload",
        action="store_true",
        help="do not load the default mode's models and caption encoder before the server says ready",
    )


def run(args: argparse.Namespace) -> int:
    import uvicorn  # noqa: PLC0415

    from worldsplat.api.app import create_app  # noqa: PLC0415
    from worldsplat.api.state import MAX_SCENE_PIXELS  # noqa: PLC0415

    mpix = MAX_SCENE_PIXELS / 1e6 if args.max_scene_mpix is None else args.max_scene_mpix

    # torch's OpenMP threads spin while they wait: on a 2-core machine shared with other work (training, the
    # browser, other servers) a spinning thread starves its sibling, and one DiT window took 24-30 s instead of
    # 2.5 s (playground.md, "Threads"). Passive waiting, unless the caller chose; read when torch is imported (later).
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
    os.environ["WORLDSPLAT_BACKEND"] = args.backend  # read by inference.load_models (pipeline.onnx.BACKEND_ENV)
    if not 1 <= args.port <= 65535:
        raise ValueError(f"--port must be in 1..65535, got {args.port}")
    if args.cache_max_mb <= 0 or args.max_queued <= 0 or not mpix > 0:
        raise ValueError("--cache-max-mb, --max-queued and --max-scene-mpix must be positive")
    app = create_app(
        args.cache_dir,
        web_dir=args.web_dir,
        max_cache_bytes=args.cache_max_mb << 20,
        max_queued=args.max_queued,
        warm=not args.no_warm,
        max_scene_pixels=int(mpix * 1e6),
        preload=not args.no_preload,
    )
    print(f"worldsplat serve: http://{args.host}:{args.port}/ (API docs at /docs, cache {args.cache_dir})", flush=True)
    uvicorn.run(app, host=args.host, port=args.port, log_level="warning", timeout_graceful_shutdown=5)
    return 0
