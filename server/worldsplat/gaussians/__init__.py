"""Gaussian core: one splatting math (web/docs/splatting-math.md), the torch reference rasterizer, oracle lifting,
4D aggregation (paper eq. 3), the .wsplat v1 stream format and PLY interop. See web/docs/gaussians.md."""
from worldsplat.gaussians.types import Gaussians, Scene4D
from worldsplat.gaussians.raster import rasterize
from worldsplat.gaussians.lift import lift
# Eager on purpose: a lazy __getattr__ is bypassed once the submodule `aggregate` is imported (the import system
# binds the package attribute to the module), and `from worldsplat.gaussians import aggregate` then got the module.
from worldsplat.gaussians.aggregate import aggregate

__all__ = ["Gaussians", "Scene4D", "rasterize", "lift", "aggregate"]
