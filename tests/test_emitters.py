"""Python Mitsuba emitters: goniometric point light and window portal.

Checks against closed forms (a point light over a diffuse floor), against
Mitsuba's built-in ``point`` and ``envmap`` emitters, and between the path
tracer and the light tracer (which exercises ``sample_ray``).
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest

from reroom.render.mitsuba_env import mitsuba_info

pytestmark = pytest.mark.skipif(
    not mitsuba_info().vectorized,
    reason="Python emitters need a JIT (llvm/cuda) Mitsuba variant",
)

IES_DIR = Path("/work/shared/data/ies")
HDRI_DIR = Path("/work/shared/data/hdri")


@pytest.fixture(scope="module")
def mi():
    from reroom.render.emitters import register_emitters

    return register_emitters()


def _shared(path: Path) -> Path:
    if not path.is_file():
        pytest.skip(f"shared data file {path} is not available")
    return path


def _matrix(mi, m: np.ndarray):
    return mi.ScalarTransform4f(np.asarray(m, dtype=np.float64).tolist())


def _camera(mi, origin, target, w: int, h: int, spp: int, fov: float = 70.0) -> dict:
    return {
        "type": "perspective",
        "fov": fov,
        "to_world": mi.ScalarTransform4f().look_at(origin=origin, target=target, up=[0, 0, 1]),
        "film": {"type": "hdrfilm", "width": w, "height": h, "rfilter": {"type": "box"}},
        "sampler": {"type": "independent", "sample_count": spp},
    }


def _floor(mi, albedo: float, half: float = 20.0) -> dict:
    return {
        "type": "rectangle",
        "to_world": mi.ScalarTransform4f().scale([half, half, 1.0]),
        "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": albedo}},
    }


# ---------------------------------------------------------------------- goniometric light
ALBEDO = 0.6
LIGHT_POS = np.array([0.3, -0.2, 2.0])


def _asa_setup(mi):
    from reroom.io.ies import read_ies
    from reroom.render.emitters import goniometric_light, luminaire_frame

    prof = read_ies(_shared(IES_DIR / "ASA_15M_R2.ies"))
    # phi = 0 along world +Y; the nadir still points down.
    frame = luminaire_frame(nadir=(0, 0, -1), azimuth0=(0, 1, 0))
    light = goniometric_light(prof, LIGHT_POS, frame=frame, scale=1e-3)
    return prof, frame, light


def _analytic_floor_radiance(prof, frame, pts: np.ndarray, scale: float = 1e-3) -> np.ndarray:
    """L = albedo / pi * I(theta) cos(theta_s) / r^2 on the z = 0 floor."""
    d = pts - LIGHT_POS
    r = np.linalg.norm(d, axis=-1)
    dw = d / r[..., None]
    intensity = prof.intensity_dir(dw @ frame) * scale  # world -> luminaire: frame^T d
    return ALBEDO / np.pi * intensity * np.maximum(-dw[..., 2], 0) / r**2


def test_goniometric_nee_matches_closed_form(mi) -> None:
    """NEE of a delta light is exact: path-traced radiance equals the closed form."""
    prof, frame, light = _asa_setup(mi)
    scene = mi.load_dict(
        {
            "type": "scene",
            "integrator": {"type": "path", "max_depth": 2},
            "floor": _floor(mi, ALBEDO),
            "light": light,
        }
    )
    rng = np.random.default_rng(0)
    n = 4000
    pts = np.c_[rng.uniform(-6, 6, (n, 2)), np.zeros(n)]
    origin = (pts + [0, 0, 5.0]).T.astype(np.float32)
    down = np.tile([[0.0], [0.0], [-1.0]], (1, n)).astype(np.float32)
    ray = mi.Ray3f(mi.Point3f(origin), mi.Vector3f(down))
    sampler = mi.load_dict({"type": "independent"})
    sampler.seed(0, n)
    radiance, valid, _ = scene.integrator().sample(scene, sampler, ray)
    got = np.array(radiance)[0]
    want = _analytic_floor_radiance(prof, frame, pts)
    assert np.all(np.array(valid))
    lit = want > 0.02 * want.max()
    assert lit.sum() > 1000
    rel = np.abs(got[lit] - want[lit]) / want[lit]
    assert rel.max() < 1e-3, rel.max()
    assert got.sum() == pytest.approx(want.sum(), rel=1e-4)
    # The asymmetric beam really is oriented: swapping the azimuth frame changes the result.
    other = _analytic_floor_radiance(prof, np.eye(3), pts)
    assert np.abs(other - want).max() > 0.1 * want.max()


def test_goniometric_render_matches_closed_form(mi) -> None:
    """A rendered image (camera, pixel filter, spp) of the lit floor matches the closed form."""
    prof, frame, light = _asa_setup(mi)
    w, h, spp = 48, 36, 64
    cam = _camera(mi, [0.0, -6.0, 5.0], [0.0, 1.0, 0.0], w, h, spp)
    scene = mi.load_dict(
        {
            "type": "scene",
            "integrator": {"type": "path", "max_depth": 2},
            "sensor": cam,
            "floor": _floor(mi, ALBEDO),
            "light": light,
        }
    )
    image = np.array(mi.render(scene, seed=0))[..., 0]
    assert image.max() > 0  # a silently broken emitter renders zeros

    # Closed form averaged over each pixel, with rays from the same sensor model.
    k = 8
    sub = (np.arange(k) + 0.5) / k
    yy, xx = np.meshgrid(
        (np.arange(h)[:, None] + sub).ravel(), (np.arange(w)[:, None] + sub).ravel(), indexing="ij"
    )
    pos = np.stack([xx.ravel() / w, yy.ravel() / h]).astype(np.float32)
    sensor = scene.sensors()[0]
    rays, _ = sensor.sample_ray(0.0, 0.5, mi.Point2f(pos), mi.Point2f(0.5, 0.5))
    o, d = np.array(rays.o).T, np.array(rays.d).T
    t = -o[:, 2] / d[:, 2]
    want = _analytic_floor_radiance(prof, frame, o + t[:, None] * d)
    want = want.reshape(h, k, w, k).mean(axis=(1, 3))
    lit = want > 0.05 * want.max()
    err = np.abs(image - want)[lit].sum() / want[lit].sum()
    assert err < 0.01, err
    assert image.sum() == pytest.approx(want.sum(), rel=5e-3)


def test_isotropic_table_matches_builtin_point(mi) -> None:
    from reroom.render.emitters import goniometric_light

    def render(light: dict) -> np.ndarray:
        scene = mi.load_dict(
            {
                "type": "scene",
                "integrator": {"type": "path", "max_depth": 3},
                "sensor": _camera(mi, [0, -3, 3], [0, 0, 0.5], 32, 24, 8),
                "floor": _floor(mi, 0.5, half=3.0),
                "wall": {
                    "type": "rectangle",
                    "to_world": mi.ScalarTransform4f().translate([0, 2, 1]).rotate([1, 0, 0], 90),
                    "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": 0.7}},
                },
                "light": light,
            }
        )
        return np.array(mi.render(scene, seed=5))

    intensity = 3.7
    ours = render(goniometric_light(intensity, [0.2, 0.1, 1.2]))
    ref = render(
        {
            "type": "point",
            "position": [0.2, 0.1, 1.2],
            "intensity": {"type": "rgb", "value": intensity},
        }
    )
    assert ref.max() > 0
    np.testing.assert_allclose(ours, ref, rtol=1e-4, atol=1e-6 * ref.max())
    # A colour and scale multiply the table.
    tinted = render(
        goniometric_light(1.0, [0.2, 0.1, 1.2], color=(1.0, 0.5, 0.25), scale=intensity)
    )
    np.testing.assert_allclose(tinted, ref * [1.0, 0.5, 0.25], rtol=1e-4, atol=1e-6 * ref.max())


def test_goniometric_light_tracing_and_parameters(mi) -> None:
    """``sample_ray`` (used by the light tracer) agrees with NEE; ``scale`` is a live parameter."""
    from reroom.io.ies import read_ies
    from reroom.render.emitters import goniometric_light

    prof = read_ies(_shared(IES_DIR / "ies_light_2.ies"))
    light = goniometric_light(prof, [0, 0, 1.5], flux=50.0)
    grid_flux = prof.to_tabulated(181, 2).total_flux()
    assert light["scale"] == pytest.approx(50.0 / grid_flux)

    def scene(integrator: str):
        return mi.load_dict(
            {
                "type": "scene",
                "integrator": {"type": integrator, "max_depth": 2},
                "sensor": _camera(mi, [0, -3, 3], [0, 0, 0], 32, 24, 256),
                "floor": _floor(mi, 0.5, half=4.0),
                "light": light,
            }
        )

    path_scene = scene("path")
    a = np.array(mi.render(path_scene, seed=1))
    b = np.array(mi.render(scene("ptracer"), seed=2))
    assert a.mean() > 0
    assert b.mean() == pytest.approx(a.mean(), rel=0.01)

    params = mi.traverse(path_scene)
    params["light.scale"] = 2.0 * light["scale"]
    params.update()
    c = np.array(mi.render(path_scene, seed=1))
    np.testing.assert_allclose(c, 2.0 * a, rtol=1e-5, atol=1e-7)


# ---------------------------------------------------------------------- window portal
ROOM = dict(x=2.0, y=1.5, z=2.5, wy0=-0.6, wy1=0.6, wz0=0.8, wz1=1.8)


def _rect(mi, center, ex, ey, albedo: float = 0.7) -> dict:
    ex, ey = np.asarray(ex, float), np.asarray(ey, float)
    n = np.cross(ex, ey)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = ex, ey, n / np.linalg.norm(n), center
    diffuse = {"type": "diffuse", "reflectance": {"type": "rgb", "value": albedo}}
    return {
        "type": "rectangle",
        "to_world": _matrix(mi, m),
        "bsdf": {"type": "twosided", "bsdf": diffuse},
    }


def _room(mi) -> dict:
    """A 4 x 3 x 2.5 m box room with a 1.2 x 1 m hole in the x = +2 wall."""
    X, Y, Z = ROOM["x"], ROOM["y"], ROOM["z"]
    y0, y1, z0, z1 = ROOM["wy0"], ROOM["wy1"], ROOM["wz0"], ROOM["wz1"]
    return {
        "floor": _rect(mi, [0, 0, 0], [X, 0, 0], [0, Y, 0]),
        "ceiling": _rect(mi, [0, 0, Z], [X, 0, 0], [0, -Y, 0]),
        "back": _rect(mi, [-X, 0, Z / 2], [0, Y, 0], [0, 0, Z / 2]),
        "left": _rect(mi, [0, Y, Z / 2], [X, 0, 0], [0, 0, Z / 2]),
        "right": _rect(mi, [0, -Y, Z / 2], [X, 0, 0], [0, 0, Z / 2]),
        "below_window": _rect(mi, [X, 0, z0 / 2], [0, Y, 0], [0, 0, z0 / 2]),
        "above_window": _rect(mi, [X, 0, (z1 + Z) / 2], [0, Y, 0], [0, 0, (Z - z1) / 2]),
        "left_of_window": _rect(
            mi, [X, (y1 + Y) / 2, (z0 + z1) / 2], [0, (Y - y1) / 2, 0], [0, 0, (z1 - z0) / 2]
        ),
        "right_of_window": _rect(
            mi, [X, (y0 - Y) / 2, (z0 + z1) / 2], [0, (Y + y0) / 2, 0], [0, 0, (z1 - z0) / 2]
        ),
    }


def _room_scene(
    mi,
    kind: str,
    hdri: np.ndarray,
    spp: int,
    w: int = 32,
    h: int = 24,
    max_depth: int = 4,
    rotation: float = 0.0,
    scale: float = 1.0,
):
    from reroom.render.emitters import envmap_emitter, window_portal

    d = {
        "type": "scene",
        "integrator": {"type": "path", "max_depth": max_depth},
        "sensor": _camera(mi, [-1.8, -1.2, 1.6], [1.5, 0.5, 0.8], w, h, spp, fov=75),
    }
    d.update(_room(mi))
    if kind == "portal":
        center = [ROOM["x"], (ROOM["wy0"] + ROOM["wy1"]) / 2, (ROOM["wz0"] + ROOM["wz1"]) / 2]
        size = (ROOM["wy1"] - ROOM["wy0"], ROOM["wz1"] - ROOM["wz0"])
        d["window"] = window_portal(
            center, *size, inward_normal=[-1, 0, 0], hdri=hdri, scale=scale, rotation_deg=rotation
        )
    else:
        d["sky"] = envmap_emitter(hdri, scale=scale, rotation_deg=rotation)
    # optimize=False: Mitsuba 3.9.1 merges meshes that share a BSDF and the merged
    # mesh has an invalid bounding box, which shrinks the envmap's bounding sphere
    # so that its shadow rays stop short of the walls (light leaks into the room).
    return mi.load_dict(d, optimize=False)


def _smooth_latlong(h: int = 32, w: int = 64) -> np.ndarray:
    """A smooth analytic sky (brighter upwards and towards +X) sampled at pixel centres."""
    theta = (np.arange(h) + 0.5) / h * np.pi
    az = (0.5 - (np.arange(w) + 0.5) / w) * 2 * np.pi
    t, a = np.meshgrid(theta, az, indexing="ij")
    x, y, z = np.sin(t) * np.cos(a), np.sin(t) * np.sin(a), np.cos(t)
    r = 1.0 + 2.0 * np.maximum(z, 0) + 1.5 * np.exp(3 * (x - 1)) + 0.5 * y
    return np.stack([r, 0.8 * r + 0.3 * x, 0.6 * r + 0.4 * z + 0.5], -1).clip(0).astype(np.float32)


def test_portal_lookup_convention_matches_envmap(mi) -> None:
    """The portal's lat-long lookup, the numpy reference and the built-in envmap agree."""
    import drjit as dr

    from reroom.render.emitters import envmap_emitter, latlong_direction_to_uv, latlong_lookup

    h, w = 16, 32
    rows = np.repeat(np.arange(h, dtype=np.float32)[:, None], w, 1)
    cols = np.repeat(np.arange(w, dtype=np.float32)[None, :], h, 0)
    image = np.stack([rows, cols, rows * cols / 10.0], -1)
    rng = np.random.default_rng(2)
    q = rng.normal(size=(3000, 3))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    rotation = 40.0
    # Convention: v = theta / pi with pixel centres at (r + 0.5) / H; u at (c + 0.5) / W.
    uv = latlong_direction_to_uv(q, rotation)
    ref = latlong_lookup(image, q, rotation)
    np.testing.assert_allclose(ref[:, 0], np.clip(uv[:, 1] * h - 0.5, 0, h - 1), atol=1e-9)
    inner = (uv[:, 0] * w > 1) & (uv[:, 0] * w < w - 1)
    np.testing.assert_allclose(ref[inner, 1], uv[inner, 0] * w - 0.5, atol=1e-9)
    # +X is the image centre, +Y a quarter from the left, the zenith the top row.
    np.testing.assert_allclose(
        latlong_direction_to_uv(np.eye(3)), [[0.5, 0.5], [0.25, 0.5], [0.5, 0.0]], atol=1e-12
    )
    np.testing.assert_allclose(
        latlong_direction_to_uv([[0.0, 1.0, 0.0]], 90.0), [[0.5, 0.5]], atol=1e-12
    )

    env = mi.load_dict(envmap_emitter(image, scale=2.0, rotation_deg=rotation))
    si = dr.zeros(mi.SurfaceInteraction3f, len(q))
    si.wi = mi.Vector3f(-q.T.astype(np.float32))
    env_val = np.array(env.eval(si)).T
    np.testing.assert_allclose(env_val, 2.0 * ref, atol=2e-3 * np.abs(ref).max())

    scene = _room_scene(mi, "portal", image, 1, scale=2.0, rotation=rotation)
    portal = [e for e in scene.emitters() if "Portal" in str(e)][0]
    got = np.array(portal._radiance(mi.Vector3f(q.T.astype(np.float32)))).T
    np.testing.assert_allclose(got, 2.0 * ref, atol=1e-5 * np.abs(ref).max())


def test_portal_is_one_sided_and_shows_the_sky(mi) -> None:
    """Looking out through the window shows the HDRI; the outside of the portal is dark."""
    from reroom.render.emitters import latlong_lookup, window_portal

    sky = _smooth_latlong()

    def view(origin, target) -> np.ndarray:
        scene = mi.load_dict(
            {
                "type": "scene",
                "integrator": {"type": "path", "max_depth": 1},
                "sensor": _camera(mi, origin, target, 8, 8, 4, fov=10),
                "window": window_portal([0, 0, 1.3], 1.0, 1.0, [-1, 0, 0], sky, scale=0.5),
            }
        )
        return np.array(mi.render(scene, seed=0))

    inside = view([-3.0, 0.0, 1.3], [0.0, 0.0, 1.3])
    want = 0.5 * latlong_lookup(sky, np.array([[1.0, 0.0, 0.0]]))[0]
    np.testing.assert_allclose(inside.mean(axis=(0, 1)), want, rtol=0.02)
    outside = view([3.0, 0.0, 1.3], [0.0, 0.0, 1.3])
    assert outside.max() == 0.0


def test_portal_matches_envmap_with_lower_variance(mi) -> None:
    """Same room lit through the hole by an envmap or by the portal: same image, less noise."""
    sky = _smooth_latlong()
    w, h = 32, 24
    ref = np.array(mi.render(_room_scene(mi, "portal", sky, 1024, w, h), seed=100))

    # Envmap at high spp in independent batches, to estimate its standard error per block.
    env_scene = _room_scene(mi, "env", sky, 512, w, h)
    batches = np.stack([np.array(mi.render(env_scene, seed=200 + i)) for i in range(4)])
    assert batches.mean() == pytest.approx(ref.mean(), rel=0.01)

    def blocks(img: np.ndarray) -> np.ndarray:
        return img.reshape(*img.shape[:-3], 4, h // 4, 4, w // 4, 3).mean(axis=(-4, -2))

    env_blocks = blocks(batches)
    env_mean = env_blocks.mean(axis=0)
    env_se = env_blocks.std(axis=0, ddof=1) / 2.0
    z = (env_mean - blocks(ref)) / (env_se + 1e-3 * blocks(ref).mean())
    assert np.abs(z).max() < 5.0, np.abs(z).max()

    # Equal spp: the portal's error against the reference is much smaller on the room's
    # surfaces. Pixels that see the bright window (and its edge) are left out: there
    # the error is dominated by sub-pixel sampling of the window outline, which is the
    # same for both emitters.
    from scipy.ndimage import binary_dilation

    surfaces = ~binary_dilation(ref.sum(-1) > 1.0, iterations=1)
    assert surfaces.mean() > 0.8
    spp = 16
    rmse, rmse_all, rate = {}, {}, {}
    for kind in ("portal", "env"):
        scene = _room_scene(mi, kind, sky, spp, w, h)
        np.array(mi.render(scene, seed=1))  # compile the kernels before timing
        t0 = time.perf_counter()
        img = np.array(mi.render(scene, seed=7))
        rate[kind] = w * h * spp / (time.perf_counter() - t0)
        rmse[kind] = float(np.sqrt(np.mean((img - ref)[surfaces] ** 2)))
        rmse_all[kind] = float(np.sqrt(np.mean((img - ref) ** 2)))
    print(
        f"\nRMSE at {spp} spp on room surfaces: portal {rmse['portal']:.4g}, "
        f"envmap {rmse['env']:.4g}; all pixels: portal {rmse_all['portal']:.4g}, "
        f"envmap {rmse_all['env']:.4g}; samples/s: portal {rate['portal']:.3g}, "
        f"envmap {rate['env']:.3g}"
    )
    assert rmse["portal"] < rmse["env"] / 3.0
    assert rmse_all["portal"] < rmse_all["env"]


def test_portal_with_real_hdri_agrees_with_envmap(mi) -> None:
    """The same check on a real (downsized) HDRI, including its non-smooth horizon."""
    from reroom.render.emitters import load_hdri

    sky = load_hdri(_shared(HDRI_DIR / "courtyard.exr"), max_width=64)
    assert sky.shape == (32, 64, 3) and sky.min() >= 0
    w, h = 32, 24
    portal = np.array(mi.render(_room_scene(mi, "portal", sky, 512, w, h, rotation=120.0), seed=3))
    env = np.array(mi.render(_room_scene(mi, "env", sky, 2048, w, h, rotation=120.0), seed=4))
    assert portal.mean() > 0
    assert env.mean() == pytest.approx(portal.mean(), rel=0.02)
    # Pixels that see the sky directly through the window agree closely.
    window = portal.sum(-1) > 4 * np.median(portal.sum(-1))
    assert window.sum() >= 4
    np.testing.assert_allclose(env[window].mean(0), portal[window].mean(0), rtol=0.02)


def test_sky_peakedness_and_default_share() -> None:
    """An even sky is sampled on the opening alone; a map with a small sun is not."""
    from reroom.render.emitters import (
        SKY_PEAKEDNESS_THRESHOLD,
        _pixel_directions,
        default_sky_sampling,
        latlong_direction_to_uv,
        sky_peakedness,
    )

    even = np.ones((16, 32, 3), np.float32)
    assert sky_peakedness(even) == pytest.approx(1.0)
    assert sky_peakedness(even, [1.0, 0.0, 0.0]) == pytest.approx(1.0)
    assert default_sky_sampling(even, [1.0, 0.0, 0.0]) == 0.0
    sun = even.copy()
    sun[6, 8] = 5000.0  # one pixel holds most of the light
    v = sky_peakedness(sun)
    assert v > 10 * SKY_PEAKEDNESS_THRESHOLD
    assert 0.45 < default_sky_sampling(sun) < 0.5
    # A sun behind the opening does not count.
    d = _pixel_directions(16, 32)[6, 8]
    assert sky_peakedness(sun, -d) == pytest.approx(1.0, abs=1e-6)
    # The pixel directions follow the module's lat-long convention, rotation included.
    for rot in (0.0, 75.0):
        dirs = _pixel_directions(16, 32, rot).reshape(-1, 3)
        uv = latlong_direction_to_uv(dirs, rot)
        rows, cols = np.meshgrid(np.arange(16), np.arange(32), indexing="ij")
        np.testing.assert_allclose(uv[:, 0] * 32 - 0.5, cols.ravel(), atol=1e-6)
        np.testing.assert_allclose(uv[:, 1] * 16 - 0.5, rows.ravel(), atol=1e-6)


def test_portal_sky_pdf_integrates_to_one(mi) -> None:
    """The sky strategy's solid-angle pdf is a density over the sphere."""
    from reroom.data import hdri_path
    from reroom.render.emitters import load_hdri

    sky = load_hdri(hdri_path("sunrise"), max_width=128)
    scene = _room_scene(mi, "portal", sky, 1, rotation=30.0)
    portal = [e for e in scene.emitters() if "Portal" in str(e)][0]
    assert portal.sky_share > 0.4
    n = 400_000
    k = np.arange(n) + 0.5
    z = 1.0 - 2.0 * k / n
    phi = np.pi * (1.0 + 5.0**0.5) * k
    r = np.sqrt(1.0 - z * z)
    d = np.stack([r * np.cos(phi), r * np.sin(phi), z]).astype(np.float32)
    pdf = np.array(portal._sky_pdf(mi.Vector3f(d)))
    assert pdf.mean() * 4.0 * np.pi == pytest.approx(1.0, rel=0.02)
    # Nothing behind the opening (outward is +x here).
    assert pdf[d[0] < -0.05].max() == 0.0


def test_portal_sky_sampling_finds_a_low_sun_without_bias(mi) -> None:
    """A low sun through the window: same image as Mitsuba's envmap, far less noise."""
    from reroom.data import hdri_path
    from reroom.render.emitters import load_hdri

    sky = load_hdri(hdri_path("sunrise"))  # its sun holds ~60 % of the light
    w, h = 32, 24
    env = np.array(mi.render(_room_scene(mi, "env", sky, 2048, w, h), seed=4))
    sky_scene = _room_scene(mi, "portal", sky, 512, w, h)
    portal = [e for e in sky_scene.emitters() if "Portal" in str(e)][0]
    assert portal.sky_share > 0.4
    img = np.array(mi.render(sky_scene, seed=3))
    assert img.mean() == pytest.approx(env.mean(), rel=0.03)

    def rmse(share: float | None, spp: int, seed: int) -> float:
        from reroom.render.emitters import window_portal

        scene = _room_scene(mi, "portal", sky, spp, w, h)
        if share is not None:
            # Rebuild with the share forced (0: uniform points on the opening alone).
            d = {"type": "scene", "integrator": {"type": "path", "max_depth": 4}}
            d["sensor"] = _camera(mi, [-1.8, -1.2, 1.6], [1.5, 0.5, 0.8], w, h, spp, fov=75)
            d.update(_room(mi))
            centre = [ROOM["x"], 0.0, (ROOM["wz0"] + ROOM["wz1"]) / 2]
            d["window"] = window_portal(centre, 1.2, 1.0, [-1, 0, 0], sky)
            d["window"]["emitter"]["sky_sampling"] = share
            scene = mi.load_dict(d, optimize=False)
        errs = [np.array(mi.render(scene, seed=seed + i)) - img for i in range(4)]
        return float(np.sqrt(np.mean(np.square(errs)[:, surfaces])))

    # Pixels that see the sky through the window are the same for both strategies.
    from scipy.ndimage import binary_dilation

    surfaces = ~binary_dilation(img.sum(-1) > 4 * np.median(img.sum(-1)), iterations=1)
    assert surfaces.mean() > 0.8

    uniform, mixed = rmse(0.0, 16, 10), rmse(None, 16, 10)
    print(
        f"\nRMSE at 16 spp: uniform points {uniform:.4g}, mixture {mixed:.4g}; mean / envmap {img.mean() / env.mean():.4f}"
    )
    assert mixed < uniform / 2.0


def test_portal_opening_and_share_are_checked(mi) -> None:
    from reroom.render.emitters import portal_emitter

    sky = np.ones((8, 16, 3), np.float32)
    with pytest.raises(ValueError, match="inward_normal must be a nonzero 3-vector"):
        portal_emitter(sky, opening=([0, 0, 1], [1, 0, 0], [0, 0, 1], [0, 0, 0]))
    with pytest.raises(ValueError, match="opening half_u must be a finite 3-vector"):
        portal_emitter(sky, opening=([0, 0, 1], [np.nan, 0, 0], [0, 0, 1], [0, 1, 0]))
    with pytest.raises(ValueError, match="span no area"):
        portal_emitter(sky, opening=([0, 0, 1], [1, 0, 0], [2, 0, 0], [0, 1, 0]))
    shape = {"type": "rectangle", "emitter": portal_emitter(sky, sky_sampling=0.3)}
    with pytest.raises(Exception, match="sky_sampling needs 'outward'"):
        mi.load_dict({"type": "scene", "window": shape})
    opening = ([0, 0, 1], [1, 0, 0], [0, 0, 1], [0, 1, 0])
    shape = {"type": "rectangle", "emitter": portal_emitter(sky, opening=opening, sky_sampling=1.0)}
    with pytest.raises(Exception, match=r"sky_sampling must be in \[0, 1\)"):
        mi.load_dict({"type": "scene", "window": shape})
