"""Albedo textures of the room's planes from the photos (reroom.invert.textures)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import trimesh

from reroom.invert.textures import (
    SurfaceTexture,
    match_planes,
    photo_textures,
    planar_groups,
    read_texture_planes,
    read_textures,
    smoothness_per_plane,
    write_textures,
)
from reroom.rays import RayCaster
from reroom.render.camera import subpixel_positions
from reroom.scan import Intrinsics, look_at, write_scan
from reroom.scan.camera import Frame

SIZE = (4.0, 3.0, 2.5)
CELL = 0.5  # checker cells on the floor (metres)
DARK, LIGHT = 0.2, 0.6  # the floor's two albedos
WALL, CEILING = 0.5, 2.0  # the ceiling is brighter than white: saturated in every frame


def _grid(origin, u, v, nu: int, nv: int) -> tuple[np.ndarray, np.ndarray]:
    """A planar grid of ``nu x nv`` cells (vertices, faces), unwelded from the others."""
    a, b = np.meshgrid(np.linspace(0, 1, nu + 1), np.linspace(0, 1, nv + 1), indexing="ij")
    pts = np.asarray(origin) + a.reshape(-1, 1) * np.asarray(u) + b.reshape(-1, 1) * np.asarray(v)
    idx = np.arange((nu + 1) * (nv + 1)).reshape(nu + 1, nv + 1)
    q = np.stack([idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:], idx[:-1, 1:]], -1).reshape(-1, 4)
    return pts, np.concatenate([q[:, [0, 1, 2]], q[:, [0, 2, 3]]])


def _room() -> tuple[trimesh.Trimesh, np.ndarray]:
    """Box room as six unwelded grids (10 cm), labelled per plane, plus a board tilted
    20 degrees against the x = 4 wall that the layout also calls wall."""
    x, y, z = SIZE
    parts = [
        (_grid([0, 0, 0], [x, 0, 0], [0, y, 0], 40, 30), 1),  # floor
        (_grid([0, 0, z], [x, 0, 0], [0, y, 0], 40, 30), 2),  # ceiling
        (_grid([0, 0, 0], [x, 0, 0], [0, 0, z], 40, 25), 0),  # y = 0
        (_grid([0, y, 0], [x, 0, 0], [0, 0, z], 40, 25), 0),  # y = 3
        (_grid([0, 0, 0], [0, y, 0], [0, 0, z], 30, 25), 0),  # x = 0
        (_grid([x, 0, 0], [0, y, 0], [0, 0, z], 30, 25), 0),  # x = 4
        (_grid([x - 0.3, 1.0, 0.0], [0, 0.6, 0], [0.3, 0, 0.8], 6, 8), 0),  # the board
    ]
    verts, faces, labels = [], [], []
    n = 0
    for (v, f), lab in parts:
        verts.append(v)
        faces.append(f + n)
        labels.append(np.full(len(v), lab, np.uint8))
        n += len(v)
    mesh = trimesh.Trimesh(np.concatenate(verts), np.concatenate(faces), process=False)
    return mesh, np.concatenate(labels)


def _floor_albedo(p: np.ndarray) -> np.ndarray:
    odd = (np.floor(p[:, 0] / CELL) + np.floor(p[:, 1] / CELL)) % 2 == 1
    return np.where(odd, LIGHT, DARK)


def _radiance(points: np.ndarray) -> np.ndarray:
    """Radiance under a uniform irradiance of pi: the albedo (walls and board WALL)."""
    out = np.full(len(points), WALL)
    floor = points[:, 2] < 1e-4
    out[floor] = _floor_albedo(points[floor])
    out[points[:, 2] > SIZE[2] - 1e-4] = CEILING
    return out


@pytest.fixture(scope="module")
def texture_scan(tmp_path_factory) -> tuple[Path, trimesh.Trimesh, np.ndarray]:
    root = tmp_path_factory.mktemp("texscan")
    mesh, labels = _room()
    intr = Intrinsics.from_fov(160, 120, 70.0)
    poses = [
        look_at([0.5, 0.5, 1.6], [2.5, 1.8, 0.0]),
        look_at([3.5, 2.5, 1.7], [1.5, 1.0, 0.0]),
        look_at([2.0, 1.5, 2.0], [2.0, 1.4, 0.0]),
        look_at([2.0, 1.5, 1.2], [2.6, 2.0, 2.5]),  # the ceiling and the y = 3 wall
    ]
    scales = [1.0, 0.8, 1.2, 1.0]
    caster = RayCaster(mesh)
    images = []
    # Each pixel the mean of 4 x 4 rays over its square, as a sensor integrates.
    sub = subpixel_positions(0, intr.width, 0, intr.height, 4)
    for pose, s in zip(poses, scales, strict=True):
        o, d = Frame(0, root / "x.png", pose, intr).pixel_rays(sub)
        hits = caster.intersect(o, d, tmin=caster.eps)
        radiance = _radiance(hits.points).reshape(intr.height * intr.width, 16).mean(axis=1)
        linear = np.clip(radiance * s, 0.0, 1.0)
        code = np.round(255.0 * linear ** (1 / 2.2)).astype(np.uint8)
        images.append(np.repeat(code.reshape(intr.height, intr.width, 1), 3, axis=2))
    write_scan(root, mesh, intr, poses, images, meta={"reroom": {"response": "gamma2.2"}})
    (root / "hdr").mkdir()
    frames = [{"index": j, "scale": [s] * 3} for j, s in enumerate(scales)]
    (root / "hdr" / "exposures.json").write_text(
        json.dumps({"response": "gamma2.2", "frames": frames})
    )
    return root, mesh, labels


def test_planes_of_a_box_room_leave_out_a_tilted_board():
    mesh, labels = _room()
    planes, face_plane = planar_groups(mesh.vertices, mesh.faces, labels, np.eye(3))
    got = sorted((p["label"], p["axis"], round(p["offset"], 3)) for p in planes)
    assert got == [
        ("ceiling", 2, 2.5),
        ("floor", 2, 0.0),
        ("wall", 0, 0.0),
        ("wall", 0, 4.0),
        ("wall", 1, 0.0),
        ("wall", 1, 3.0),
    ]
    board = np.arange(len(mesh.faces)) >= len(mesh.faces) - 2 * 6 * 8
    assert np.all(face_plane[board] == -1)
    assert np.all(face_plane[~board] >= 0)


def test_textures_reproduce_the_photos_albedo(texture_scan):
    root, mesh, labels = texture_scan
    irradiance = np.full((len(mesh.vertices), 3), np.pi)
    textures, stats = photo_textures(root, mesh, labels, np.eye(3), irradiance, texel=0.05)
    by = {(t.label, t.axis, round(t.offset, 2)): t for t in textures}
    assert stats["frames_used"] == 4 and stats["samples"] > 10000
    # The ceiling is saturated in every frame: no texture, and a note that says so.
    assert ("ceiling", 2, 2.5) not in by
    assert stats["saturated"] > 1000
    assert any("ceiling" in n for n in stats["notes"])
    floor = by[("floor", 2, 0.0)]
    assert floor.observed_fraction > 0.5
    # Texel centres at least a texel from a checker edge: the checker, to 8-bit steps.
    h, w = floor.shape
    cu = floor.origin[0] + (np.arange(w) + 0.5) * floor.texel
    cv = floor.origin[1] + (np.arange(h) + 0.5) * floor.texel
    uu, vv = np.meshgrid(cu, cv)
    inner = (np.abs(uu / CELL - np.round(uu / CELL)) * CELL > 0.06) & (
        np.abs(vv / CELL - np.round(vv / CELL)) * CELL > 0.06
    )
    ok = inner & (floor.count > 0) & (uu > 0) & (uu < 4) & (vv > 0) & (vv < 3)
    assert ok.sum() > 500
    want = _floor_albedo(np.c_[uu[ok], vv[ok]])
    np.testing.assert_allclose(floor.albedo[ok][:, 0], want, rtol=0.03)
    # Without per-vertex albedo the local mean is the photos' own, so the detail is the
    # pattern about it: above 1 on light cells, below on dark ones.
    light = want == LIGHT
    assert floor.detail[ok][light, 0].mean() > 1.2 and floor.detail[ok][~light, 0].mean() < 0.8
    # The walls: uniform; the board's pixels are not on the x = 4 wall's texture.
    # (a ray that grazes the floor corner may see the floor: a texel or two at the foot)
    wall = by[("wall", 0, 4.0)]
    seen = wall.count > 0
    assert np.mean(np.abs(wall.albedo[seen] - WALL) < 0.03 * WALL) > 0.995


def test_solved_texels_sharpen_the_edges_the_footprints_blur(texture_scan):
    root, mesh, labels = texture_scan
    irradiance = np.full((len(mesh.vertices), 3), np.pi)
    errors, texels = {}, {}
    for solve in (False, True):
        textures, stats = photo_textures(
            root, mesh, labels, np.eye(3), irradiance, deconvolve=solve
        )
        floor = next(t for t in textures if t.label == "floor")
        h, w = floor.shape
        cu = floor.origin[0] + (np.arange(w) + 0.5) * floor.texel
        cv = floor.origin[1] + (np.arange(h) + 0.5) * floor.texel
        uu, vv = np.meshgrid(cu, cv)
        edge = (
            np.minimum(
                np.abs(uu / CELL - np.round(uu / CELL)), np.abs(vv / CELL - np.round(vv / CELL))
            )
            * CELL
        )
        ok = (floor.count > 0) & (uu > 0.1) & (uu < 3.9) & (vv > 0.1) & (vv < 2.9)
        want = _floor_albedo(np.c_[uu.ravel(), vv.ravel()]).reshape(h, w)
        err = np.abs(floor.albedo[..., 0] - want) / want
        near, far = ok & (edge > 0.01) & (edge < 0.03), ok & (edge > 0.05)
        errors[solve] = (np.median(err[near]), np.median(err[far]), np.percentile(err[far], 95))
        texels[solve] = stats["texel"]
        if solve:
            assert stats["deconvolution"]["footprint"] > 1.0  # in texels
    # Texels half the median footprint when solved.
    assert texels[True] <= 0.5 * texels[False] + 1e-3
    # 1-3 cm from a cell's edge the mean per texel mixes both cells; the solve does not.
    assert errors[True][0] < 0.3 * errors[False][0]
    # Away from the edges both are the checker (the solve a little noisier: 8-bit steps).
    assert errors[True][1] < 0.01 and errors[True][2] < 0.05


def test_local_mean_follows_the_per_vertex_albedo(texture_scan):
    root, mesh, labels = texture_scan
    irradiance = np.full((len(mesh.vertices), 3), np.pi)
    vertex = np.full((len(mesh.vertices), 3), 0.6)  # walls 20 % above what the photos say
    textures, _ = photo_textures(root, mesh, labels, np.eye(3), irradiance, vertex, texel=0.05)
    wall = next(t for t in textures if t.label == "wall" and t.axis == 1 and t.offset > 1)
    seen = wall.count > 0
    np.testing.assert_allclose(wall.albedo[seen], 0.6, rtol=0.03)
    np.testing.assert_allclose(wall.detail[seen], 1.0, atol=0.03)


def test_bad_inputs_are_named(texture_scan, tmp_path: Path):
    root, mesh, labels = texture_scan
    with pytest.raises(ValueError, match="irradiance has shape"):
        photo_textures(root, mesh, labels, np.eye(3), np.ones((3, 3)))
    with pytest.raises(ValueError, match="texel must be positive"):
        photo_textures(root, mesh, labels, np.eye(3), np.ones((len(labels), 3)), texel=0.0)
    # No labelled plane: no textures, and a note.
    textures, stats = photo_textures(
        root, mesh, np.full(len(labels), 255), np.eye(3), np.ones((len(labels), 3))
    )
    assert textures == [] and "no floor, ceiling or wall plane" in stats["notes"][0]


def test_write_read_round_trip_and_plane_matching(tmp_path: Path):
    rng = np.random.default_rng(0)
    tex = SurfaceTexture(
        label="floor",
        axis=2,
        offset=0.0,
        origin=(-0.1, -0.2),
        texel=0.1,
        albedo=rng.uniform(0, 1, (5, 7, 3)).astype(np.float32),
        detail=rng.uniform(0.5, 1.5, (5, 7, 3)).astype(np.float32),
        count=rng.integers(0, 3, (5, 7)),
        rotation=np.eye(3),
        name="floor_0",
    )
    entries = write_textures([tex], tmp_path)
    (back,) = read_textures(entries, tmp_path)
    np.testing.assert_allclose(back.albedo, tex.albedo, atol=1e-6)
    np.testing.assert_allclose(back.detail, tex.detail, atol=1e-6)
    np.testing.assert_array_equal(back.count, tex.count)
    # Texture coordinates: the corner is (0, 0), the far corner (1, 1).
    uv = back.texture_coords(np.array([[-0.1, -0.2, 0.0], [0.6, 0.3, 0.0]]))
    np.testing.assert_allclose(uv, [[0, 0], [1, 1]], atol=1e-12)
    # A floor face 5 cm above the plane matches; a wall face or a face 0.5 m up does not.
    v = np.array([[0, 0, 0.05], [1, 0, 0.05], [0, 1, 0.05], [0, 0, 0.5], [1, 0, 0.5], [0, 1, 0.5]])
    f = np.array([[0, 1, 2], [3, 4, 5], [0, 1, 2]])
    got = match_planes([back], v, f, np.array(["floor", "floor", "wall"], dtype=object))
    assert got.tolist() == [0, -1, -1]
    # The renderer's planes, read without the images: the same mapping.
    (plane,) = read_texture_planes(entries, tmp_path)
    np.testing.assert_allclose(plane.texture_coords(v), back.texture_coords(v))
    # A mis-sized file is named, and so is a missing one.
    entries[0]["width"] = 8
    with pytest.raises(Exception, match="floor_0.exr"):
        read_textures(entries, tmp_path)
    (tmp_path / "textures" / "floor_0.exr").unlink()
    with pytest.raises(Exception, match="floor_0.exr.*missing"):
        read_texture_planes(entries, tmp_path)


def test_an_unreadable_frame_is_skipped_with_a_warning(texture_scan, tmp_path: Path):
    import shutil

    root, mesh, labels = texture_scan
    copy = tmp_path / "scan"
    shutil.copytree(root, copy)
    frames = json.loads((copy / "transforms.json").read_text())["frames"]
    bad = copy / frames[0]["file_path"]
    bad.write_bytes(b"not a png")
    irradiance = np.full((len(mesh.vertices), 3), np.pi)
    with pytest.warns(UserWarning, match="cannot read it"):
        textures, stats = photo_textures(copy, mesh, labels, np.eye(3), irradiance, texel=0.05)
    assert stats["frames_unreadable"] == [str(bad)]
    assert stats["frames_used"] == 3 and any(t.label == "floor" for t in textures)


def test_unseen_texels_continue_a_striped_pattern():
    from reroom.invert.textures import _continue_pattern

    rng = np.random.default_rng(3)
    h, w = 24, 40
    stripes = rng.uniform(0.6, 1.4, h)  # one value per row: planks along u
    detail = np.repeat(np.repeat(stripes[:, None], w, axis=1)[..., None], 3, axis=2)
    seen = np.ones((h, w), bool)
    seen[6:15, 12:25] = False  # under a sofa
    got = _continue_pattern(np.where(seen[..., None], detail, 1.0), seen)
    np.testing.assert_allclose(got, detail)
    # The same along columns; and no dominant direction (noise): unseen stays 1.
    got_t = _continue_pattern(np.where(seen.T[..., None], detail.transpose(1, 0, 2), 1.0), seen.T)
    np.testing.assert_allclose(got_t, detail.transpose(1, 0, 2))
    noise = rng.uniform(0.8, 1.2, (h, w, 3))
    flat = _continue_pattern(np.where(seen[..., None], noise, 1.0), seen)
    assert np.all(flat[~seen] == 1.0)


def test_pixels_across_a_silhouette_are_left_out(tmp_path: Path):
    """A photo's pixel integrates its whole footprint: where a dark board stands in front
    of the wall, the pixels along its outline mix the two. Those must not darken the
    wall's texture (``footprint``); with the test off, they do."""
    root = tmp_path / "scan"
    mesh, labels = _room()
    n_board = 2 * 6 * 8  # the board's faces come last
    intr = Intrinsics.from_fov(160, 120, 70.0)
    poses = [look_at([1.0, 1.2, 1.2], [4.0, 1.4, 0.5]), look_at([1.5, 2.2, 1.4], [4.0, 1.0, 0.4])]
    caster = RayCaster(mesh)
    images = []
    ss = 4  # 4 x 4 rays per pixel, averaged: the sensor's box footprint
    for pose in poses:
        frame = Frame(0, root / "x.png", pose, intr)
        off = (np.arange(ss) + 0.5) / ss
        jj, ii, sy, sx = np.meshgrid(
            np.arange(intr.width), np.arange(intr.height), off, off, indexing="xy"
        )
        uv = np.stack([(jj + sx).ravel(), (ii + sy).ravel()], axis=1)
        o, d = frame.pixel_rays(uv)
        hits = caster.intersect(o, d, tmin=caster.eps)
        rad = _radiance(hits.points)
        rad[hits.face >= len(mesh.faces) - n_board] = 0.05  # a dark board
        lin = rad.reshape(jj.shape).mean(axis=(2, 3))  # (height, width): "xy" indexing
        code = np.round(255.0 * np.clip(lin, 0, 1) ** (1 / 2.2)).astype(np.uint8)
        images.append(np.repeat(code[..., None], 3, axis=2))
    write_scan(root, mesh, intr, poses, images, meta={"reroom": {"response": "gamma2.2"}})
    (root / "hdr").mkdir()
    frames = [{"index": j, "scale": [1.0] * 3} for j in range(len(poses))]
    (root / "hdr" / "exposures.json").write_text(
        json.dumps({"response": "gamma2.2", "frames": frames})
    )
    irradiance = np.full((len(mesh.vertices), 3), np.pi)
    walls = {}
    for fp in (1.0, 0.0):
        textures, stats = photo_textures(
            root, mesh, labels, np.eye(3), irradiance, texel=0.03, footprint=fp
        )
        walls[fp] = next(t for t in textures if t.label == "wall" and t.axis == 0 and t.offset > 1)
        if fp:
            assert stats["edge"] > 100
        else:
            assert stats["edge"] == 0
    # Off: texels along the board's outline read dark (a 3 % tolerance on WALL = 0.5).
    seen = walls[0.0].count > 0
    dark = np.abs(walls[0.0].albedo[seen][:, 0] - WALL) > 0.03 * WALL
    assert dark.sum() > 20
    # On: every texel it keeps is the wall's albedo (to 8-bit steps).
    seen = walls[1.0].count > 0
    assert seen.sum() > 1000
    np.testing.assert_allclose(walls[1.0].albedo[seen][:, 0], WALL, rtol=0.03)


def test_a_beam_edge_between_vertices_stays_out_of_the_albedo(tmp_path: Path):
    """A downlight's beam ends in a sharp circle on the floor, between the mesh's 10 cm
    vertices. Interpolating the vertices' irradiance blurs that edge, and the texture
    takes the difference as albedo: a ring, a ghost of the beam that stays when the light
    is moved. With the point light's direct light evaluated at each sample
    (``sharp_irradiance``) the floor's checker comes back without it."""
    from reroom.invert.direct import point_light_irradiance

    root = tmp_path / "scan"
    mesh, labels = _room()
    caster = RayCaster(mesh)
    light, axis = np.array([2.0, 1.5, 2.4]), np.array([0.0, 0.0, 1.0])
    bins = 64
    theta = (np.arange(bins) + 0.5) * np.pi / bins  # from the axis: pi is straight down
    profile = np.where(theta > np.radians(155.0), 8.0, 0.0)  # a 25-degree beam
    intens = np.repeat(profile[:, None], 3, axis=1)

    def sharp(points: np.ndarray, normals: np.ndarray) -> np.ndarray:
        return point_light_irradiance(
            caster, points, normals, light, axis, intens, interpolation="constant"
        )

    up = np.tile([0.0, 0.0, 1.0], (len(mesh.vertices), 1))
    floor_v = labels == 1
    sharp_v = np.zeros((len(mesh.vertices), 3))
    sharp_v[floor_v] = sharp(mesh.vertices[floor_v], up[floor_v])
    intr = Intrinsics.from_fov(160, 120, 70.0)
    poses = [look_at([0.5, 0.5, 1.6], [2.2, 1.6, 0.0]), look_at([3.5, 2.5, 1.7], [1.8, 1.4, 0.0])]
    images = []
    for pose in poses:
        o, d = Frame(0, root / "x.png", pose, intr).pixel_rays()
        hits = caster.intersect(o, d, tmin=caster.eps)
        e = np.full(len(o), np.pi)
        on_floor = hits.hit & (hits.points[:, 2] < 1e-4)
        n_up = np.tile([0.0, 0.0, 1.0], (int(on_floor.sum()), 1))
        e[on_floor] += sharp(hits.points[on_floor], n_up)[:, 0]
        linear = np.clip(_radiance(hits.points) * e / np.pi * 0.5, 0.0, 1.0)
        code = np.round(255.0 * linear ** (1 / 2.2)).astype(np.uint8)
        images.append(np.repeat(code.reshape(intr.height, intr.width, 1), 3, axis=2))
    write_scan(root, mesh, intr, poses, images, meta={"reroom": {"response": "gamma2.2"}})
    (root / "hdr").mkdir()
    frames = [{"index": j, "scale": [0.5] * 3} for j in range(len(poses))]
    (root / "hdr" / "exposures.json").write_text(
        json.dumps({"response": "gamma2.2", "frames": frames})
    )
    irradiance = np.pi + sharp_v
    floors = {}
    for on in (False, True):
        extra = {"sharp_irradiance": sharp, "sharp_at_vertices": sharp_v} if on else {}
        textures, _ = photo_textures(
            root, mesh, labels, np.eye(3), irradiance, texel=0.025, **extra
        )
        floors[on] = next(t for t in textures if t.label == "floor")
    t = floors[True]
    h, w = t.shape
    uu, vv = np.meshgrid(
        t.origin[0] + (np.arange(w) + 0.5) * t.texel, t.origin[1] + (np.arange(h) + 0.5) * t.texel
    )
    radius = 2.4 * np.tan(np.radians(25.0))
    ring = np.abs(np.hypot(uu - light[0], vv - light[1]) - radius) < 0.05
    inner = (np.abs(uu / CELL - np.round(uu / CELL)) * CELL > 0.04) & (
        np.abs(vv / CELL - np.round(vv / CELL)) * CELL > 0.04
    )
    ok = ring & inner & (floors[False].count > 0) & (t.count > 0)
    assert ok.sum() > 100
    want = _floor_albedo(np.c_[uu[ok], vv[ok]])
    err = {on: np.abs(floors[on].albedo[ok][:, 0] / want - 1.0) for on in (False, True)}
    assert np.mean(err[False] > 0.1) > 0.2  # the ghost ring
    assert np.percentile(err[True], 95) < 0.04


def test_sharp_irradiance_comes_with_its_vertex_values(texture_scan):
    root, mesh, labels = texture_scan
    irradiance = np.full((len(mesh.vertices), 3), np.pi)
    with pytest.raises(ValueError, match="go together"):
        photo_textures(
            root, mesh, labels, np.eye(3), irradiance, sharp_irradiance=lambda p, n: 0 * p
        )
    with pytest.raises(ValueError, match="sharp_at_vertices has shape"):
        photo_textures(
            root,
            mesh,
            labels,
            np.eye(3),
            irradiance,
            sharp_irradiance=lambda p, n: 0 * p,
            sharp_at_vertices=np.zeros((3, 3)),
        )


def test_texture_smoothness_per_label():
    labels = ["wall", "floor", "wall", "ceiling"]
    np.testing.assert_array_equal(smoothness_per_plane(2.0, labels), [2, 2, 2, 2])
    np.testing.assert_array_equal(
        smoothness_per_plane({"wall": 4.0, "floor": 0.5}, labels), [4, 0.5, 4, 1]
    )
    with pytest.raises(ValueError, match="unknown label"):
        smoothness_per_plane({"sofa": 1.0}, labels)
    with pytest.raises(ValueError, match="finite and >= 0"):
        smoothness_per_plane({"wall": -1.0}, labels)
    with pytest.raises(ValueError, match="finite and >= 0"):
        smoothness_per_plane(float("nan"), labels)
