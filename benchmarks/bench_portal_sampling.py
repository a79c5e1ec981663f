"""Noise of a window portal's light sampling: uniform points on the opening vs the mixture.

Usage::

    python benchmarks/bench_portal_sampling.py [--hdri sunrise,sunset,...] [--spp 16]
        [--ref-spp 2048] [--seeds 8]

A 4 x 3 x 2.5 m box room (albedo 0.5) lit only through a 1.2 x 1 m window in its
y = 0 wall, rendered by the ``path`` integrator (depth 4) at 96 x 72 from inside. For
each bundled HDRI, the window's ``reroom_portal`` emitter is rendered with

* ``sky_sampling = 0``: next-event estimation takes uniform points on the opening only
  (reroom before session 12);
* the default share (:func:`reroom.render.emitters.default_sky_sampling`): part of the
  samples drawn from the map's brightness and followed to the opening;

and each is compared with a reference (the default, ``--ref-spp`` x 4 seeds). Printed
per HDRI: its peakedness and default share, the relative RMSE of ``--spp`` renders
(mean over ``--seeds`` seeds) for both, their ratio, the ratio of means (both are
unbiased, so it drifts only by noise) and the render time per sample. Both strategies
are tested against Mitsuba's own ``envmap`` in ``tests/test_emitters.py``.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from reroom.data import hdri_path
from reroom.render.emitters import (
    default_sky_sampling,
    load_hdri,
    register_emitters,
    sky_peakedness,
    window_portal,
)
from reroom.scan import look_at

HDRIS = ("sunrise", "sunset", "city", "forest", "night", "studio", "interior", "courtyard")


def box_room_scene(mi, hdri: np.ndarray, share: float | None, spp: int):
    """The benchmark room with its window showing ``hdri`` (see the module docstring)."""
    white = {"type": "diffuse", "reflectance": {"type": "rgb", "value": 0.5}}

    def rect(c, hu, hv, n):
        m = np.eye(4)
        m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = hu, hv, n, c
        if np.linalg.det(m[:3, :3]) < 0:
            m[:3, 0] = -np.asarray(hu)
        return {"type": "rectangle", "to_world": mi.ScalarTransform4f(m.tolist()), "bsdf": white}

    h = 2.5
    s = {
        "type": "scene",
        "integrator": {"type": "path", "max_depth": 4},
        "floor": rect([2, 1.5, 0], [2, 0, 0], [0, 1.5, 0], [0, 0, 1]),
        "ceiling": rect([2, 1.5, h], [2, 0, 0], [0, 1.5, 0], [0, 0, -1]),
        "x0": rect([0, 1.5, h / 2], [0, 1.5, 0], [0, 0, h / 2], [1, 0, 0]),
        "x1": rect([4, 1.5, h / 2], [0, 1.5, 0], [0, 0, h / 2], [-1, 0, 0]),
        "y1": rect([2, 3, h / 2], [2, 0, 0], [0, 0, h / 2], [0, -1, 0]),
        # The y = 0 wall around a window at x 1.4-2.6, z 1.0-2.0.
        "y0_left": rect([0.7, 0, h / 2], [0.7, 0, 0], [0, 0, h / 2], [0, 1, 0]),
        "y0_right": rect([3.3, 0, h / 2], [0.7, 0, 0], [0, 0, h / 2], [0, 1, 0]),
        "y0_below": rect([2, 0, 0.5], [0.6, 0, 0], [0, 0, 0.5], [0, 1, 0]),
        "y0_above": rect([2, 0, 2.25], [0.6, 0, 0], [0, 0, 0.25], [0, 1, 0]),
        "window": window_portal([2, 0, 1.5], 1.2, 1.0, [0, 1, 0], hdri),
        "sensor": {
            "type": "perspective",
            "fov": 70,
            "to_world": mi.ScalarTransform4f(look_at([2, 2.8, 1.6], [2, 0.5, 0.5]).tolist()),
            "film": {"type": "hdrfilm", "width": 96, "height": 72, "rfilter": {"type": "box"}},
            "sampler": {"type": "independent", "sample_count": spp},
        },
    }
    if share is not None:
        s["window"]["emitter"]["sky_sampling"] = float(share)
    return mi.load_dict(s)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--hdri", default=",".join(HDRIS))
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--ref-spp", type=int, default=2048)
    ap.add_argument("--seeds", type=int, default=8)
    args = ap.parse_args()
    mi = register_emitters()
    print(
        "| HDRI | peakedness | default share | RMSE uniform | RMSE mixture | ratio | "
        "mean / ref (uniform, mixture) | ns per sample (uniform, mixture) |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for name in [h.strip() for h in args.hdri.split(",") if h.strip()]:
        sky = load_hdri(hdri_path(name))
        outward = [0.0, -1.0, 0.0]
        share = default_sky_sampling(sky, outward)
        ref_scene = box_room_scene(mi, sky, None, args.ref_spp)
        ref = np.mean([np.array(mi.render(ref_scene, seed=1000 + k)) for k in range(4)], axis=0)
        row = {}
        for label, s in (("uniform", 0.0), ("mixture", None)):
            scene = box_room_scene(mi, sky, s, args.spp)
            np.array(mi.render(scene, seed=0))  # compile before timing
            errs, means = [], []
            t0 = time.perf_counter()
            for seed in range(1, args.seeds + 1):
                img = np.array(mi.render(scene, seed=seed))
                errs.append(np.linalg.norm(img - ref) / np.linalg.norm(ref))
                means.append(img.mean() / ref.mean())
            dt = (time.perf_counter() - t0) / (args.seeds * 96 * 72 * args.spp)
            row[label] = (float(np.mean(errs)), float(np.mean(means)), dt * 1e9)
        u, m = row["uniform"], row["mixture"]
        print(
            f"| {name} | {sky_peakedness(sky, outward):.1f} | {share:.2f} | {u[0]:.3f} | "
            f"{m[0]:.3f} | {u[0] / m[0]:.2f} | {u[1]:.3f}, {m[1]:.3f} | {u[2]:.0f}, {m[2]:.0f} |",
            flush=True,
        )


if __name__ == "__main__":
    main()
