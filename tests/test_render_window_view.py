"""A window shows the camera its photos' view while the room is lit by its light map."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh

from reroom.io.mesh import write_ply
from reroom.render.emitters import portal_emitter
from reroom.render.frames import FrameRenderer
from reroom.scan import Intrinsics, look_at


def _scene(tmp: Path, view: np.ndarray | None) -> dict:
    """A closed box room whose -Y wall has a 1.2 x 0.8 m window (a portal)."""
    box = trimesh.creation.box(extents=[4.0, 3.0, 2.5])
    box.apply_translation([0.0, 0.0, 1.25])
    box.invert()
    centre = np.array([0.0, -1.499, 1.25])
    hu, hv, n = np.array([0.6, 0.0, 0.0]), np.array([0.0, 0.0, 0.4]), np.array([0.0, 1.0, 0.0])
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = hu, hv, n, centre
    light = np.full((32, 64, 3), 4.0, np.float32)
    from reroom.render import mitsuba

    mi = mitsuba()

    return {
        "type": "scene",
        "integrator": {"type": "path", "max_depth": 6},
        "room": {
            "type": "ply",
            "filename": str(write_ply(tmp / "room.ply", box, {})),
            "face_normals": True,
            "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": 0.6}},
        },
        "window": {
            "type": "rectangle",
            "to_world": mi.ScalarTransform4f(m.tolist()),
            "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": 0.0}},
            "emitter": portal_emitter(light, opening=(centre, hu, hv, n), view=view),
        },
    }


def test_the_camera_sees_the_view_and_the_room_the_light(tmp_path: Path):
    intr = Intrinsics.from_fov(64, 48, 70.0)
    c2w = look_at(np.array([0.3, 1.2, 1.3]), np.array([0.0, -1.5, 1.2]))
    view = np.full((64, 128, 3), 4.0, np.float32)
    view[..., 0] = 9.0  # the outdoors as the photos saw it: red
    plain = FrameRenderer(_scene(tmp_path, None), intr, spp=64).render(c2w, seed=3)
    shown = FrameRenderer(_scene(tmp_path, view), intr, spp=64).render(c2w, seed=3)
    window = plain.min(axis=2) > 3.9  # pixels wholly through the window
    assert window.sum() > 50
    np.testing.assert_allclose(plain[window], 4.0, rtol=1e-4)
    np.testing.assert_allclose(
        shown[window], np.broadcast_to([9.0, 4.0, 4.0], shown[window].shape), rtol=1e-4
    )
    # The room is lit by the light map alone: the walls are the same render.
    from scipy import ndimage

    walls = ~ndimage.binary_dilation(plain.max(axis=2) > 1.0, iterations=2)
    assert walls.sum() > 500
    np.testing.assert_allclose(shown[walls], plain[walls], rtol=1e-5, atol=1e-6)
    # With the denoiser, too: the view is added back after denoising the rest.
    den = FrameRenderer(_scene(tmp_path, view), intr, spp=64, denoise=True).render(c2w, seed=3)
    np.testing.assert_allclose(
        den[window], np.broadcast_to([9.0, 4.0, 4.0], den[window].shape), rtol=1e-3
    )
