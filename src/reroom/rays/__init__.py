"""Ray casting against triangle meshes: closest hits, occlusion, visibility, sampling.

:class:`RayCaster` wraps Embree (through embreex, multi-threaded) or, optionally,
Mitsuba 3 behind one vectorised interface; :func:`sample_hemisphere` draws
stratified cosine-weighted or uniform directions around surface normals.
"""

from reroom.rays.caster import Hits, RayCaster
from reroom.rays.sampling import orthonormal_basis, sample_hemisphere

__all__ = ["Hits", "RayCaster", "orthonormal_basis", "sample_hemisphere"]
