"""Pick the fastest Mitsuba 3 variant that works on this machine.

Mitsuba's vectorised ``llvm_ad_rgb`` variant JIT-compiles through LLVM. Dr.Jit
loads ``libLLVM.so`` at run time; LLVM 15/16 crash on Mitsuba's kernels
("Cannot select ... fminimum") and 14 is too old, so we look for LLVM >= 17
ourselves, point ``DRJIT_LIBLLVM_PATH`` at it, and fall back to the slow
``scalar_rgb`` variant with a warning when there is none. Probing in-process
would risk a hard crash, which is why detection is by file name.

Set ``REROOM_MITSUBA_VARIANT`` to force a variant.
"""

from __future__ import annotations

import glob
import os
import re
import warnings
from dataclasses import dataclass
from functools import lru_cache
from types import ModuleType

MIN_LLVM = 17
_SEARCH_DIRS = (
    "/usr/lib/x86_64-linux-gnu",
    "/usr/lib/aarch64-linux-gnu",
    "/usr/lib",
    "/usr/local/lib",
    "/usr/lib/llvm-*/lib",
)


@dataclass(frozen=True)
class MitsubaInfo:
    """What :func:`mitsuba` chose: the variant, the LLVM library, and why."""

    variant: str
    llvm_path: str | None
    llvm_version: int | None
    mitsuba_version: str
    note: str

    @property
    def vectorized(self) -> bool:
        return not self.variant.startswith("scalar")


def find_llvm() -> tuple[str | None, int | None]:
    """Return ``(path, major_version)`` of the newest usable ``libLLVM`` (>= 17), if any."""
    env = os.environ.get("DRJIT_LIBLLVM_PATH")
    if env and os.path.isfile(env):
        m = re.search(r"LLVM[-.](\d+)", os.path.basename(env))
        return env, int(m.group(1)) if m else None
    best: tuple[str | None, int | None] = (None, None)
    for pattern in _SEARCH_DIRS:
        for d in glob.glob(pattern):
            for f in glob.glob(os.path.join(d, "libLLVM*.so*")):
                m = re.search(r"libLLVM[-.]?(\d+)", os.path.basename(f))
                if not m:
                    continue
                ver = int(m.group(1))
                if ver >= MIN_LLVM and (best[1] is None or ver > best[1]):
                    best = (f, ver)
    return best


@lru_cache(maxsize=1)
def mitsuba_info() -> MitsubaInfo:
    """Decide the variant (once per process) without importing Mitsuba's JIT yet."""
    import importlib.metadata as md

    try:
        mi_version = md.version("mitsuba")
    except md.PackageNotFoundError:
        mi_version = "not installed"
    forced = os.environ.get("REROOM_MITSUBA_VARIANT")
    path, ver = find_llvm()
    if forced:
        return MitsubaInfo(forced, path, ver, mi_version, "forced by REROOM_MITSUBA_VARIANT")
    if path is not None:
        return MitsubaInfo("llvm_ad_rgb", path, ver, mi_version, f"LLVM {ver} found")
    return MitsubaInfo(
        "scalar_rgb",
        None,
        None,
        mi_version,
        f"no libLLVM >= {MIN_LLVM} found: using the slow scalar_rgb variant "
        "(install it with `apt-get install libllvm19`, or run scripts/setup.sh as root)",
    )


@lru_cache(maxsize=1)
def mitsuba() -> ModuleType:
    """Import Mitsuba with the chosen variant set, and return the module.

    Warns once when falling back to ``scalar_rgb``.
    """
    info = mitsuba_info()
    if info.llvm_path and "DRJIT_LIBLLVM_PATH" not in os.environ:
        os.environ["DRJIT_LIBLLVM_PATH"] = info.llvm_path
    if info.variant.startswith("scalar") and not os.environ.get("REROOM_MITSUBA_VARIANT"):
        warnings.warn(info.note, RuntimeWarning, stacklevel=2)
    import mitsuba as mi

    mi.set_variant(info.variant)
    return mi
