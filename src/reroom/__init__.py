"""reroom: turn a scan of a room into an editable model of its light and materials.

The pipeline runs one way, one subpackage per stage::

    scan (reroom.scan, reroom.importers, reroom.synth)
      -> HDR radiance on the mesh
      -> room layout
      -> lights and materials
      -> edits -> renders

Shared infrastructure: :mod:`reroom.rays` (ray casting), :mod:`reroom.io`
(atomic writes, images, meshes) and :mod:`reroom.render` (Mitsuba set-up).
"""

from reroom.errors import ReroomError, ScanError

__version__ = "0.1.0"

__all__ = ["ReroomError", "ScanError", "__version__"]
