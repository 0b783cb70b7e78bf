"""WorldSplat playground: procedural driving world, 4D Gaussian core, generation pipeline and server."""

__version__ = "0.1.0"
