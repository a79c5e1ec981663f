"""Path-traced frames and per-vertex radiance from a Mitsuba scene.

Both go through Mitsuba's ``path`` integrator, i.e. the same physically based
light transport, never through reroom's own (inverse) light model -- later
stages must not be tested on data made by their own assumptions. Used by the
synthetic generator (frames and the per-vertex truth) and by the renders and
baked lighting of edited room models.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from reroom.render import mitsuba
from reroom.render.camera import mitsuba_to_world, perspective_sensor
from reroom.scan.camera import Intrinsics

#: Path-tracing samples per view that :func:`auto_spp` spends on a denoised render.
RENDER_SAMPLES_PER_VIEW = 1_000_000


def auto_spp(
    width: int, height: int, budget: int = RENDER_SAMPLES_PER_VIEW, lo: int = 4, hi: int = 64
) -> int:
    """Samples per pixel for a denoised ``width x height`` render: about ``budget`` a view.

    The largest power of four (a perfect square: what the multi-jittered sampler takes)
    with ``width x height x spp <= budget``, within ``[lo, hi]``: 16 at 160 x 120, 4 at
    640 x 360. A render's cost is its samples; the denoiser needs fewer per pixel at a
    higher resolution, where each pixel has more neighbours on the same surface
    (measured in docs/edit.md, "Denoising").
    """
    per_pixel = budget / max(int(width) * int(height), 1)
    spp = lo
    while spp * 4 <= min(per_pixel, hi):
        spp *= 4
    return spp


class FrameRenderer:
    """Renders many frames of one scene, re-posing a single sensor between frames.

    Re-using the loaded scene lets Dr.Jit reuse its compiled kernels: after the
    first frame, each frame costs only its samples.
    """

    def __init__(
        self,
        scene_dict: dict[str, Any],
        intr: Intrinsics,
        spp: int,
        denoise: bool = False,
        aux_spp: int = 4,
        sampler: str | None = None,
    ) -> None:
        """Load ``scene_dict`` for frames of intrinsics ``intr`` at ``spp`` samples per pixel.

        ``sampler``: a Mitsuba sampler's name; default
        :func:`reroom.render.camera.default_sampler`'s for ``spp``.

        With ``denoise``, each frame is passed through OIDN
        (:func:`reroom.render.denoise.denoise`) guided by the first-hit albedo and normal
        of a cheap pass (Mitsuba's ``aov`` integrator at ``aux_spp``: camera rays only,
        ~0.1 s for 640 x 360), before the glows are composited. Emitters seen directly
        (a panel, the sky through a window) are kept out of the denoiser: a pass of the
        path tracer at depth 1 with the same samples gives exactly their part of each
        pixel, which is added back after denoising the rest. Fed to the network, their
        bright edges smear into the walls around them (a 20x brighter panel in a small
        frame: 10 % RMSE added at 64 spp). Only renders of a recovered model are
        denoised, never the synthetic truth.
        """
        from reroom.render.glow import glow_sources, split_glow

        mi = mitsuba()
        self.mi = mi
        self.intr = intr
        self.spp = spp
        d, glows = split_glow(scene_dict)
        # Glowing fittings of point and line lights (reroom.render.glow): composited
        # after the path tracer, as they are not part of the light transport.
        self.glows = glow_sources(d, glows)
        d["sensor"] = perspective_sensor(np.eye(4), intr, spp, sampler=sampler)
        self.scene = mi.load_dict(d, optimize=False)
        self.params = mi.traverse(self.scene)
        if "sensor.to_world" not in self.params:
            raise RuntimeError("this Mitsuba build does not expose sensor.to_world for updates")
        self.denoise = bool(denoise)
        self.aux_spp = int(aux_spp)
        self._aux = self._direct = None
        # Windows that show the camera the photos' view (reroom_portal's ``view``): the
        # emitters seen directly are rendered again with it switched on, and the
        # difference is the camera's view through the window, exactly (same samples).
        self._views = [k for k in self.params.keys() if k.endswith(".use_view")]
        if self.denoise or self._views:
            from reroom.render.denoise import AUX_AOVS

            # A separate pass on the same loaded scene: wrapping the path tracer in the
            # aov integrator instead doubles its cost (measured, 640 x 360, 4 spp).
            self._aux = mi.load_dict({"type": "aov", "aovs": AUX_AOVS})
            self._direct = mi.load_dict({"type": "path", "max_depth": 1})

    def _seen(self, seed: int, use_view: bool) -> np.ndarray:
        """The emitters seen directly (a depth-1 path trace, ``spp`` samples, ``seed``),
        the windows showing their view (``use_view``) or their lighting map."""
        mi = self.mi
        for k in self._views:
            self.params[k] = 1.0 if use_view else 0.0
        if self._views:
            self.params.update()
        seen = mi.render(self.scene, integrator=self._direct, spp=self.spp, seed=seed)
        seen = np.nan_to_num(np.asarray(seen, dtype=np.float32)[..., :3])
        if use_view and self._views:
            for k in self._views:
                self.params[k] = 0.0
            self.params.update()
        return seen

    def render(self, c2w: np.ndarray, seed: int) -> np.ndarray:
        """Linear RGB radiance ``(H, W, 3)`` float32 for camera pose ``c2w`` (OpenGL axes)."""
        mi = self.mi
        self.params["sensor.to_world"] = mitsuba_to_world(c2w)
        self.params.update()
        img = np.asarray(mi.render(self.scene, spp=self.spp, seed=seed), dtype=np.float32)[..., :3]
        if self.denoise:
            from reroom.render.denoise import denoise

            aux = np.asarray(
                mi.render(self.scene, integrator=self._aux, spp=self.aux_spp, seed=seed),
                dtype=np.float32,
            )
            # Same seed and spp: the same camera samples, so this is exactly the part of
            # each pixel that is emission seen directly (edge pixels included).
            seen = self._seen(seed, False)
            shown = self._seen(seed, True) if self._views else seen
            img = denoise(np.maximum(img - seen, 0.0), aux[..., -6:-3], aux[..., -3:]) + shown
        elif self._views:
            img = img - self._seen(seed, False) + self._seen(seed, True)
        if self.glows:
            from reroom.render.glow import glow_layer

            glow, cover = glow_layer(self.scene, self.glows, c2w, self.intr)
            img = (img * (1.0 - cover[..., None]) + glow).astype(np.float32)
        return img


def _warn_off_surface(
    mi, scene: Any, points: np.ndarray, normals: np.ndarray, offset: float, jitter: float
) -> None:
    """Warn when probe points have no surface within ``offset`` behind them: each probe
    ray stops at ``2 offset`` (its first hit must be the point itself), so such a point
    reads as 0 radiance, silently (warned when at least 1 % of them do). Four rays a point, shifted ``jitter`` sideways as the
    samples are (a ray aimed exactly at a mesh vertex can slip between its triangles)."""
    from reroom.rays.sampling import orthonormal_basis

    if len(points) == 0:
        return
    t1, t2 = orthonormal_basis(normals)
    hit = np.zeros(len(points), dtype=bool)
    for side in (t1, -t1, t2, -t2):
        o = (points + offset * normals + jitter * side).astype(np.float32)
        d = (-normals).astype(np.float32)
        ray = mi.Ray3f(mi.Point3f(*o.T), mi.Vector3f(*d.T))
        ray.maxt = 2.0 * offset
        hit |= np.asarray(scene.ray_test(ray), dtype=bool).reshape(-1)[: len(points)]
    # A few misses are mesh corners (a diagonal normal aimed at the corner itself); many
    # are points given off their surface.
    if (~hit).sum() >= max(1.0, 0.01 * len(points)):
        import warnings

        miss = np.flatnonzero(~hit)
        warnings.warn(
            f"probe_radiance: {len(miss)} of {len(points)} points have no surface within "
            f"{offset:g} m behind them along their normal (first: point {int(miss[0])} at "
            f"{np.round(points[miss[0]], 4).tolist()}); they read as 0 radiance. Give points "
            "on the surface.",
            stacklevel=3,
        )


def probe_radiance(
    scene: Any,
    points: np.ndarray,
    normals: np.ndarray,
    spp: int,
    seed: int = 0,
    offset: float = 0.004,
    jitter: float = 0.001,
    batch_rays: int = 2_000_000,
    progress: Callable[[int, int], None] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Outgoing radiance of surface points toward their normals, by path tracing.

    For each point a ray starts ``offset`` metres out along the normal and
    looks back at the point, so the integrator returns the radiance leaving
    the surface toward the normal direction (emission included). For diffuse
    surfaces that is *the* radiance; for glossy ones it is the radiance seen
    head-on.

    Each sample's ray is shifted sideways by a random offset within ``jitter``
    metres: a ray aimed exactly at a mesh vertex runs along the edges of the
    triangles around it, and Mitsuba's (non-watertight) intersection test can
    let it slip through, which would read as zero radiance.

    Returns ``(mean, stderr)``, each ``(N, 3)``: the Monte-Carlo estimate and
    its standard error (from the per-sample variance). Points must lie on a surface:
    one with none within ``offset`` behind it reads 0, and a warning names the first
    when at least 1 % of the points do.
    """
    mi = mitsuba()
    import drjit as dr

    from reroom.rays.sampling import orthonormal_basis

    points = np.asarray(points, np.float64)
    normals = np.asarray(normals, np.float64)
    normals = normals / np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-12)
    n = len(points)
    _warn_off_surface(mi, scene, points, normals, offset, jitter)
    rng = np.random.default_rng(seed)
    integrator = scene.integrator()
    total = np.zeros((n, 3))
    total_sq = np.zeros((n, 3))
    per_batch = max(1, batch_rays // max(spp, 1))
    done = 0
    for start in range(0, n, per_batch):
        stop = min(n, start + per_batch)
        m = stop - start
        nrm = normals[start:stop]
        t1, t2 = orthonormal_basis(nrm)
        o = points[start:stop] + offset * nrm
        o_rep = np.repeat(o, spp, axis=0)
        r = jitter * np.sqrt(rng.random(m * spp))
        phi = 2 * np.pi * rng.random(m * spp)
        o_rep += (r * np.cos(phi))[:, None] * np.repeat(t1, spp, 0)
        o_rep += (r * np.sin(phi))[:, None] * np.repeat(t2, spp, 0)
        o_rep = o_rep.astype(np.float32)
        d_rep = np.repeat(-nrm, spp, axis=0).astype(np.float32)
        sampler = mi.load_dict({"type": "independent"})
        sampler.seed(seed * 7919 + start, m * spp)
        ray = mi.Ray3f(mi.Point3f(*o_rep.T), mi.Vector3f(*d_rep.T))
        ray.maxt = 2.0 * offset
        # maxt bounds only the first segment: the first hit must be the point itself.
        spec, _, _ = integrator.sample(scene, sampler, ray)
        vals = np.asarray(spec, dtype=np.float64)
        vals = vals.T if vals.shape[0] == 3 and vals.ndim == 2 else vals
        vals = vals.reshape(m, spp, 3)
        total[start:stop] = vals.sum(1)
        total_sq[start:stop] = (vals**2).sum(1)
        dr.flush_malloc_cache()
        done += m
        if progress is not None:
            progress(done, n)
    mean = total / spp
    var = np.maximum(total_sq / spp - mean**2, 0.0)
    return mean, np.sqrt(var / max(spp - 1, 1))
