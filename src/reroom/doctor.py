"""``reroom doctor``: what reroom will use on this machine."""

from __future__ import annotations

import importlib.metadata as md
import os
import platform


def environment_report() -> dict[str, str]:
    """Versions, the Mitsuba variant, the LLVM library, the ray engine and thread counts."""
    from reroom import __version__
    from reroom.render.mitsuba_env import mitsuba_info

    info = mitsuba_info()
    report = {
        "reroom": __version__,
        "python": platform.python_version(),
        "platform": f"{platform.system()} {platform.machine()}",
        "cpu cores": str(os.cpu_count()),
        "mitsuba": info.mitsuba_version,
        "mitsuba variant": info.variant + ("" if info.vectorized else "  (slow fallback)"),
        "llvm": f"{info.llvm_path} (LLVM {info.llvm_version})" if info.llvm_path else "not found",
        "variant note": info.note,
    }
    try:
        import embreex  # noqa: F401

        report["ray engine"] = (
            f"Embree via embreex {md.version('embreex')}, {os.cpu_count()} threads"
        )
    except ImportError:
        report["ray engine"] = "embreex missing: falling back to Mitsuba ray queries"
    for pkg in (
        "numpy",
        "scipy",
        "trimesh",
        "open3d-cpu",
        "numba",
        "scikit-image",
        "openexr",
        "typer",
        "rich",
    ):
        try:
            report[pkg] = md.version(pkg)
        except md.PackageNotFoundError:
            report[pkg] = "missing"
    try:
        import numba

        report["numba threads"] = str(numba.config.NUMBA_NUM_THREADS)
    except ImportError:
        pass
    return report


def check_mitsuba_works() -> tuple[bool, str]:
    """Render a tiny scene to prove the chosen variant runs; return (ok, message)."""
    import time

    try:
        from reroom.render import mitsuba

        mi = mitsuba()
        t = time.perf_counter()
        scene = mi.load_dict(mi.cornell_box())
        img = mi.render(scene, spp=4)
        mean = float(__import__("numpy").asarray(img).mean())
        return (
            mean > 0,
            f"rendered a Cornell box in {time.perf_counter() - t:.2f} s (mean {mean:.3f})",
        )
    except Exception as exc:  # report, don't crash: this is a diagnostic
        return False, f"rendering failed: {exc}"
