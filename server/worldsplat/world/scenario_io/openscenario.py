"""ASAM OpenSCENARIO 1.x (+ its OpenDRIVE road) in and out: the format's two entry points.

Reading and writing live apart, one file per format and direction (`openscenario_read`, `openscenario_write`,
`opendrive_read`, `opendrive_write`); this module names what callers use, so they need not know the split.
"""

from worldsplat.world.scenario_io.openscenario_read import import_openscenario
from worldsplat.world.scenario_io.openscenario_write import export_openscenario

__all__ = ["export_openscenario", "import_openscenario"]
