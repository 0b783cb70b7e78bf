"""Gaussian core: one splatting math (web/docs/splatting-math.md), the torch reference rasterizer, oracle lifting,
4D aggregation (paper eq. 3), the .wsplat v1 stream format and PLY interop. See web/docs/gaussians.md."""
from worldsplat.gaussians.types import Gaussians, Scene4D
from worldsplat.gaussians.raster import rasterize
from worldsplat.gaussians.lift import lift

__all__ = ["Gaussians", "Scene4D", "rasterize", "lift", "aggregate"]


def __getattr__(name):  # aggregation is imported on first use
    if name == "aggregate":
        from worldsplat.gaussians.aggregate import aggregate as fn
        return fn
    raise AttributeError(name)
