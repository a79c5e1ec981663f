"""A light's colour from the unsaturated edge of its clipped image (``reroom.invert.emitter_color``).

The photos are rendered here by ray casting a tube and a panel under a ceiling: a pixel is the mean
of 4 x 4 sub-pixel rays, blurred by a Gaussian lens spread (sigma 0.7 pixel), exposed
per channel (a white balance), clipped at the white level, gamma-encoded and quantised
to 8 bits. The tube is 30 times the white level in a bluish white, the panel 15 times
in a warm white, the ceiling and fixture around them warmer, so a colour read from the
clipped blobs or from the background would be wrong.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import trimesh
from scipy.ndimage import gaussian_filter

from reroom.invert.emitter_color import emitter_color, rectangle_points, segment_points
from reroom.invert.line_photos import caster_without_fixture
from reroom.rays import RayCaster
from reroom.scan.camera import Frame, Intrinsics, look_at

AXIS_Z, RADIUS, CEILING = 2.6, 0.016, 2.7
P0, P1, UP = np.array([0.0, 0.0, AXIS_Z]), np.array([1.2, 0.0, AXIS_Z]), np.array([0, 0, 1.0])
TUBE = 30.0 * np.array([0.9, 1.0, 1.15])
PANEL = 15.0 * np.array([1.1, 1.0, 0.85])
PANEL_CENTRE, PANEL_HALF = np.array([0.6, 1.2, CEILING - 0.01]), 0.3
BACKGROUND = 0.12 * np.array([1.2, 1.0, 0.7])
LUT = np.linspace(0.0, 1.0, 256) ** 2.2  # the inverse of the gamma 2.2 encoding


def _scene() -> tuple[trimesh.Trimesh, int, int]:
    """Tube, panel, housing and ceiling; the tube's and the panel's face counts."""
    tube = trimesh.creation.cylinder(radius=RADIUS, segment=(P0, P1), sections=32)
    c, a = PANEL_CENTRE, PANEL_HALF
    panel = trimesh.Trimesh(
        [c + [-a, -a, 0], c + [a, -a, 0], c + [a, a, 0], c + [-a, a, 0]], [[0, 1, 2], [0, 2, 3]]
    )
    housing = trimesh.creation.box(extents=(1.3, 0.16, 0.05))
    housing.apply_translation((0.6, 0.0, 2.675))
    ceiling = trimesh.Trimesh(
        [[-6, -6, CEILING], [6, -6, CEILING], [6, 6, CEILING], [-6, 6, CEILING]],
        [[0, 2, 1], [0, 3, 2]],
    )
    mesh = trimesh.util.concatenate([tube, panel, housing, ceiling])
    return mesh, len(tube.faces), len(panel.faces)


def _photos(tube: np.ndarray = TUBE, width: int = 320, height: int = 240):
    """Frames below the lights, their 8-bit photos and per-channel exposures."""
    mesh, n_tube, n_panel = _scene()
    caster = RayCaster(mesh)
    intr = Intrinsics.from_fov(width, height, 60.0)
    rng = np.random.default_rng(7)
    sub = (np.arange(4) + 0.5) / 4
    ox, oy = np.meshgrid(sub, sub)
    frames, images, scales = [], {}, {}
    eyes = [(x, y, 1.4) for y in (-1.5, -0.6, 0.4) for x in (-0.2, 0.6, 1.4)]
    for i, eye in enumerate(eyes):
        target = np.array([0.6 + rng.uniform(-0.3, 0.3), rng.uniform(0.0, 1.0), AXIS_Z])
        frame = Frame(i, Path(f"frame_{i:03d}.png"), look_at(np.array(eye), target), intr)
        jj, ii = np.meshgrid(np.arange(width), np.arange(height))
        uv = np.stack(
            [(jj[..., None] + ox.ravel()).ravel(), (ii[..., None] + oy.ravel()).ravel()], axis=1
        )
        o, d = frame.pixel_rays(uv)
        hits = caster.intersect(o, d)
        face = np.where(hits.hit, hits.face, -1)[:, None]
        radiance = np.where(face < n_tube, tube[None, :], PANEL[None, :])
        radiance = np.where((face < 0) | (face >= n_tube + n_panel), BACKGROUND, radiance)
        pixel = radiance.reshape(height, width, 16, 3).mean(axis=2)
        pixel = gaussian_filter(pixel, sigma=(0.7, 0.7, 0))
        scale = rng.uniform(1.0, 2.0) * np.array([1.1, 1.0, 0.8])  # exposure x white balance
        sensor = np.clip(pixel * scale, 0.0, 1.0)
        images[i] = (sensor ** (1 / 2.2) * 255 + 0.5).astype(np.uint8)
        scales[i] = scale
        frames.append(frame)
    return frames, images, scales, mesh


@pytest.fixture(scope="module")
def photos():
    return _photos()


def _colour(photos, light: str = "tube", **kw):
    frames, images, scales, mesh = photos
    if light == "tube":
        caster = caster_without_fixture(mesh.vertices, mesh.faces, P0, P1)
        points = segment_points(P0, P1)
    else:
        caster = RayCaster(mesh)
        points = rectangle_points(PANEL_CENTRE, [1, 0, 0], [0, 1, 0], [0.6, 0.6])
    kw.setdefault("facing", lambda c: c[2] < AXIS_Z)
    return emitter_color(
        frames, lambda f: images[f.index], lambda i: scales[i], LUT, caster, points,
        **kw,
    )  # fmt: skip


@pytest.mark.parametrize("light, truth", [("tube", TUBE), ("panel", PANEL)])
def test_the_colour_comes_from_the_clipped_images_edge(photos, light, truth) -> None:
    found = _colour(photos, light)
    assert found is not None
    assert found.frames >= 4 and found.pixels >= 60
    np.testing.assert_allclose(found.color, truth / truth.mean(), rtol=0.015)
    assert np.all(found.spread < 0.015)
    # the blobs clip white and their background is warm: neither holds the light's colour
    frames, images, scales, _ = photos
    assert max(int(((img >= 250).all(axis=2)).sum()) for img in images.values()) > 100


def test_a_light_below_saturation_or_unreadable_gives_no_colour() -> None:
    # exposed below the white level in some channel: no blob clipped in all three
    dim = _photos(tube=0.8 * TUBE / TUBE.max(), width=160, height=120)
    assert _colour(dim) is None
    # frames that cannot be read or have no exposure are skipped, not guessed
    frames, images, scales, mesh = _photos(width=160, height=120)
    others = caster_without_fixture(mesh.vertices, mesh.faces, P0, P1)
    pts = segment_points(P0, P1)
    assert emitter_color(frames, lambda f: None, lambda i: scales[i], LUT, others, pts) is None
    assert (
        emitter_color(frames, lambda f: images[f.index], lambda i: None, LUT, others, pts) is None
    )
    # a facing test that no camera passes: nothing seen
    assert _colour((frames, images, scales, mesh), facing=lambda c: False) is None


def test_a_frame_whose_edge_disagrees_is_dropped(photos) -> None:
    # Two frames read with a tinted exposure (their background is then not what lies
    # behind their edge, as a wrong one is): without the vote their colour would pull
    # the sum's red up and its blue down.
    frames, images, scales, mesh = photos
    tint = {0: np.array([0.75, 1.0, 1.3]), 4: np.array([0.75, 1.0, 1.3])}
    caster = caster_without_fixture(mesh.vertices, mesh.faces, P0, P1)
    found = emitter_color(
        frames, lambda f: images[f.index], lambda i: scales[i] * tint.get(i, 1.0), LUT, caster,
        segment_points(P0, P1), facing=lambda c: c[2] < AXIS_Z,
    )  # fmt: skip
    assert found is not None and found.dropped == 2
    np.testing.assert_allclose(found.color, TUBE / TUBE.mean(), rtol=0.015)
    assert found.summary()["frames_dropped"] == 2


def test_consistent_frames_votes_by_pixels() -> None:
    from reroom.invert.emitter_color import consistent_frames

    good = np.array([[1.0, 1.0, 1.0], [2.0, 2.02, 1.98], [0.5, 0.5, 0.51]])
    bad = np.array([[0.8, 1.0, 1.2], [1.0, 1.0, 0.0]])  # off colour; a channel at 0
    keep = consistent_frames(np.vstack([good, bad]), np.array([10, 10, 10, 10, 10]))
    assert keep.tolist() == [True, True, True, False, False]
    # the median is by pixels: one big off-colour frame outvotes two small ones
    keep = consistent_frames(np.array([[1.0, 1.0, 1.0], [0.8, 1.0, 1.2]]), np.array([1, 50]))
    assert keep.tolist() == [False, True]
    assert consistent_frames(np.zeros((2, 3)), np.array([3, 3])).tolist() == [False, False]


def test_no_frame_is_dropped_without_a_majority(photos) -> None:
    # Half the frames tinted one way: no colour most frames agree on, so none is dropped
    # and the spread over them all shows the disagreement.
    frames, images, scales, mesh = photos
    tinted = {f.index for f in frames[::2]}
    caster = caster_without_fixture(mesh.vertices, mesh.faces, P0, P1)
    found = emitter_color(
        frames, lambda f: images[f.index],
        lambda i: scales[i] * (np.array([0.75, 1.0, 1.3]) if i in tinted else 1.0), LUT,
        caster, segment_points(P0, P1), facing=lambda c: c[2] < AXIS_Z,
    )  # fmt: skip
    assert found is not None and found.dropped == 0
    assert found.spread.max() > 0.02
