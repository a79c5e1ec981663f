"""A line light's tube and trough from the photos (``reroom.invert.line_photos``).

The photos are rendered here by ray casting a baffled tube under a ceiling: a pixel is
the mean of 4 x 4 sub-pixel rays, the tube 30 times the white level (so it clips, as a
tube does in an auto-exposed room photo), everything else mid-grey.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import trimesh

from reroom.invert.basis import LineBasis
from reroom.invert.line_fixture import line_open_fraction
from reroom.invert.line_photos import (
    PhotoTube,
    TubeSighting,
    caster_without_fixture,
    cutoff_angle,
    fixture_extent,
    observe_tube,
    trough_edges,
    trough_fixture,
    tube_extent,
)
from reroom.rays import RayCaster
from reroom.rays.geometry import segment_distance
from reroom.scan.camera import Frame, Intrinsics, look_at

AXIS_Z, RADIUS, HALF_GAP, BAFFLE_BOTTOM, CEILING = 2.6, 0.016, 0.07, 2.54, 2.7
P0, P1, UP = np.array([0.0, 0.0, AXIS_Z]), np.array([1.2, 0.0, AXIS_Z]), np.array([0, 0, 1.0])


def _fixture_mesh() -> trimesh.Trimesh:
    """Two baffles (y = +-7 to 8 cm, z 2.54-2.65) and a housing slab (z 2.65-2.70)."""
    parts = []
    for y0 in (-HALF_GAP - 0.01, HALF_GAP):
        b = trimesh.creation.box(extents=(1.3, 0.01, 0.11))
        b.apply_translation((0.6, y0 + 0.005, BAFFLE_BOTTOM + 0.055))
        parts.append(b)
    top = trimesh.creation.box(extents=(1.3, 0.16, 0.05))
    top.apply_translation((0.6, 0.0, 2.675))
    parts.append(top)
    return trimesh.util.concatenate(parts)


def _scene() -> tuple[trimesh.Trimesh, int]:
    """The tube, its fixture and a ceiling; returns the mesh and the tube's face count."""
    tube = trimesh.creation.cylinder(radius=RADIUS, segment=(P0, P1), sections=32)
    ceiling = trimesh.Trimesh(
        [[-6, -6, CEILING], [6, -6, CEILING], [6, 6, CEILING], [-6, 6, CEILING]],
        [[0, 2, 1], [0, 3, 2]],
    )
    return trimesh.util.concatenate([tube, _fixture_mesh(), ceiling]), len(tube.faces)


def _frames(
    width: int = 160, height: int = 120, sub_px: int = 4
) -> tuple[list[Frame], dict[int, np.ndarray]]:
    """Cameras at 1.5 m on one side of the tube (y <= 0.5 m), each photo rendered
    (``sub_px`` x ``sub_px`` rays a pixel)."""
    mesh, n_tube = _scene()
    caster = RayCaster(mesh)
    intr = Intrinsics.from_fov(width, height, 60.0)
    rng = np.random.default_rng(3)
    frames, images = [], {}
    eyes = [(x, y, 1.5) for y in np.linspace(-3.2, 0.5, 12) for x in (-0.4, 0.6, 1.6)]
    sub = (np.arange(sub_px) + 0.5) / sub_px
    ox, oy = np.meshgrid(sub, sub)
    for i, eye in enumerate(eyes):
        target = np.array([0.6 + rng.uniform(-0.3, 0.3), 0.0, AXIS_Z])
        frame = Frame(i, Path(f"frame_{i:03d}.png"), look_at(np.array(eye), target), intr)
        jj, ii = np.meshgrid(np.arange(intr.width), np.arange(intr.height))
        uv = np.stack(
            [(jj[..., None] + ox.ravel()).ravel(), (ii[..., None] + oy.ravel()).ravel()], axis=1
        )
        o, d = frame.pixel_rays(uv)
        hits = caster.intersect(o, d)
        radiance = np.where(hits.hit & (hits.face < n_tube), 30.0, 0.4)
        pixel = radiance.reshape(intr.height, intr.width, sub_px**2).mean(axis=2)
        images[i] = np.repeat(
            (np.clip(pixel, 0, 1) * 255 + 0.5).astype(np.uint8)[..., None], 3, axis=2
        )
        frames.append(frame)
    return frames, images


@pytest.fixture(scope="module")
def photos() -> tuple[list[Frame], dict[int, np.ndarray]]:
    return _frames()


@pytest.fixture(scope="module")
def fine_photos() -> tuple[list[Frame], dict[int, np.ndarray]]:
    """The same views at 320x240: the tube 4-5 pixels wide, so part of it can be seen."""
    return _frames(320, 240, 2)


def _observe(photos, p0, p1):
    frames, images = photos
    mesh, _ = _scene()
    others = caster_without_fixture(mesh.vertices, mesh.faces, p0, p1)
    return observe_tube(frames, lambda f: images[f.index], others, p0, p1, UP)


def test_the_axis_radius_and_cutoff_come_from_the_stripes(photos) -> None:
    # Detected 2 cm to the side and 4 cm low, as on the fused `furnished` scan.
    shift = np.array([0.0, 0.02, -0.04])
    tube = _observe(photos, P0 + shift, P1 + shift)
    assert tube.stripe_samples >= 50 and tube.stripe_frames >= 5
    np.testing.assert_allclose(tube.p0, P0, atol=0.004)
    np.testing.assert_allclose(tube.p1, P1, atol=0.004)
    assert tube.residual_m < 0.004
    # From the rays through the stripes' edges, which graze the tube. These photos'
    # 4 x 4 sub-pixel rays miss a tube's sliver under an eighth of a pixel at each edge,
    # so the stripes read about a quarter of a pixel narrow (0.92 of the radius here).
    assert 0.85 * RADIUS < tube.radius < 1.1 * RADIUS
    # side = x cross z = -y: the cameras (y <= 0.5) see the tube from the +side only,
    # and the baffle edge (7 cm out, 6 cm down) hides it all from about 59 degrees on.
    hidden = np.degrees(np.arccos(-RADIUS / np.hypot(HALF_GAP, 0.06))) - np.degrees(
        np.arctan2(0.06, HALF_GAP)
    )
    assert tube.cutoff_deg[0] is None
    assert abs(tube.cutoff_deg[1] - hidden) < 6.0
    summary = tube.summary()
    assert summary["frames_bright"] < summary["frames_seeing"]


def test_edge_rays_that_graze_a_cylinder_pass_its_axis_at_its_radius() -> None:
    """``_line_distance``: a ray tangent to the tube passes the axis at the radius, from
    any direction; a ray along the axis, at its offset."""
    from reroom.invert.line_photos import _line_distance

    rng = np.random.default_rng(7)
    eyes = rng.uniform([-1.0, -3.0, 0.5], [2.0, -0.5, 1.8], size=(20, 3))
    # The point of the tube's silhouette: on the circle around the axis at x, the tangent
    # from the eye's projection onto the cross-section plane.
    x = rng.uniform(0.1, 1.1, size=20)
    q = eyes[:, 1:] - [0.0, AXIS_Z]  # the eye in the cross-section (y, z), axis at 0
    dist = np.linalg.norm(q, axis=1)
    ang = np.arctan2(q[:, 1], q[:, 0]) + np.arccos(RADIUS / dist)
    touch = np.stack([x, RADIUS * np.cos(ang), AXIS_Z + RADIUS * np.sin(ang)], axis=1)
    d = touch - eyes
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    np.testing.assert_allclose(_line_distance(eyes, d, P0, P1), RADIUS, rtol=1e-9)
    along = _line_distance(np.array([[0.0, 0.03, AXIS_Z]]), np.array([[1.0, 0.0, 0.0]]), P0, P1)
    np.testing.assert_allclose(along, [0.03])


def test_the_trough_leaves_the_tube_open_as_the_true_fixture_does(photos) -> None:
    tube = _observe(photos, P0, P1)
    mesh, _ = _scene()
    bottom, top = fixture_extent(mesh.vertices, tube.p0, tube.p1, UP, tube.radius)
    assert bottom == pytest.approx(AXIS_Z - BAFFLE_BOTTOM, abs=0.005)
    assert top == pytest.approx(CEILING - AXIS_Z, abs=0.005)
    trough = trough_edges(tube, bottom, tube.radius)
    assert "mirrored" in trough.how[0] and "deg" in trough.how[1]
    edges = trough.edges
    assert edges[0] == edges[1] and abs(edges[1] - HALF_GAP) < 0.015
    assert abs(trough.bottom - bottom) < 0.006  # the scanned depth was right
    basis = LineBasis(16, 3)
    ours = _trough_open(tube, trough, top, basis)
    true = _true_open(basis)
    assert np.linalg.norm(ours - true) / np.linalg.norm(true) < 0.15
    assert np.all(ours[basis.index(np.arange(7), 0)] <= 0.05)  # upwards, across: the housing


def _trough_open(tube, trough, top: float, basis: LineBasis) -> np.ndarray:
    caster = trough_fixture(tube.p0, tube.p1, UP, trough.edges, trough.bottom, top)
    return line_open_fraction(
        caster.occluded, tube.p0, tube.p1, UP, tube.radius, basis, 0.3, samples=64
    )


def _true_open(basis: LineBasis) -> np.ndarray:
    mesh, n_tube = _scene()
    keep = np.arange(len(mesh.faces)) >= n_tube  # the fixture and the ceiling
    fixture = RayCaster(mesh.vertices, mesh.faces[keep], eps=1e-6)
    return line_open_fraction(fixture.occluded, P0, P1, UP, RADIUS, basis, 0.3, samples=64)


def test_a_shallow_scanned_underside_is_corrected_by_the_part_hidden_views(fine_photos) -> None:
    # A fused scan's block ends 6 mm above the baffles' bottom (as on `furnished`): with
    # that depth held, the part-hidden views and the cut-off disagree; fitted, the depth
    # moves toward the truth and the trough's open fraction toward the true fixture's.
    tube = _observe(fine_photos, P0, P1)
    depth, shallow, top = AXIS_Z - BAFFLE_BOTTOM, AXIS_Z - BAFFLE_BOTTOM - 0.006, 0.1
    held = trough_edges(tube, shallow, tube.radius, bottom_sigma=1e-6)
    fitted = trough_edges(tube, shallow, tube.radius)
    assert abs(held.bottom - shallow) < 1e-5
    assert "fitted to the part-hidden views" in fitted.bottom_from
    assert abs(fitted.bottom - depth) < abs(shallow - depth)
    basis = LineBasis(16, 3)
    true = _true_open(basis)

    def err(t):
        return np.linalg.norm(_trough_open(tube, t, top, basis) - true) / np.linalg.norm(true)

    assert err(fitted) < err(held)


def test_views_too_coarse_to_see_part_of_the_tube_leave_the_scanned_depth() -> None:
    # One part-hidden view where the whole tube would span 1.6 pixels: its width says
    # nothing, so the depth stays the scanned one and the edge is the bracket's middle.
    sightings = [
        TubeSighting(0, 20.0, True, 10, 0.032, 0.02),
        TubeSighting(1, 47.0, True, 10, 0.015, 0.02),
        TubeSighting(2, 60.0, False, 10),
        TubeSighting(3, 62.0, False, 10),
    ]
    tube = PhotoTube(P0, P1, (0.0, 0.0), 30, 3, 0.001, RADIUS, sightings, (None, 53.5))
    trough = trough_edges(tube, 0.054, RADIUS)
    assert trough.bottom == 0.054 and trough.bottom_from == "scanned"
    assert "hidden from 47.0-60.0 deg" in trough.how[1] and trough.how[0] == "mirrored"
    # The same view in a finer photo (0.5 cm pixels) counts, and moves the depth.
    sightings[1] = TubeSighting(1, 47.0, True, 10, 0.015, 0.005)
    fine = trough_edges(tube, 0.054, RADIUS)
    assert "1 partial views" in fine.how[1] and fine.bottom_from.startswith("fitted")


def test_cutoff_angle_needs_dark_sightings_beyond_the_bright_ones() -> None:
    assert cutoff_angle([10, 20, 30], [True, True, True]) is None
    assert cutoff_angle([10, 20, 30], [False, False, False]) is None
    assert cutoff_angle([10, 40, 50], [True, False, True], min_dark=1) is not None
    # One stray dark sighting among bright ones does not move the split.
    assert cutoff_angle([10, 20, 25, 40, 60, 62], [True, False, True, True, False, False]) == 50.0


def test_no_trough_without_a_cutoff(photos) -> None:
    tube = _observe(photos, P0, P1)
    tube.cutoff_deg = (None, None)
    assert trough_edges(tube, 0.06, RADIUS) is None


def _fused_scan(photos, folder: Path) -> trimesh.Trimesh:
    """A fused scan's fixture written with the photos as a scan in ``folder``: one closed
    block from the baffles' bottom to the ceiling, the tube's lower half poking out of
    it, and the ceiling around it. Returns the mesh."""
    from reroom.scan import write_scan

    frames, images = photos
    block = trimesh.creation.box(extents=(1.3, 0.16, CEILING - BAFFLE_BOTTOM - 0.02))
    block.apply_translation((0.6, 0.0, 0.5 * (CEILING + BAFFLE_BOTTOM + 0.02)))
    ceiling = trimesh.creation.box(extents=(6.0, 6.0, 0.02))
    ceiling.apply_translation((0.6, 0.0, CEILING + 0.01))
    mesh = trimesh.util.concatenate([block, ceiling])
    write_scan(folder, mesh, frames[0].intrinsics, [f.c2w for f in frames],
               [images[f.index] for f in frames])  # fmt: skip
    return mesh


def test_the_pipeline_takes_the_tube_and_trough_from_the_photos(photos, tmp_path) -> None:
    from reroom.invert.pipeline import InvertOptions, _line_open_shape

    mesh = _fused_scan(photos, tmp_path)
    shift = np.array([0.0, 0.02, -0.04])  # the detected axis, on the block's underside
    geometry = {"p0": P0 + shift, "p1": P1 + shift, "d_perp": UP, "radius": 0.037}
    basis = LineBasis(16, 3)
    notes: list[str] = []
    shape, info, g = _line_open_shape(
        tmp_path, mesh, "tube", geometry, basis, InvertOptions(), notes
    )
    assert info["fixture_inside_fraction"] > 0.05
    assert "a trough from the photos instead" in notes[-1]
    assert g["axis_from"] == "photos" and geometry["radius"] == 0.037  # a copy
    np.testing.assert_allclose(g["p0"], P0, atol=0.004)
    assert 0.75 * RADIUS < g["radius"] < 1.35 * RADIUS
    photo = info["fixture_from_photos"]
    assert photo["detected_radius"] == 0.037 and photo["cutoff_deg"][0] is None
    assert shape is not None and shape.max() == 1.0
    # Without the photos (no scan there) the prior is dropped, with both reasons noted.
    notes = []
    shape, info, g = _line_open_shape(
        tmp_path / "nothing", mesh, "tube", geometry, basis, InvertOptions(), notes
    )
    assert shape is None and g is geometry and "photos cannot be read" in notes[0]
    assert "no shape prior" in notes[-1]
    off = InvertOptions(line_photo_fixture=False)
    shape, info, g = _line_open_shape(tmp_path, mesh, "tube", geometry, basis, off, [])
    assert shape is None and "fixture_from_photos" not in info


def test_an_axis_seen_on_one_half_moves_parallel_to_itself(photos) -> None:
    frames, images = photos
    mesh, _ = _scene()
    far = ~(segment_distance(mesh.vertices, P0, P1) < 0.25)[mesh.faces].any(axis=1)
    # What may stand between a camera and the tube: the room, and a slab under the
    # tube's second half that hides it from every camera.
    slab = trimesh.creation.box(extents=(1.25, 10.0, 0.05))
    slab.apply_translation((0.975, 0.0, 2.3))
    others = trimesh.util.concatenate([trimesh.Trimesh(mesh.vertices, mesh.faces[far]), slab])
    shift = np.array([0.0, 0.02, -0.04])
    tube = observe_tube(
        frames, lambda f: images[f.index], RayCaster(others), P0 + shift, P1 + shift, UP
    )
    assert tube.stripe_samples >= 20
    np.testing.assert_allclose(tube.p1 - tube.p0, P1 - P0, atol=1e-9)
    np.testing.assert_allclose(tube.p0, P0, atol=0.004)


def test_an_unreadable_frame_is_neither_bright_nor_dark(photos) -> None:
    frames, images = photos
    mesh, _ = _scene()
    others = caster_without_fixture(mesh.vertices, mesh.faces, P0, P1)
    everything = observe_tube(frames, lambda f: images[f.index], others, P0, P1, UP)
    unreadable = {s.frame for s in everything.sightings if not s.bright}
    tube = observe_tube(
        frames, lambda f: None if f.index in unreadable else images[f.index], others, P0, P1, UP
    )
    assert unreadable and all(s.bright for s in tube.sightings)
    assert tube.cutoff_deg == (None, None)  # no dark view left to bound it
    np.testing.assert_allclose(tube.p0, everything.p0)


def test_a_degenerate_line_is_refused_with_a_clear_error(photos) -> None:
    frames, images = photos
    mesh, _ = _scene()
    others = caster_without_fixture(mesh.vertices, mesh.faces, P0, P1)
    with pytest.raises(ValueError, match="zero length"):
        observe_tube(frames, lambda f: images[f.index], others, P0, P0, UP)
    with pytest.raises(ValueError, match="parallel"):
        observe_tube(frames, lambda f: images[f.index], others, P0, P1, P1 - P0)
    with pytest.raises(ValueError, match="zero length"):
        trough_fixture(P0, P0, UP, (0.07, 0.07), 0.06, 0.1)


def _extent(photos, p0, p1, load=None):
    frames, images = photos
    mesh, _ = _scene()
    tube = _observe(photos, p0, p1)
    lit = [f for f in frames if f.index in {s.frame for s in tube.sightings if s.bright}]
    dh = (p1 - p0) / np.linalg.norm(p1 - p0)
    clear = caster_without_fixture(mesh.vertices, mesh.faces, p0 - dh, p1 + dh)
    load = load or (lambda f: images[f.index])
    return tube_extent(lit, load, clear, RayCaster(mesh), p0, p1, UP)


def test_the_tube_runs_as_far_as_its_stripe_in_the_photos(photos) -> None:
    # A fused scan held only the second half of the tube bright.
    half = _extent(photos, P0 + 0.5 * (P1 - P0), P1)
    assert abs(half.p0[0] - P0[0]) < 0.03 and abs(half.p1[0] - P1[0]) < 0.03
    assert half.moved_m[0] == pytest.approx(0.6, abs=0.03)
    np.testing.assert_allclose(half.p0[1:], P0[1:], atol=1e-9)  # along the axis given
    # A span that is right stays: the stripe overshoots its ends by a pixel at most,
    # and by as much at both.
    whole = _extent(photos, P0, P1)
    assert whole.moved_m == (0.0, 0.0) and whole.bright.any()
    assert abs(whole.shift_m) < 0.003
    np.testing.assert_allclose([whole.p0, whole.p1], [P0, P1], atol=0.003)
    # Photos that cannot be read say nothing: the ends stay.
    frames, images = photos
    blind = _extent(photos, P0 + 0.5 * (P1 - P0), P1, load=lambda f: None)
    assert blind.moved_m == (0.0, 0.0) and not blind.seen.any()


@pytest.mark.parametrize("offset", [-0.03, 0.045])
def test_a_span_off_along_its_axis_is_centred_on_the_stripe(photos, offset) -> None:
    # A fused scan's bright span sits on its voxel grid: the right length, centimetres
    # off along the axis. Its length is kept and its centre moves to the stripe's.
    along = np.array([offset, 0.0, 0.0])
    moved = _extent(photos, P0 + along, P1 + along)
    assert moved.moved_m == (0.0, 0.0)
    assert moved.shift_m == pytest.approx(-offset, abs=0.003)
    np.testing.assert_allclose([moved.p0, moved.p1], [P0, P1], atol=0.003)
    assert moved.summary()["centre_shift_m"] == pytest.approx(-offset, abs=0.003)
    # Further off than min_move: the end grows to the stripe (as before), no re-centring.
    far = np.array([0.12, 0.0, 0.0])
    stays = _extent(photos, P0 + far, P1 + far)
    assert stays.shift_m == 0.0


def test_the_pipeline_extends_a_tube_the_scan_held_in_part(photos, tmp_path) -> None:
    from reroom.invert.pipeline import InvertOptions, _line_open_shape

    mesh = _fused_scan(photos, tmp_path)
    # Detected on the block's underside, over its second half only, and tilted.
    p0 = P0 + 0.5 * (P1 - P0) + np.array([0.0, 0.02, -0.03])
    p1 = P1 + np.array([0.0, 0.02, -0.05])
    geometry = {"p0": p0, "p1": p1, "d_perp": UP, "radius": 0.037}
    _, info, g = _line_open_shape(
        tmp_path, mesh, "tube", geometry, LineBasis(16, 3), InvertOptions(), []
    )
    np.testing.assert_allclose(g["p0"], P0, atol=0.03)
    np.testing.assert_allclose(g["p1"], P1, atol=0.03)
    photo = info["fixture_from_photos"]
    assert photo["extent"]["ends_moved_m"][0] > 0.5 and "first_fit" in photo
