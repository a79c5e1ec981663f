"""Objects to insert into a room: bundled furniture made from primitives, or mesh files.

The bundled models (``chair``, ``table``, ``sofa``, ``shelf``, ``cube``) are built here from
trimesh boxes and cylinders, so nothing is downloaded and the same geometry serves the
model side (:mod:`reroom.edit.apply`) and the synthetic-truth side of an edit. Every model
is made in its own frame: metres, +Z up, the footprint centred on the origin, the base at
``z = 0``, the front (where one sits, or the open side of a shelf) facing -Y.

:func:`placed_object` scales it, turns it about +Z and puts the footprint centre on the
edit's ``position`` (the base at its ``z``): the convention of the ``insert`` edit.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
import trimesh

from reroom.errors import ReroomError

__all__ = [
    "BUNDLED_OBJECTS",
    "DEFAULT_COLORS",
    "bundled_object",
    "load_object_file",
    "object_mesh",
    "placed_object",
]

#: Linear diffuse albedo of each bundled model when the edit gives no ``color``
#: (plausible painted wood, fabric and grey plastic values).
DEFAULT_COLORS: dict[str, tuple[float, float, float]] = {
    "chair": (0.45, 0.28, 0.15),
    "table": (0.35, 0.22, 0.12),
    "sofa": (0.20, 0.28, 0.45),
    "shelf": (0.60, 0.55, 0.45),
    "cube": (0.60, 0.60, 0.60),
}

#: File suffixes trimesh loads as meshes for ``insert``.
MESH_SUFFIXES = (".obj", ".ply", ".gltf", ".glb", ".stl", ".off")


def _box(lo: Sequence[float], hi: Sequence[float]) -> trimesh.Trimesh:
    lo_a, hi_a = np.asarray(lo, float), np.asarray(hi, float)
    return trimesh.creation.box(bounds=np.stack([lo_a, hi_a]))


def _post(x: float, y: float, z0: float, z1: float, radius: float) -> trimesh.Trimesh:
    """A vertical cylinder (a leg) from ``z0`` to ``z1`` at ``(x, y)``."""
    return trimesh.creation.cylinder(radius=radius, segment=[[x, y, z0], [x, y, z1]], sections=12)


def _chair() -> list[trimesh.Trimesh]:
    # The synthetic generator's chair (reroom.synth.presets._chair): 44 cm seat at 43-47 cm,
    # 4 cm legs, back up to 90 cm on the +Y side (so the front faces -Y).
    s = 0.22
    parts = [_box([-s, -s, 0.43], [s, s, 0.47]), _box([-s, s - 0.04, 0.47], [s, s, 0.90])]
    for dx in (-s + 0.02, s - 0.02):
        for dy in (-s + 0.02, s - 0.02):
            parts.append(_post(dx, dy, 0.0, 0.43, 0.02))
    return parts


def _table() -> list[trimesh.Trimesh]:
    w, d = 0.60, 0.40  # half sizes: a 1.2 x 0.8 m dining table, top at 72-76 cm
    parts = [_box([-w, -d, 0.72], [w, d, 0.76])]
    for dx in (-w + 0.06, w - 0.06):
        for dy in (-d + 0.06, d - 0.06):
            parts.append(_post(dx, dy, 0.0, 0.72, 0.03))
    return parts


def _sofa() -> list[trimesh.Trimesh]:
    w, d = 1.0, 0.45  # 2.0 m wide, 0.9 m deep, back on the +Y side
    return [
        _box([-w, -d, 0.0], [w, d, 0.42]),
        _box([-w, d - 0.22, 0.42], [w, d, 0.85]),
        _box([-w, -d, 0.42], [-w + 0.18, d - 0.22, 0.62]),
        _box([w - 0.18, -d, 0.42], [w, d - 0.22, 0.62]),
    ]


def _shelf() -> list[trimesh.Trimesh]:
    w, d, h, t = 0.40, 0.15, 1.80, 0.02  # 0.8 m wide, 0.3 m deep, 1.8 m tall bookcase
    parts = [
        _box([-w, -d, 0.0], [-w + t, d, h]),
        _box([w - t, -d, 0.0], [w, d, h]),
        _box([-w + t, d - t, 0.0], [w - t, d, h]),
    ]
    for z in np.linspace(0.0, h - t, 5):
        parts.append(_box([-w + t, -d, z], [w - t, d - t, z + t]))
    return parts


def _cube() -> list[trimesh.Trimesh]:
    return [_box([-0.25, -0.25, 0.0], [0.25, 0.25, 0.5])]


_BUILDERS: dict[str, Callable[[], list[trimesh.Trimesh]]] = {
    "chair": _chair,
    "table": _table,
    "sofa": _sofa,
    "shelf": _shelf,
    "cube": _cube,
}

#: Names of the bundled furniture models.
BUNDLED_OBJECTS: tuple[str, ...] = tuple(_BUILDERS)


def bundled_object(name: str) -> trimesh.Trimesh:
    """The bundled model ``name`` in its own frame (see the module docstring).

    Raises
    ------
    ReroomError
        For a name that is not bundled (lists the ones that are).
    """
    if name not in _BUILDERS:
        raise ReroomError(
            f"no bundled object named {name!r}; choose one of {list(BUNDLED_OBJECTS)} "
            f"or give a mesh file ({', '.join(MESH_SUFFIXES)})"
        )
    return trimesh.util.concatenate(_BUILDERS[name]())


def load_object_file(path: str | Path) -> trimesh.Trimesh:
    """Load a mesh file (OBJ, PLY, glTF/GLB, STL, OFF) as one triangle mesh, +Z up.

    glTF is +Y up by specification, so glTF/GLB files are turned +90 degrees about +X;
    other formats are taken as +Z up (reroom's convention). The result is re-centred
    so its footprint centre is the origin and its base is at ``z = 0``.

    Raises
    ------
    ReroomError
        Naming the file, when it is missing, does not load, or holds no triangles.
    """
    p = Path(path)
    if not p.is_file():
        raise ReroomError(f"{p}: mesh file to insert is missing")
    try:
        loaded = trimesh.load(str(p), force="mesh", process=False)
    except Exception as exc:  # trimesh raises many kinds for unreadable files
        raise ReroomError(f"{p}: mesh file does not load ({exc})") from exc
    if not isinstance(loaded, trimesh.Trimesh) or len(loaded.faces) == 0:
        raise ReroomError(f"{p}: mesh file holds no triangles")
    mesh = trimesh.Trimesh(
        np.asarray(loaded.vertices, float), np.asarray(loaded.faces), process=False
    )
    if not np.all(np.isfinite(mesh.vertices)):
        raise ReroomError(f"{p}: mesh file has non-finite vertex coordinates")
    if p.suffix.lower() in (".gltf", ".glb"):
        mesh.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [1, 0, 0]))
    return _recentre(mesh)


def _recentre(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    lo, hi = mesh.bounds
    mesh = mesh.copy()
    mesh.apply_translation([-(lo[0] + hi[0]) / 2, -(lo[1] + hi[1]) / 2, -lo[2]])
    return mesh


def object_mesh(obj: str) -> trimesh.Trimesh:
    """A bundled model by name, or a mesh file by path, in the object's own frame."""
    if obj in _BUILDERS:
        return _recentre(bundled_object(obj))
    if Path(obj).suffix.lower() in MESH_SUFFIXES or Path(obj).exists():
        return load_object_file(obj)
    return bundled_object(obj)  # raises, listing the bundled names


def placed_object(
    obj: str | trimesh.Trimesh,
    position: Sequence[float],
    rotation_deg: float = 0.0,
    scale: float = 1.0,
) -> trimesh.Trimesh:
    """The object scaled by ``scale``, turned ``rotation_deg`` about +Z, standing on ``position``.

    ``position`` is where the footprint centre stands, its ``z`` the height of the base
    (the floor), in the scan's mesh frame.
    """
    mesh = object_mesh(obj) if isinstance(obj, str) else _recentre(obj)
    a = np.radians(float(rotation_deg))
    m = np.eye(4)
    m[:3, :3] = float(scale) * np.array(
        [[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0], [0.0, 0.0, 1.0]]
    )
    m[:3, 3] = np.asarray(position, float)
    mesh.apply_transform(m)
    return mesh
