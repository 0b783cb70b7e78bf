"""`worldsplat` console script: one sub-command per concern, each living beside the code it drives.

Each command module exposes `configure(parser)` and `run(args) -> int`; they are imported lazily so that a quick
command (`presets`) never pays for importing torch.
"""

from __future__ import annotations

import argparse
import importlib
import sys

# command -> (module, help)
COMMANDS: dict[str, tuple[str, str]] = {
    "presets": ("worldsplat.cli.presets", "list the shipped scenario presets"),
    "sim": ("worldsplat.cli.sim", "render a scenario's exact ground truth (RGB, depth, masks, conditions)"),
    "dataset": ("worldsplat.cli.dataset", "write a sharded, resumable training dataset (locally or on Ray)"),
    "batch": ("worldsplat.cli.batch", "many scenarios -> many scenes, resumable (locally or on Ray)"),
    "export-nuscenes": ("worldsplat.cli.export_nuscenes", "scenes or dataset clips -> the nuScenes layout"),
    "generate": ("worldsplat.cli.generate", "scenario -> 4D Gaussian scene (.wsplat)"),
    "render": ("worldsplat.cli.render", "render a .wsplat/.ply at a rig camera or any camera"),
    "export": ("worldsplat.cli.ply", "export a .wsplat to .ply / .glb (KHR_gaussian_splatting) / .spz / .sog / .splat"),
    "import": ("worldsplat.cli.ply", "import a .ply / .glb / .spz / .sog / .splat to .wsplat"),
    "export-onnx": (
        "worldsplat.cli.export_onnx",
        "derive the onnxruntime serving graphs from the weights (set-up runs it)",
    ),
    "serve": ("worldsplat.cli.serve", "serve the playground (page, wasm viewer, API)"),
    "train": ("worldsplat.cli.train", "train a generation model (vae, decoder, dit)"),
    "train-enhancer": ("worldsplat.cli.train_enhancer", "train the enhanced diffusion model (refinement)"),
    "train-campaign": (
        "worldsplat.cli.train_campaign",
        "train the served model stack stage by stage: VAE, cache, decoder, prior, DiT (resumable)",
    ),
    "train-stack": (
        "worldsplat.cli.train_stack",
        "train the served stack (VAE, decoder, prior, DiT, enhancer, pixel mix) on the CPU or a GPU (resumable)",
    ),
    "eval": ("worldsplat.cli.eval", "evaluate against the world's exact ground truth"),
    "judge": ("worldsplat.cli.judge", "the downstream judge: train it, score held-out clips and served scenes"),
    "gallery": ("worldsplat.cli.gallery", "GT | VAE | reconstruct | generate PNGs of presets and held-out scenarios"),
    "bench": ("worldsplat.cli.bench", "speed-against-error benchmark report"),
    "import-scenario": ("worldsplat.cli.scenario_files", "OpenSCENARIO 1.x / CommonRoad XML -> scenario JSON"),
    "export-scenario": ("worldsplat.cli.scenario_files", "scenario JSON -> OpenSCENARIO + OpenDRIVE"),
}


def build_parser(only: str | None = None) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="worldsplat", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name, (module, help_text) in COMMANDS.items():
        p = sub.add_parser(name, help=help_text, description=help_text)
        if only is None or name == only:
            mod = importlib.import_module(module)
            attr = name.replace("-", "_")
            configure = getattr(mod, f"configure_{attr}", None) or mod.configure
            configure(p)
            p.set_defaults(_run=getattr(mod, f"run_{attr}", None) or mod.run)
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    first = next((a for a in argv if not a.startswith("-")), None)
    only = first if first in COMMANDS else None
    if only is None:
        # Help or an unknown command: argparse reports it without importing every command module.
        build_parser(only="__none__").parse_args(argv)
        return 2
    args = build_parser(only=only).parse_args(argv)
    try:
        return int(args._run(args) or 0)
    except (ValueError, FileNotFoundError) as e:
        print(f"worldsplat {only}: error: {e}", file=sys.stderr)
        return 2
