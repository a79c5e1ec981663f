"""Where in one view of an edit-fidelity run the error is: blocks, boxes and holes.

Usage::

    python benchmarks/bench_view_error.py FIDELITY_DIR EDIT VIEW [--block 20]
        [--box NAME:Y0:Y1:X0:X1 ...] [--top 10,50,100,300,1000]

``FIDELITY_DIR`` is the ``--out`` of ``benchmarks/bench_edit_fidelity.py``, whose
``pairs/EDIT_VIEW.npz`` holds the view's ours and truth in image units. Printed:

* the relative RMSE over the whole view (not noise-corrected: both renders' Monte-Carlo
  noise is in it);
* the share of the squared error held by the worst N pixels;
* the share of the squared error in each ``block x block`` pixel block (percent, the
  image's layout: row 0 at the top);
* **holes**: pixels black in ours (sum of channels under 0.05) where the truth is lit
  (over 0.5), their count and share: a surface missing from the rendered model (the
  backing shell's lost sill of session 50 showed as one);
* per ``--box`` (rows ``Y0:Y1``, columns ``X0:X1``, half-open): its share of the squared
  error and the mean of ours and of the truth per channel, with their ratio (e.g. a panel
  seen directly: how bright ours is inside it).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

DARK = 0.05
LIT = 0.5


def load_pair(run: Path, edit: str, view: str) -> tuple[np.ndarray, np.ndarray]:
    """Ours and the truth of one view, ``(H, W, 3)`` each, in image units."""
    path = run / "pairs" / f"{edit}_{view}.npz"
    if not path.is_file():
        raise SystemExit(
            f"{path}: no such file (run bench_edit_fidelity.py with --out {run} and this edit)"
        )
    with np.load(path) as z:
        return np.asarray(z["ours"], np.float64), np.asarray(z["truth"], np.float64)


def parse_box(text: str) -> tuple[str, int, int, int, int]:
    """``NAME:Y0:Y1:X0:X1`` -> its parts."""
    parts = text.split(":")
    if len(parts) != 5:
        raise argparse.ArgumentTypeError(f"{text!r}: a box is NAME:Y0:Y1:X0:X1")
    try:
        y0, y1, x0, x1 = (int(x) for x in parts[1:])
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"{text!r}: the rows and columns are integers") from exc
    return parts[0], y0, y1, x0, x1


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("run", type=Path)
    ap.add_argument("edit")
    ap.add_argument("view")
    ap.add_argument("--block", type=int, default=20)
    ap.add_argument("--box", type=parse_box, action="append", default=[])
    ap.add_argument("--top", default="10,50,100,300,1000")
    args = ap.parse_args()

    ours, truth = load_pair(args.run, args.edit, args.view)
    se = ((ours - truth) ** 2).sum(axis=-1)
    total = float(se.sum())
    if total <= 0:
        print(f"{args.edit} {args.view}: ours equals the truth")
        return
    print(f"{args.edit} {args.view}: relative RMSE {np.sqrt(total / (truth**2).sum()):.2%}")
    ranked = np.sort(se.ravel())[::-1]
    cum = np.cumsum(ranked) / total
    tops = [int(x) for x in args.top.split(",") if x.strip()]
    print("worst pixels: " + ", ".join(f"{n} hold {cum[min(n, len(cum)) - 1]:.1%}" for n in tops))
    h, w = se.shape
    b = max(1, int(args.block))
    grid = se[: h // b * b, : w // b * b].reshape(h // b, b, w // b, b).sum(axis=(1, 3))
    print(f"\nshare of the squared error per {b} x {b} block (%):")
    for row in 100.0 * grid / total:
        print(" ".join(f"{x:5.1f}" for x in row))
    holes = (ours.sum(axis=-1) < DARK) & (truth.sum(axis=-1) > LIT)
    print(
        f"\nholes (ours under {DARK} where the truth is over {LIT}): {int(holes.sum())} pixels, "
        f"{se[holes].sum() / total:.1%} of the squared error"
    )
    for name, y0, y1, x0, x1 in args.box:
        sel = np.zeros_like(se, bool)
        sel[y0:y1, x0:x1] = True
        mo, mt = ours[sel].mean(axis=0), truth[sel].mean(axis=0)
        ratio = mo / np.maximum(mt, 1e-12)
        print(
            f"box {name} [{y0}:{y1}, {x0}:{x1}]: {se[sel].sum() / total:.1%} of the squared "
            f"error; mean ours {'/'.join(f'{x:.3f}' for x in mo)}, truth "
            f"{'/'.join(f'{x:.3f}' for x in mt)}, ratio {'/'.join(f'{x:.3f}' for x in ratio)}"
        )


if __name__ == "__main__":
    main()
