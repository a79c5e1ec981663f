"""Triangle meshes in PLY: validated reading and attribute-preserving writing.

The central mesh object is :class:`trimesh.Trimesh`. Per-vertex data that
trimesh does not model (radiance, albedo, labels, flags) travels in
``mesh.vertex_attributes`` and is written as extra PLY vertex properties.

PLY files are parsed with :mod:`plyfile` rather than trimesh's loader because
trimesh silently triangulates quads and drops unknown properties; a scan loader
must instead *report* non-triangle faces and keep every property.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import trimesh

from reroom.errors import ScanError
from reroom.io.atomic import atomic_path

if TYPE_CHECKING:
    from plyfile import PlyData

_RGB = ("r", "g", "b")


def read_ply(path: str | Path) -> trimesh.Trimesh:
    """Read a triangle mesh from a PLY file, validating it.

    Extra vertex properties (anything but x, y, z, nx, ny, nz) are kept in
    ``mesh.vertex_attributes``; properties named ``<name>_r``, ``<name>_g``,
    ``<name>_b`` are gathered into one ``(N, 3)`` array ``<name>``, and the
    standard ``red, green, blue`` into ``color`` (uint8).

    Raises
    ------
    ScanError
        If the file is missing, is not a PLY file, has no vertices or no faces,
        has non-triangle faces, face indices out of range, or non-finite
        vertex coordinates.
    """
    from plyfile import PlyData, PlyParseError

    path = Path(path)
    if not path.is_file():
        raise ScanError(path, "mesh file is missing")
    try:
        ply = _read_triangles_fast(path)
        if ply is None:
            ply = PlyData.read(str(path), mmap=False)
    except (PlyParseError, ValueError, OSError, EOFError, IndexError, KeyError) as exc:
        raise ScanError(path, f"is not a readable PLY mesh ({exc})") from exc
    names = [el.name for el in ply.elements]
    if "vertex" not in names:
        raise ScanError(path, "has no 'vertex' element")
    vdata = ply["vertex"].data
    if len(vdata) == 0:
        raise ScanError(path, "mesh has no vertices")
    for coord in ("x", "y", "z"):
        if coord not in vdata.dtype.names:
            raise ScanError(path, f"vertex element lacks the '{coord}' property")
    vertices = np.stack([vdata["x"], vdata["y"], vdata["z"]], axis=1).astype(np.float64)
    if not np.all(np.isfinite(vertices)):
        bad = int(np.count_nonzero(~np.isfinite(vertices).all(axis=1)))
        raise ScanError(path, f"{bad} vertices have non-finite coordinates")
    if "face" not in names or len(ply["face"].data) == 0:
        raise ScanError(path, "mesh has no faces (a point cloud is not a mesh)")
    fdata = ply["face"].data
    index_prop = next(
        (p for p in ("vertex_indices", "vertex_index") if p in fdata.dtype.names), None
    )
    if index_prop is None:
        raise ScanError(path, "face element lacks 'vertex_indices'")
    lists = fdata[index_prop]
    if lists.ndim == 2:  # fixed-size records from the fast reader
        sizes = np.full(len(lists), lists.shape[1], np.int64)
    else:
        sizes = np.fromiter((len(f) for f in lists), dtype=np.int64, count=len(lists))
    if np.any(sizes != 3):
        bad_sizes = sorted(set(sizes[sizes != 3].tolist()))
        raise ScanError(
            path,
            f"{int(np.count_nonzero(sizes != 3))} faces are not triangles "
            f"(faces with {bad_sizes} vertices); triangulate the mesh first",
        )
    if lists.ndim == 2:
        faces = lists.astype(np.int64)
    else:
        faces = np.vstack(lists).astype(np.int64) if len(lists) else np.zeros((0, 3), np.int64)
    if faces.min() < 0 or faces.max() >= len(vertices):
        raise ScanError(path, f"face indices out of range [0, {len(vertices)})")

    mesh = trimesh.Trimesh(vertices=vertices, faces=faces, process=False, validate=False)
    attrs = _gather_attributes(vdata)
    if "color" in attrs:
        rgba = np.concatenate([attrs["color"], np.full((len(vertices), 1), 255, np.uint8)], axis=1)
        mesh.visual = trimesh.visual.ColorVisuals(mesh, vertex_colors=rgba)
    mesh.vertex_attributes.update(attrs)
    return mesh


def _read_triangles_fast(path: Path) -> PlyData | None:
    """Read a binary PLY whose faces are all triangles as fixed-size records, or ``None``.

    plyfile reads variable-length face lists one Python object per face (6 s for 400k
    faces); told that every list has 3 entries it maps the file as one structured array
    (0.02 s). A file with any other face size fails that read, and the caller falls back
    to the general reader, which reports the non-triangle faces.
    """
    from plyfile import PlyData, PlyParseError

    lengths = {"face": {"vertex_indices": 3, "vertex_index": 3}}
    try:
        ply = PlyData.read(str(path), mmap="c", known_list_len=lengths)
        for el in ply.elements:  # copy out of the memory map, so the file is not held open
            el.data = np.array(el.data)
    except (PlyParseError, ValueError, IndexError, KeyError):
        return None
    return ply


def _gather_attributes(vdata: np.ndarray) -> dict[str, np.ndarray]:
    skip = {"x", "y", "z", "nx", "ny", "nz"}
    props = [p for p in vdata.dtype.names if p not in skip]
    attrs: dict[str, np.ndarray] = {}
    used: set[str] = set()
    if all(c in props for c in ("red", "green", "blue")):
        attrs["color"] = np.stack([vdata[c] for c in ("red", "green", "blue")], 1).astype(np.uint8)
        used |= {"red", "green", "blue", "alpha"}
    for p in props:
        if p in used:
            continue
        if p.endswith("_r"):
            base = p[:-2]
            trio = [f"{base}_{c}" for c in _RGB]
            if all(t in props for t in trio):
                attrs[base] = np.stack([np.asarray(vdata[t]) for t in trio], axis=1)
                used.update(trio)
                continue
        if p.endswith(("_g", "_b")) and p[:-2] + "_r" in props:
            continue
        attrs[p] = np.asarray(vdata[p])
        used.add(p)
    return attrs


def write_ply(
    path: str | Path,
    mesh: trimesh.Trimesh,
    attributes: dict[str, np.ndarray] | None = None,
    *,
    binary: bool = True,
) -> Path:
    """Write ``mesh`` as PLY with per-vertex ``attributes``, atomically.

    ``attributes`` defaults to ``mesh.vertex_attributes``. An ``(N, 3)`` float
    attribute ``name`` is written as ``name_r, name_g, name_b``; ``color``
    (uint8 ``(N, 3)``) as the standard ``red, green, blue``. Float attributes
    are written as float32, integer ones keep their type.
    """
    attributes = dict(mesh.vertex_attributes if attributes is None else attributes)
    if binary:
        return write_triangle_ply(path, mesh.vertices, mesh.faces, attributes)
    from plyfile import PlyData, PlyElement

    v = np.asarray(mesh.vertices)
    n = len(v)
    fields: list[tuple[str, np.ndarray]] = [
        ("x", v[:, 0].astype(np.float32)),
        ("y", v[:, 1].astype(np.float32)),
        ("z", v[:, 2].astype(np.float32)),
    ]
    for name, value in attributes.items():
        arr = np.asarray(value)
        if arr.shape[0] != n:
            raise ValueError(f"attribute {name!r} has {arr.shape[0]} rows for {n} vertices")
        if name == "color":
            for i, c in enumerate(("red", "green", "blue")):
                fields.append((c, arr[:, i].astype(np.uint8)))
        elif arr.ndim == 2 and arr.shape[1] == 3:
            for i, c in enumerate(_RGB):
                fields.append((f"{name}_{c}", _cast(arr[:, i])))
        elif arr.ndim == 1:
            fields.append((name, _cast(arr)))
        else:
            raise ValueError(f"attribute {name!r} has unsupported shape {arr.shape}")
    vert = np.empty(n, dtype=[(k, a.dtype) for k, a in fields])
    for k, a in fields:
        vert[k] = a
    faces = np.asarray(mesh.faces, dtype=np.int32)
    face = np.empty(len(faces), dtype=[("vertex_indices", np.int32, (3,))])
    face["vertex_indices"] = faces
    ply = PlyData(
        [PlyElement.describe(vert, "vertex"), PlyElement.describe(face, "face")],
        text=not binary,
    )
    with atomic_path(path) as tmp:
        ply.write(str(tmp))
    return Path(path)


_PLY_TYPES = {
    np.dtype("float32"): "float",
    np.dtype("float64"): "double",
    np.dtype("uint8"): "uchar",
    np.dtype("int8"): "char",
    np.dtype("int16"): "short",
    np.dtype("uint16"): "ushort",
    np.dtype("int32"): "int",
    np.dtype("uint32"): "uint",
}


def _cast(a: np.ndarray) -> np.ndarray:
    a = np.asarray(a)
    if a.dtype == np.bool_:
        return a.astype(np.uint8)
    if np.issubdtype(a.dtype, np.floating):
        return a.astype(np.float32)
    if a.dtype == np.int64:
        return a.astype(np.int32)
    if a.dtype == np.uint64:
        return a.astype(np.uint32)
    return a


def write_triangle_ply(
    path: str | Path,
    vertices: np.ndarray,
    faces: np.ndarray,
    vertex_attributes: dict[str, np.ndarray] | None = None,
    face_attributes: dict[str, np.ndarray] | None = None,
) -> Path:
    """Write a binary little-endian PLY of a triangle mesh, atomically.

    Per-vertex attributes follow :func:`write_ply`'s conventions (an ``(N, 3)``
    attribute ``name`` becomes ``name_r, name_g, name_b``; ``color`` becomes
    ``red, green, blue``; floats are written as float32); per-face attributes must
    be 1D. plyfile writes list properties one Python call per face (1.1 s for 460k
    faces); a triangle mesh's face block has a fixed layout, so here it is one numpy
    record array (0.02 s), with the same bytes.
    """
    v = np.asarray(vertices)
    f = np.asarray(faces)
    vfields: list[tuple[str, np.ndarray]] = [
        ("x", v[:, 0].astype(np.float32)),
        ("y", v[:, 1].astype(np.float32)),
        ("z", v[:, 2].astype(np.float32)),
    ]
    for name, arr in (vertex_attributes or {}).items():
        arr = np.asarray(arr)
        if arr.shape[0] != len(v):
            raise ValueError(f"attribute {name!r} has {arr.shape[0]} rows for {len(v)} vertices")
        if name == "color":
            vfields += [
                (c, arr[:, i].astype(np.uint8)) for i, c in enumerate(("red", "green", "blue"))
            ]
        elif arr.ndim == 2 and arr.shape[1] == 3:
            vfields += [(f"{name}_{c}", _cast(arr[:, i])) for i, c in enumerate("rgb")]
        elif arr.ndim == 1:
            vfields.append((name, _cast(arr)))
        else:
            raise ValueError(f"attribute {name!r} has unsupported shape {arr.shape}")
    ffields: list[tuple[str, np.ndarray]] = []
    for name, arr in (face_attributes or {}).items():
        arr = np.asarray(arr)
        if arr.shape != (len(f),):
            raise ValueError(f"face attribute {name!r} must have shape ({len(f)},)")
        ffields.append((name, _cast(arr)))

    vert = np.empty(len(v), dtype=[(k, a.dtype.newbyteorder("<")) for k, a in vfields])
    for k, a in vfields:
        vert[k] = a
    face = np.empty(
        len(f),
        dtype=[("n", "u1"), ("idx", "<i4", (3,))]
        + [(k, a.dtype.newbyteorder("<")) for k, a in ffields],
    )
    face["n"] = 3
    face["idx"] = f.astype(np.int32)
    for k, a in ffields:
        face[k] = a
    header = ["ply", "format binary_little_endian 1.0", f"element vertex {len(v)}"]
    header += [f"property {_PLY_TYPES[a.dtype]} {k}" for k, a in vfields]
    header += [f"element face {len(f)}", "property list uchar int vertex_indices"]
    header += [f"property {_PLY_TYPES[a.dtype]} {k}" for k, a in ffields]
    header.append("end_header")
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        fh.write(("\n".join(header) + "\n").encode("ascii"))
        fh.write(vert.tobytes())
        fh.write(face.tobytes())
    return Path(path)
