"""Networks, samplers and training loops for the WorldSplat playground (tiny / small / paper configs)."""
