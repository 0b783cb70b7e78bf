"""Scenario -> 4D Gaussian scene. The one place the modes meet.

    scene = generate_scene(scenario, mode="oracle" | "reconstruct" | "generate", steps=8, progress=cb, cancelled=fn)

oracle      the world's exact RGB + depth + dynamic masks, lifted pixel-aligned (worldsplat.gaussians.lift) and
            aggregated (paper eq. 3 + economy). Training-free; always available.
reconstruct ground-truth multi-view video -> VAE encoder -> latent Gaussian decoder (paper §3.5), via
            `worldsplat.pipeline.inference`; needs shipped weights.
generate    world conditions -> 4D-aware DiT -> latent Gaussian decoder; needs shipped weights.
`progress(stage, fraction)` is called as stages advance; `cancelled()` is checked between stages and frames and
raises worldsplat.core.errors.Cancelled.
"""

from __future__ import annotations

from collections.abc import Callable

from worldsplat.core.errors import check as _check_cancelled
from worldsplat.core.scenario import scenario_id
from worldsplat.gaussians.aggregate import AggregateStats, Economy, aggregate_4d
from worldsplat.gaussians.lift import lift
from worldsplat.gaussians.types import Scene4D
from worldsplat.world import build_world, simulate

ALL_MODES = ("oracle", "reconstruct", "generate")
ORACLE_VERSION = "oracle-2"  # 2: the sky is lifted as a far static shell (cached oracle scenes of 1 have none)

Progress = Callable[[str, float], None]
CancelCheck = Callable[[], bool]


def _models_inference():
    try:
        from worldsplat.pipeline import inference  # noqa: PLC0415 - optional: broken networks must not stop the oracle
    except ImportError:
        return None
    return inference


def available_modes() -> list[str]:
    """Modes whose requirements exist here: oracle always; reconstruct/generate when the weights are shipped."""
    inf = _models_inference()
    modes = ["oracle"]
    if inf is not None:
        try:
            have = set(inf.available_modes())
        except Exception:  # a broken models package must not take the oracle down with it
            have = set()
        modes += [m for m in ("reconstruct", "generate") if m in have]
    return modes


class _Modes:
    """`MODES` is evaluated on use (weights may appear after import)."""

    def __iter__(self):
        return iter(available_modes())

    def __contains__(self, m) -> bool:
        return m in available_modes()

    def __repr__(self) -> str:
        return repr(available_modes())


MODES = _Modes()


def default_mode() -> str:
    """The default mode of the playground and of `worldsplat generate`: generate once its weights ship (a scene from
    the scenario alone), else oracle. reconstruct is offered but not the default: it reads the same ground-truth video
    the oracle lifts exactly, and the small shipped VAE/decoder reproduce it blurred (it shows the models at work)."""
    return "generate" if "generate" in available_modes() else "oracle"


def _check(cancelled: CancelCheck | None) -> None:
    _check_cancelled(cancelled)


def generate_scene(
    scenario,
    mode: str | None = None,
    steps: int = 8,
    progress: Progress | None = None,
    cancelled: CancelCheck | None = None,
    seed: int | None = None,
    economy: Economy | None = None,
) -> Scene4D:
    """Build the 4D Gaussian scene of a scenario. `meta` records scenario_id, mode, model_version, caption, fps
    and the aggregation statistics. `mode` None is `default_mode()`."""
    mode = default_mode() if mode is None else mode
    if mode not in ALL_MODES:
        raise ValueError(f"unknown mode {mode!r}; modes are {', '.join(ALL_MODES)}")
    prog = progress or (lambda stage, f: None)
    _check(cancelled)
    prog("world", 0.0)
    world = build_world(scenario)
    # the scenario travels in the .wsplat header so a scene read back can be refined (conditions S', B') anywhere
    meta = {
        "scenario_id": scenario_id(scenario),
        "mode": mode,
        "caption": world.caption,
        "fps": float(world.fps),
        "scenario": scenario.model_dump(mode="json"),
    }
    _check(cancelled)
    if mode == "oracle":
        scene, stats = _oracle(world, prog, cancelled, economy)
        meta["model_version"] = ORACLE_VERSION
    else:
        inf = _models_inference()
        if inf is None:
            raise FileNotFoundError(f"mode {mode!r} needs the worldsplat_models package, which is not importable")
        if mode not in set(inf.available_modes()):
            raise FileNotFoundError(
                f"mode {mode!r} needs model weights that are not shipped here; available modes: "
                f"{', '.join(available_modes())}"
            )
        models = inf.load_models()
        if mode == "reconstruct":
            prog("simulate", 0.0)
            clip = simulate(world)
            _check(cancelled)
            prog("reconstruct", 0.0)
            dec = inf.reconstruct(clip, models=models)
        else:
            prog("conditions", 0.0)
            cond = world.conditions(layout_size=inf.layout_size(models))
            _check(cancelled)
            prog("generate", 0.0)
            dec = inf.generate(
                cond,
                steps=steps,
                seed=int(scenario.seed if seed is None else seed),
                models=models,
                rig=world.rig,
                frame_times=world.frame_times,
                progress=lambda f: prog("generate", float(f)),
            )
        _check(cancelled)
        prog("aggregate", 0.0)
        scene, stats = inf.aggregate_decoded(dec, economy=economy)
        meta["model_version"] = str(dec.meta.get("model_version", models.version))
        if mode == "generate":
            meta["steps"] = int(steps)
    meta["aggregate"] = stats.as_dict()
    scene.meta.update(meta)
    prog("done", 1.0)
    return scene


def _oracle(
    world, prog: Progress, cancelled: CancelCheck | None, economy: Economy | None
) -> tuple[Scene4D, AggregateStats]:
    prog("simulate", 0.0)
    clip = simulate(world)
    _check(cancelled)
    return _aggregate_clip(clip, economy, prog, cancelled)


def _aggregate_clip(
    clip, economy: Economy | None, prog: Progress, cancelled: CancelCheck | None
) -> tuple[Scene4D, AggregateStats]:
    T, V, H, W = clip.depth.shape
    per_view = []
    for t in range(T):
        prog("lift", t / T)
        per_view.append(
            [lift(clip.rgb[t, v], clip.depth[t, v], clip.dynamic[t, v], clip.camera(t, v)) for v in range(V)]
        )
        _check(cancelled)
    prog("aggregate", 0.0)
    return aggregate_4d(per_view, clip.frame_times, clip.rig, clip.ego_to_world, economy=economy, image_size=(H, W))


def oracle_scene(clip, meta: dict | None = None, economy: Economy | None = None) -> Scene4D:
    """The oracle scene of a simulated clip (exact RGB + depth + dynamic masks, lifted), aggregated exactly as the
    playground serves it (paper eq. 3 + economy, `aggregate_4d`): the reference the learned models, the refinement
    pairs and the evaluation are measured on."""
    scene, stats = _aggregate_clip(clip, economy, lambda stage, f: None, None)
    scene.meta.update(
        {
            "mode": "oracle",
            "model_version": ORACLE_VERSION,
            "caption": getattr(clip, "caption", ""),
            "fps": float(clip.fps),
            "aggregate": stats.as_dict(),
            **(meta or {}),
        }
    )
    return scene
