"""Gaussian core: one splatting math (web/docs/splatting-math.md), the torch reference rasterizer, oracle lifting,
4D aggregation (paper eq. 3), the .wsplat v1 / v2 stream format (the `wsplat` package) and file interop (PLY, glTF,
SPZ, SOG, .splat). Rotation and ray math is `worldsplat_models.geometry`'s. See web/docs/gaussians.md."""

from worldsplat.gaussians.lift import lift
from worldsplat.gaussians.raster import rasterize
from worldsplat.gaussians.types import Gaussians, Scene4D

__all__ = ["Gaussians", "Scene4D", "rasterize", "lift", "aggregate_4d"]


def __getattr__(name):
    # Imported on first use (aggregation pulls in more than most callers need). The function is aggregate_4d, not
    # `aggregate`: that name is the submodule, which Python binds here once it has been imported.
    if name == "aggregate_4d":
        from worldsplat.gaussians.aggregate import aggregate_4d as fn  # noqa: PLC0415 - lazy on purpose (above)

        return fn
    raise AttributeError(name)
