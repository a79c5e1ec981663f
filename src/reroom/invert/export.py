"""Outputs of ``reroom invert``: ``scene.json``, ``albedo.ply``, IES, EXR, pictures, report.

Every file is written atomically; ``scene.json`` is written last, so a folder with a
``scene.json`` is complete. Units are those of the HDR mesh (its radiance is relative:
the HDR stage fixes the scale by one reference frame), so light intensities and powers
share that unknown global factor while albedos do not.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import trimesh

from reroom.invert.basis import CubemapBasis, LineBasis
from reroom.invert.fine_profiles import apply_shares, coarsen
from reroom.invert.sun import add_sun_to_map, sun_power
from reroom.io.atomic import atomic_path, atomic_write_json
from reroom.io.ies import IESProfile, write_ies
from reroom.io.images import write_exr
from reroom.io.mesh import write_ply
from reroom.layout.meshops import harmonic_fill

__all__ = [
    "area_light_power",
    "inclination_power",
    "latlong_from_cubemap",
    "line_light_power",
    "line_profile_grid",
    "window_photo_maps",
    "window_power",
    "write_outputs",
]

FORMAT = "reroom-invert"
VERSION = 1


def inclination_power(profile: np.ndarray) -> np.ndarray:
    """Radiant flux of a point light with a piecewise constant profile in ``theta``.

    Parameters
    ----------
    profile : ndarray, shape (bins,) or (bins, 3)
        Intensity (per steradian) of each equal bin of ``theta in [0, pi]``.

    Returns
    -------
    ndarray
        ``sum_i I_i * 2 pi (cos theta_i - cos theta_{i+1})``.
    """
    bins = len(profile)
    edges = np.linspace(0.0, np.pi, bins + 1)
    solid = 2 * np.pi * (np.cos(edges[:-1]) - np.cos(edges[1:]))
    return np.tensordot(solid, np.asarray(profile, float), axes=(0, 0))


def line_light_power(
    profile: np.ndarray, length: float, phi_bins: int = 1, fold: bool = True
) -> np.ndarray:
    """Radiant flux of a line light ``i(theta, phi) cos(phi)`` per metre (eq. 5.11 generalised).

    A piece ``dx`` sends ``i(theta, phi) cos(phi) dx`` per steradian toward a direction at
    angle ``phi`` from the plane perpendicular to the line, so the flux is ``length *
    integral i cos(phi) d omega`` with ``d omega = cos(phi) dphi dtheta`` and ``theta``
    over ``[0, pi]`` on both sides of the line
    (:meth:`reroom.invert.basis.LineBasis.power_weights`). With ``phi_bins = 1``
    (separable) integrating ``cos^2 phi`` gives ``pi / 2`` and the flux is ``length * pi *
    dtheta * sum_k i_k``.

    Parameters
    ----------
    profile : ndarray, shape (size,) or (size, 3)
        Per-bin intensity per metre in :class:`~reroom.invert.basis.LineBasis` order
        (``theta_bin * phi_bins + phi_bin``; a ``(theta_bins, phi_bins)`` grid flattened).
    length : float
        Metres.
    phi_bins, fold : int, bool
        The basis's ``phi`` bins.
    """
    prof = np.asarray(profile, float)
    if phi_bins < 1 or prof.shape[0] % phi_bins:
        raise ValueError(f"profile of {prof.shape[0]} bins is no multiple of {phi_bins} phi bins")
    if phi_bins == 1:
        bins = len(prof)
        dtheta = np.pi / bins
        return length * np.pi * dtheta * np.sum(prof, axis=0)
    weights = LineBasis(prof.shape[0] // phi_bins, phi_bins, fold).power_weights()
    return length * np.tensordot(weights, prof, axes=(0, 0))


def line_profile_grid(distribution: dict[str, Any]) -> tuple[np.ndarray, bool]:
    """A line light's ``(theta_bins, phi_bins)`` profile grid and ``phi`` fold from ``scene.json``.

    Reads both layouts of ``distribution``: ``basis: "line"`` with ``profile`` a
    ``(bins, phi_bins)`` nested list, ``phi_bins`` and ``phi_fold``; and the separable
    ``basis: "inclination"`` with a 1D ``profile`` of files written before the ``phi``
    bins (read as ``phi_bins = 1``).
    """
    prof = np.asarray(distribution["profile"], float)
    phi_bins = int(distribution.get("phi_bins", 1))
    fold = bool(distribution.get("phi_fold", True))
    if prof.ndim == 1:
        if phi_bins != 1 and prof.size % phi_bins == 0:
            return prof.reshape(-1, phi_bins), fold
        return prof[:, None], fold
    if prof.ndim != 2 or prof.shape[1] != phi_bins:
        raise ValueError(
            f"line profile has shape {prof.shape}, expected (bins, {phi_bins}) for phi_bins"
        )
    return prof, fold


def area_light_power(radiance: np.ndarray, area: float) -> np.ndarray:
    """Flux of a one-sided Lambertian emitter: ``pi * L * A``."""
    return np.pi * np.asarray(radiance, float) * area


def _sphere_directions(n: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    d = rng.standard_normal((n, 3))
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def window_power(
    cells: np.ndarray,
    basis: CubemapBasis,
    normal: np.ndarray,
    area: float,
    samples: int = 200000,
    direction_weight=None,
) -> np.ndarray:
    """Flux entering through a window whose distant light is ``cells``.

    ``cells[j]`` is the radiance arriving from outside along the directions of cell ``j``
    (a ray from the room leaving in direction ``d`` sees ``cells[cell_of(d)]``), times
    ``direction_weight(d)`` when the cells are spread by a pattern (a captured view,
    :class:`reroom.invert.window_env.WindowView`); the flux is ``A * integral L(d)
    max(0, -d . n_in) dw``, by ``samples`` seeded directions.
    """
    d = _sphere_directions(samples)
    cos = np.maximum(-(d @ np.asarray(normal, float)), 0.0)
    if direction_weight is not None:
        out = cos > 0
        cos[out] = cos[out] * np.asarray(direction_weight(d[out]), np.float64)
    j = basis.cell_of(d)
    return area * 4 * np.pi / samples * np.tensordot(cos, np.asarray(cells)[j], axes=(0, 0))


def latlong_from_cubemap(cells: np.ndarray, basis: CubemapBasis, height: int = 64) -> np.ndarray:
    """An equirectangular ``(height, 2 height, 3)`` image of a cube-map basis light.

    Zenith at the top row, the image centre looking along +X, ``u = 0.5 - atan2(y, x) /
    2 pi`` (the convention of the ground truth's HDRIs).
    """
    h, w = height, 2 * height
    v = (np.arange(h) + 0.5) / h
    u = (np.arange(w) + 0.5) / w
    theta = v * np.pi
    phi = (0.5 - u) * 2 * np.pi
    st, ct = np.sin(theta)[:, None], np.cos(theta)[:, None]
    d = np.stack(
        np.broadcast_arrays(st * np.cos(phi)[None, :], st * np.sin(phi)[None, :], ct), axis=-1
    )
    return np.asarray(cells)[basis.cell_of(d.reshape(-1, 3))].reshape(h, w, 3)


def _ies_profile(profile: np.ndarray, name: str, kind: str) -> IESProfile:
    """Axially symmetric LM-63 table; vertical angle 0 is the nadir (-axis)."""
    bins = len(profile)
    centres = (np.arange(bins) + 0.5) / bins * 180.0  # theta from the light's axis
    nadir = 180.0 - centres[::-1]
    values = np.asarray(profile, float)[::-1]
    vertical = np.concatenate([[0.0], nadir, [180.0]])
    table = np.concatenate([[values[0]], values, [values[-1]]])
    return IESProfile(
        vertical_angles=vertical,
        horizontal_angles=np.array([0.0, 360.0]),
        candela=np.stack([table, table]),
        keywords={
            "TEST": "reroom invert",
            "MANUFAC": "reroom",
            "LUMINAIRE": f"{kind} light {name} (relative radiometric units, not candela)",
        },
        symmetry="axial",
    )


def _goniometric_plot(
    path: Path,
    profile: np.ndarray,
    color: np.ndarray,
    title: str,
    phi_edges: np.ndarray | None = None,
) -> None:
    """Polar diagram of a profile against ``theta`` (thesis Fig. 5.4/5.6).

    ``profile`` is ``(bins,)``, or ``(bins, phi_bins)`` for a line light with ``phi``
    bins: one curve per ``phi`` bin (``phi_edges`` in radians label them), darker
    towards the line's axis.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    prof = np.asarray(profile, float)
    grid = prof[:, None] if prof.ndim == 1 else prof
    bins = len(grid)
    theta = (np.arange(bins) + 0.5) / bins * np.pi
    fig = plt.figure(figsize=(4, 4))
    ax = fig.add_subplot(projection="polar")
    ax.set_theta_zero_location("N")
    c = np.clip(color / max(color.max(), 1e-12), 0, 1)
    n_phi = grid.shape[1]
    for j in range(n_phi):
        shade = 0.8 * (1.0 - 0.6 * j / max(n_phi - 1, 1))
        label = None
        if n_phi > 1 and phi_edges is not None:
            lo, hi = np.degrees(phi_edges[j]), np.degrees(phi_edges[j + 1])
            label = f"phi {lo:.0f}-{hi:.0f} deg"
        col = grid[:, j]
        for sign in (1, -1):
            ax.plot(
                sign * np.r_[theta, theta[-1]],
                np.r_[col, col[-1]],
                color=c * shade,
                label=label if sign == 1 else None,
            )
    if n_phi > 1 and phi_edges is not None:
        ax.legend(fontsize=6, loc="lower left", bbox_to_anchor=(-0.15, -0.15))
    ax.set_title(title, fontsize=9)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=100, bbox_inches="tight", format="png")
    plt.close(fig)


def _cubemap_plot(path: Path, latlong: np.ndarray, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    img = latlong / max(float(np.percentile(latlong, 99)), 1e-12)
    img = np.clip(img, 0, 1) ** (1 / 2.2)
    fig, ax = plt.subplots(figsize=(6, 3.3))
    ax.imshow(img, extent=(180, -180, 180, 0), aspect="auto")  # zenith on top
    ax.set_xlabel("azimuth (deg, +X at 0)")
    ax.set_ylabel("angle from zenith (deg)")
    ax.set_title(title, fontsize=9)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=100, bbox_inches="tight", format="png")
    plt.close(fig)


def _length(g: dict) -> float:
    return float(np.linalg.norm(np.asarray(g["p1"], float) - np.asarray(g["p0"], float)))


def _window_area(g: dict) -> float:
    return float(4 * np.linalg.norm(np.asarray(g["half_u"], float)) * np.linalg.norm(g["half_v"]))


def fill_poorly_seen(
    profile: np.ndarray,
    support: np.ndarray,
    min_fraction: float,
    adjacency: np.ndarray | None = None,
    unseen: str = "zero",
) -> np.ndarray:
    """A profile whose poorly seen bins are interpolated from the well-seen ones.

    Parameters
    ----------
    profile:
        ``(B,)`` solved values per bin.
    support:
        ``(B,)`` summed transfer of each bin over the receivers (how much data it had).
    min_fraction:
        Bins with ``0 < support < min_fraction * max(support)`` are poorly seen: they
        get the linear interpolation (in bin index) of the nearest well-seen bins on
        either side, or the nearest one's value beyond the last well-seen bin. Bins no
        receiver sees at all (support 0: hidden by the light's own fitting, such as a
        shade's sides or above a recessed downlight) are 0 -- what the room receives
        from those directions, which is what the distribution describes.
    adjacency:
        ``(M, 2)`` neighbouring bins of a basis that is not a 1D chain (a line light's
        ``(theta, phi)`` bins, :meth:`reroom.invert.basis.LineBasis.adjacency`): the
        poorly seen bins then get the harmonic interpolation of the well-seen ones over
        that graph (each the mean of its neighbours), which on a chain is the linear
        interpolation above. None: the bins are a chain in index order.
    unseen:
        ``"zero"``: bins no receiver sees are 0 (a light's own fitting hides them);
        ``"fill"``: they are interpolated as the poorly seen ones (a window's cells:
        sky that no wall, floor or ceiling receiver happens to face is still sky).

    Returns
    -------
    ``(B,)`` profile; ``profile`` itself (a copy) when no bin is well seen.
    """
    if unseen not in ("zero", "fill"):
        raise ValueError(f"unseen must be 'zero' or 'fill', got {unseen!r}")
    profile = np.asarray(profile, np.float64)
    support = np.asarray(support, np.float64)
    if support.shape != profile.shape:
        raise ValueError(f"support {support.shape} and profile {profile.shape} differ")
    top = float(support.max()) if support.size else 0.0
    well = support >= min_fraction * top
    if top <= 0 or not well.any():
        return profile.copy()
    if adjacency is None:
        idx = np.arange(len(profile))
        filled = np.where(well, profile, np.interp(idx, idx[well], profile[well]))
    else:
        filled = harmonic_fill(profile, well, adjacency)
    if unseen == "fill":
        return filled
    return np.where(support > 1e-12 * top, filled, 0.0)


def _photo_shaped(profile: np.ndarray, fitted: np.ndarray, groups: np.ndarray) -> np.ndarray:
    """``profile`` with each group marked in ``groups`` shaped as ``fitted`` there, its flux
    (solid-angle weighted over the group's bins) kept."""
    from reroom.invert.basis import InclinationBasis
    from reroom.invert.fine_profiles import bin_solid_angles

    out = np.asarray(profile, np.float64).copy()
    omega = bin_solid_angles(InclinationBasis(len(out)))
    g = len(out) // len(groups)
    for i in np.flatnonzero(groups):
        s = slice(i * g, (i + 1) * g)
        got = float(omega[s] @ fitted[s])
        if got > 0:
            out[s] = fitted[s] * (float(omega[s] @ out[s]) / got)
    return out


def _line_basis_of(info: dict[str, Any], size: int) -> LineBasis:
    b = info.get("basis") or {}
    phi_bins = int(b.get("phi_bins", 1))
    return LineBasis(int(b.get("theta_bins", size // phi_bins)), phi_bins, b.get("phi_fold", True))


def _line_entry(
    block, info: dict[str, Any], result, out: Path | None, min_bin_support: float
) -> dict[str, Any]:
    """``color``, ``distribution``, ``power`` (and ``ies``) of a line light's entry."""
    g = info["geometry"]
    solved = np.asarray(result.solve.profiles[block.name], np.float64)
    basis = _line_basis_of(info, len(solved))
    support = info.get("support")
    pairs = None if basis.phi_bins == 1 else basis.adjacency()[0]
    profile = (
        solved
        if support is None
        else fill_poorly_seen(solved, np.asarray(support), min_bin_support, pairs)
    )
    color = result.solve.colors[block.name]
    shape = (basis.theta_bins, basis.phi_bins)
    dist: dict[str, Any] = {
        "basis": "line",
        "bins": basis.theta_bins,
        "phi_bins": basis.phi_bins,
        "phi_fold": basis.fold,
        "phi_edges_deg": np.degrees(basis.phi_edges()).tolist(),
        "profile": profile.reshape(shape).tolist(),
        "profile_solved": solved.reshape(shape).tolist(),
        "theta": "around the line from d_perp",
        "phi": "out of the plane perpendicular to the line, + towards p1"
        + (" (|phi|: both signs share a bin)" if basis.fold else ""),
    }
    if "shadow_clearance" in info:
        dist["shadow_clearance"] = float(info["shadow_clearance"])
    if "open_fraction" in info:
        # The shape prior: the fraction of the tube the fixture leaves open.
        dist["open_fraction"] = np.asarray(info["open_fraction"], float).reshape(shape).tolist()
        dist["tube_radius"] = float(info["tube_radius"])
    if "fixture_inside_fraction" in info:
        # The scan does not resolve the fixture around the tube: the prior was dropped,
        # or its fixture (and the tube's axis) came from the photos.
        dist["fixture_inside_fraction"] = float(info["fixture_inside_fraction"])
    if "fixture_from_photos" in info:
        dist["fixture_from_photos"] = info["fixture_from_photos"]
    if support is not None:
        sup = np.asarray(support, float)
        dist["support"] = sup.reshape(shape).tolist()
        dist["well_seen"] = (sup >= min_bin_support * sup.max()).reshape(shape).tolist()
    e: dict[str, Any] = {"color": color.tolist(), "distribution": dist}
    e["power"] = (
        line_light_power(profile, _length(g), basis.phi_bins, basis.fold) * color
    ).tolist()
    if out is not None:
        write_ies(out / f"{block.name}.ies", _line_ies(profile, basis, g, block.name))
        e["ies"] = f"{block.name}.ies"
    return e


def _line_ies(profile: np.ndarray, basis: LineBasis, g: dict[str, Any], name: str) -> IESProfile:
    """LM-63 table of a line light's intensity per metre of line.

    Separable profiles (``phi_bins = 1``): the axially symmetric table of ``i(theta)`` in
    the plane perpendicular to the line, vertical angle 0 the nadir (``-d_perp``), as
    before the ``phi`` bins. Otherwise the full type C table of ``i(theta, phi)
    cos(phi)`` per metre: vertical angle from the nadir ``-d_perp``, horizontal angle 0
    along the line (``p0 -> p1``), 90 towards ``d_perp x tangent``; 2.5 x 5 degree nodes,
    constant per bin.
    """
    if basis.phi_bins == 1:
        return _ies_profile(profile, name, "line")
    tangent = np.asarray(g["p1"], float) - np.asarray(g["p0"], float)
    tangent /= np.linalg.norm(tangent)
    up = np.asarray(g.get("d_perp", [0.0, 0.0, 1.0]), float)
    up = up - (up @ tangent) * tangent
    up /= np.linalg.norm(up)
    y = np.cross(up, tangent)
    v = np.linspace(0.0, 180.0, 73)
    hz = np.linspace(0.0, 360.0, 73)
    vv, hh = np.meshgrid(np.radians(v), np.radians(hz), indexing="xy")  # (H, V)
    d = (
        (np.sin(vv) * np.cos(hh))[..., None] * tangent
        + (np.sin(vv) * np.sin(hh))[..., None] * y
        - np.cos(vv)[..., None] * up
    ).reshape(-1, 3)
    along = np.clip(d @ tangent, -1.0, 1.0)
    perp = d - along[:, None] * tangent
    cos_phi = np.linalg.norm(perp, axis=1)
    cos_t = np.divide(perp @ up, cos_phi, out=np.ones_like(cos_phi), where=cos_phi > 1e-12)
    k = basis.bin_of(cos_t, np.arcsin(along))
    table = (np.asarray(profile, float)[k] * cos_phi).reshape(hh.shape)
    return IESProfile(
        vertical_angles=v,
        horizontal_angles=hz,
        candela=table,
        keywords={
            "TEST": "reroom invert",
            "MANUFAC": "reroom",
            "LUMINAIRE": f"line light {name} (relative radiometric units per metre of line, "
            "not candela; horizontal angle 0 along the line p0 -> p1)",
        },
        symmetry="full",
    )


def window_cells(result, name: str, support, min_bin_support: float) -> np.ndarray:
    """A window's ``(6 n^2, 3)`` cells for power, pictures and rendering.

    As a point light's bins: cells whose summed transfer over the clustered receivers
    (``support``) is below ``min_bin_support`` of the best-seen cell's rest on a few
    grazing receivers (on a 24-frame `tworooms` scan such a cell came out 600 x the
    scan's radiance and made the window's power +155 %); they, and the cells no receiver
    sees, get the harmonic interpolation of the well-seen cells over the cube map's
    adjacency. ``support`` None: the solved cells.
    """
    return filled_cells(result.solve.intensities[name], result.cubemap_n, support, min_bin_support)


def filled_cells(solved, n: int, support, min_bin_support: float) -> np.ndarray:
    """:func:`window_cells` for any ``(6 n^2, 3)`` solved cells (e.g. a render window's,
    :mod:`reroom.invert.render_window`)."""
    solved = np.asarray(solved, np.float64)
    if support is None:
        return solved.copy()
    pairs = CubemapBasis(n).adjacency()
    sup = np.asarray(support, np.float64)
    return np.stack(
        [fill_poorly_seen(solved[:, c], sup, min_bin_support, pairs, "fill") for c in range(3)],
        axis=1,
    )


def light_entries(
    result,
    out: Path | None,
    min_bin_support: float = 0.01,
    window_maps: dict[str, tuple[np.ndarray, dict[str, Any]]] | None = None,
) -> list[dict[str, Any]]:
    """The ``lights`` list of ``scene.json`` (and the files it references, if ``out``).

    ``window_maps`` gives, by window name, the rendering map built from the photos
    (:mod:`reroom.invert.window_env`) and its figures: it is written as
    ``window_<name>.exr`` (what the renderer shows) and the plain cube-map picture of the
    cells as ``window_<name>_cells.exr``. Windows without one get the cube-map picture as
    ``window_<name>.exr`` (and the same as ``_cells``).
    """
    entries = []
    basis = CubemapBasis(result.cubemap_n)
    window_maps = window_maps or {}
    # A window's sun (reroom.invert.sun) is solved as a light of its own but stored in its
    # window's entry, and drawn into its rendering map: edits of the window take it along.
    suns = {
        info["window"]: (block, info)
        for block, info in zip(result.lights, result.light_info, strict=True)
        if block.kind == "sun"
    }
    for block, info in zip(result.lights, result.light_info, strict=True):
        if block.kind == "sun":
            continue
        g = info["geometry"]
        values = result.solve.intensities[block.name]
        share = result.solve.light_share.get(block.name, 0.0)
        e: dict[str, Any] = {"name": block.name, "type": block.kind, "geometry": g}
        if "color_from_photos" in info:  # the colour prior (reroom.invert.emitter_color)
            e["color_from_photos"] = info["color_from_photos"]
        if "refinement" in info:  # point lights: reroom.invert.refine_points
            e["position_refinement"] = {
                **info["refinement"],
                "refined_from": info.get("refined_from"),
                "kept": "refined_from" in info,
            }
        if block.kind == "area":
            e["radiance"] = values[0].tolist()
            e["power"] = area_light_power(values[0], float(g.get("area", 0.0))).tolist()
        elif block.kind == "window":
            n_in = np.asarray(g["normal"], float)
            support = info.get("support")
            cells = window_cells(result, block.name, support, min_bin_support)
            e["distribution"] = {
                "basis": "cubemap",
                "n": result.cubemap_n,
                "cells": cells.tolist(),
                "cells_solved": np.asarray(values).tolist(),
                "direction_convention": "cell of the direction a ray from the room leaves in",
            }
            if support is not None:
                top = max(support) if len(support) else 0.0
                e["distribution"]["support"] = [float(x) for x in support]
                e["distribution"]["well_seen"] = [
                    bool(top > 0 and x >= min_bin_support * top) for x in support
                ]
            if "photo_prior" in info:  # InvertOptions.window_photo_prior
                e["distribution"]["photo_prior"] = info["photo_prior"]
            if "photo_bounds" in info:  # InvertOptions.window_photo_bounds
                e["distribution"]["photo_bounds"] = info["photo_bounds"]
            if "photo_shapes" in info:  # InvertOptions.window_photo_shapes
                e["distribution"]["photo_shapes"] = info["photo_shapes"]
            if "view" in info:  # InvertOptions.window_view_hdri
                e["distribution"]["view"] = info["view"]
            weight = _view_weight(info, basis, n_in)
            power = window_power(cells, basis, n_in, _window_area(g), direction_weight=weight)
            sun = suns.get(block.name)
            if sun is not None:
                sun_dir = np.asarray(sun[1]["geometry"]["direction"], float)
                sun_irr = np.asarray(result.solve.intensities[sun[0].name], float)[0]
                sun_flux = sun_power(sun_irr, sun_dir, n_in, _window_area(g))
                e["sun"] = {
                    "name": sun[0].name,
                    "direction": sun_dir.tolist(),
                    "direction_convention": "a ray from the room leaving towards the sun",
                    "irradiance": sun_irr.tolist(),
                    "power": sun_flux.tolist(),
                    "share_of_irradiance": result.solve.light_share.get(sun[0].name, 0.0),
                    "detection": sun[1].get("detection", {}),
                }
                power = power + sun_flux
            e["power"] = power.tolist()
            fine = getattr(result, "render_windows", {}).get(block.name)
            render_cells, render_basis = cells, basis
            if fine is not None:  # InvertOptions.render_window_cells
                render_basis = CubemapBasis(fine.n)
                render_cells = filled_cells(fine.cells, fine.n, fine.support, min_bin_support)
                e["render_distribution"] = {
                    "basis": "cubemap",
                    "n": fine.n,
                    "cells": render_cells.tolist(),
                    "cells_solved": np.asarray(fine.cells).tolist(),
                    "support": [float(x) for x in fine.support],
                    "direction_convention": e["distribution"]["direction_convention"],
                    "refit": "alone, every other light held at its solved intensities",
                    "objective_at_solved_cells": fine.objective_coarse,
                    "objective": fine.objective_fine,
                    "cluster_albedo_of_refit": np.nan_to_num(fine.albedo, nan=-1.0).tolist(),
                    "power": window_power(
                        render_cells,
                        render_basis,
                        n_in,
                        _window_area(g),
                        direction_weight=_view_weight(info, render_basis, n_in),
                    ).tolist(),
                    "used_by": "environment_exr, the textures and the per-vertex albedos",
                    "photo_bounds": {"cells": fine.bounded_cells},
                }
            if out is not None:
                ll = latlong_from_cubemap(cells, basis)
                write_exr(out / f"window_{block.name}_cells.exr", ll)
                photo = window_maps.get(block.name)
                env = (
                    latlong_from_cubemap(render_cells, render_basis) if photo is None else photo[0]
                )
                if sun is not None:
                    env = add_sun_to_map(env, sun_dir, sun_irr)
                write_exr(out / f"window_{block.name}.exr", env)
                e["environment_exr"] = f"window_{block.name}.exr"
                e["environment_cells_exr"] = f"window_{block.name}_cells.exr"
                source = "cells"
                if photo is not None:
                    source = "view+cells" if "view_hdri" in photo[1] else "photos+cells"
                e["environment_source"] = source
                if photo is not None:
                    figures = dict(photo[1])
                    seen_view = figures.pop("view_map", None)
                    if seen_view is not None:
                        write_exr(out / f"window_{block.name}_view.exr", seen_view)
                        e["view_exr"] = f"window_{block.name}_view.exr"
                    e["environment_photos"] = figures
        elif block.kind == "point":
            solved = np.asarray(result.solve.profiles[block.name], np.float64)
            support = info.get("support")
            if support is not None and "split_shares" in info:
                # Filled at the bins it was solved at (a bin's support is the sum of its
                # halves'), then split as fitted: the power stays the solve's.
                coarse, sup = solved, np.asarray(support, float)
                for _ in info["split_shares"]:
                    coarse, sup = coarsen(coarse), sup[0::2] + sup[1::2]
                profile = fill_poorly_seen(coarse, sup, min_bin_support)
                for halves in info["split_shares"]:
                    profile = apply_shares(profile, halves)
            elif support is not None:
                profile = fill_poorly_seen(solved, np.asarray(support), min_bin_support)
            else:
                profile = solved
            photo = info.get("photo_profile") or {}
            if photo.get("groups") and len(profile) % len(photo["groups"]) == 0:
                # The groups the photos' pixels reshaped take the refitted shape (their
                # flux as filled above: the solve's where it saw them).
                profile = _photo_shaped(profile, solved, np.asarray(photo["groups"], bool))
            color = result.solve.colors[block.name]
            e["color"] = color.tolist()
            e["distribution"] = {
                "basis": "inclination",
                "bins": len(profile),
                "profile": profile.tolist(),
                "profile_solved": solved.tolist(),
                "theta": "from the axis",
            }
            if "shadow_clearance" in info:
                e["distribution"]["shadow_clearance"] = float(info["shadow_clearance"])
            if "split_from_bins" in info:
                # Solved at these bins, then each split in two, once per entry of the
                # shares (reroom.invert.fine_profiles).
                e["distribution"]["split_from_bins"] = int(info["split_from_bins"])
                e["distribution"]["split_shares"] = [
                    [float(x) for x in halves] for halves in info["split_shares"]
                ]
            if info.get("photo_profile"):
                # Refitted to the photos' pixels (reroom.invert.photo_profiles).
                e["distribution"]["photo_profile"] = dict(info["photo_profile"])
            if "open_fraction" in info:
                # The shape prior of a bulb in a shade: the part of each band it leaves open.
                e["distribution"]["open_fraction"] = [float(x) for x in info["open_fraction"]]
            if "fixture_inside_fraction" in info:
                # The prior was dropped: the scan closed the shade around the bulb.
                e["distribution"]["fixture_inside_fraction"] = float(
                    info["fixture_inside_fraction"]
                )
            if support is not None:
                e["distribution"]["support"] = [float(x) for x in support]
                e["distribution"]["well_seen"] = [
                    bool(x >= min_bin_support * max(support)) for x in support
                ]
            e["power"] = (inclination_power(profile) * color).tolist()
            if out is not None:
                write_ies(out / f"{block.name}.ies", _ies_profile(profile, block.name, block.kind))
                e["ies"] = f"{block.name}.ies"
        else:  # line
            e.update(_line_entry(block, info, result, out, min_bin_support))
        e["share_of_irradiance"] = share
        e["explains_nothing"] = bool(share < 1e-3)
        entries.append(e)
    return entries


def _view_weight(info: dict[str, Any], basis: CubemapBasis, n_in: np.ndarray):
    """The captured view's pattern within each cell of ``basis`` (the direction weight its
    transfer was computed with), or None for a window solved without a view."""
    if "view" not in info:  # InvertOptions.window_view_hdri
        return None
    from reroom.invert.window_env import WindowView

    view = info["view"]
    return WindowView.load(view["hdri"], basis, n_in, float(view.get("rotation_deg", 0.0))).weight(
        basis
    )


def window_photo_maps(
    result,
    mesh: trimesh.Trimesh,
    scan_dir: str | Path,
    height: int = 128,
    min_bin_support: float = 0.01,
    view: tuple[str, float] | None = None,
    view_height: int = 0,
) -> tuple[dict[str, tuple[np.ndarray, dict[str, Any]]], list[str]]:
    """Rendering maps of the result's windows from the scan's photos, by window name.

    With ``view_height`` > 0 (and no captured ``view``) each window's figures hold
    ``view_map``, what a camera looking through it is shown
    (:func:`reroom.invert.window_env.view_map`).

    With ``view`` (``InvertOptions.window_view_hdri`` and its rotation), from that HDRI of
    the view instead (:class:`reroom.invert.window_env.WindowView`).

    See :mod:`reroom.invert.window_env`. Returns the maps with their figures, and notes
    for the report (frames skipped; an empty dict with a note when it cannot be done,
    e.g. a scan without ``hdr/exposures.json``: the windows then render their cells).
    """
    from reroom.errors import ReroomError
    from reroom.invert.window_env import photo_environments
    from reroom.invert.windows import WindowOpening

    wins = []
    for block, info in zip(result.lights, result.light_info, strict=True):
        if block.kind != "window":
            continue
        g = info["geometry"]
        opening = WindowOpening(
            block.name, *(np.asarray(g[k], float) for k in ("centre", "half_u", "half_v", "normal"))
        )
        fine = getattr(result, "render_windows", {}).get(block.name)
        if fine is None:
            cells = window_cells(result, block.name, info.get("support"), min_bin_support)
            wins.append((block.name, opening, cells, CubemapBasis(result.cubemap_n)))
        else:  # the render window's finer cells (reroom.invert.render_window)
            cells = filled_cells(fine.cells, fine.n, fine.support, min_bin_support)
            wins.append((block.name, opening, cells, CubemapBasis(fine.n)))
    if not wins:
        return {}, []
    if view is not None:
        # A captured view of the window spreads each solved cell (its pattern, not the
        # photos', which clip the view): the transfer was weighted by the same pattern.
        from reroom.invert.window_env import WindowView

        out = {}
        for name, opening, cells, b in wins:  # b: the solve's basis, or a render window's
            wv = WindowView.load(view[0], b, opening.normal, view[1])
            out[name] = (
                wv.environment(cells, b, height),
                {"view_hdri": str(view[0]), "rotation_deg": view[1], "height": height},
            )
        return out, []
    try:
        maps, infos, stats = photo_environments(
            scan_dir, mesh, [(o, c) for _, o, c, _ in wins], [b for *_, b in wins],
            height=height, view_height=view_height,
        )  # fmt: skip
    except (ReroomError, OSError, ValueError) as exc:
        return {}, [f"window photos: not used, the windows render their cells ({exc})"]
    notes = list(stats["notes"])
    frames = {k: stats[k] for k in ("frames", "frames_used", "frames_no_exposure")}
    frames["frames_unreadable"] = len(stats["frames_unreadable"])
    return {
        name: (env, {**info, **frames, "height": height})
        for (name, *_), env, info in zip(wins, maps, infos, strict=True)
    }, notes


def write_outputs(
    result,
    mesh: trimesh.Trimesh,
    out: Path,
    meta: dict[str, Any],
    pictures: bool = True,
    window_photos: bool | None = None,
) -> Path:
    """Write every output of ``reroom invert`` into ``out``; returns ``scene.json``'s path.

    ``window_photos``: build the windows' rendering maps from the photos of
    ``meta["scan"]`` (:func:`window_photo_maps`); None takes ``meta["options"]
    ["window_photos"]`` (default True). False writes the plain cube-map pictures.
    """
    out.mkdir(parents=True, exist_ok=True)
    if window_photos is None:
        window_photos = bool(meta.get("options", {}).get("window_photos", True))
    min_bin_support = float(meta.get("options", {}).get("min_bin_support", 0.01))
    window_maps: dict[str, tuple[np.ndarray, dict[str, Any]]] = {}
    if window_photos and meta.get("scan"):
        opts = meta.get("options", {})
        view = None
        if opts.get("window_view_hdri"):
            view = (str(opts["window_view_hdri"]), float(opts.get("window_view_rotation_deg", 0.0)))
        window_maps, photo_notes = window_photo_maps(
            result, mesh, Path(meta["scan"]), min_bin_support=min_bin_support, view=view,
            view_height=int(opts.get("window_view_height", 0)),
        )  # fmt: skip
        result.warnings.extend(photo_notes)
    flags = result.flags
    attrs = {
        "albedo": np.nan_to_num(result.albedo, nan=-1.0).astype(np.float32),
        "in_cluster": flags["in_cluster"].astype(np.uint8),
        "solved_per_vertex": flags["solved_per_vertex"].astype(np.uint8),
        "nonphysical": flags["nonphysical"].astype(np.uint8),
        "unobserved": flags["unobserved"].astype(np.uint8),
        "light": flags["light"].astype(np.uint8),
        "near_geometry": flags.get("near_geometry", np.zeros(len(flags["light"]), bool)).astype(
            np.uint8
        ),
    }
    write_ply(out / "albedo.ply", trimesh.Trimesh(mesh.vertices, mesh.faces, process=False), attrs)
    lights = light_entries(result, out, min_bin_support, window_maps=window_maps)
    solve = result.solve
    pics = []
    if pictures:
        for e in lights:
            if e["type"] in ("point", "line"):
                p = f"gonio_{e['name']}.png"
                dist = e["distribution"]
                edges = None
                if e["type"] == "line":
                    prof, fold = line_profile_grid(dist)
                    edges = LineBasis(prof.shape[0], prof.shape[1], fold).phi_edges()
                    prof = prof[:, 0] if prof.shape[1] == 1 else prof
                else:
                    prof = np.asarray(dist["profile"])
                _goniometric_plot(
                    out / p,
                    prof,
                    np.asarray(e["color"]),
                    f"{e['type']} light {e['name']}: intensity vs angle",
                    edges,
                )
                pics.append(p)
            elif e["type"] == "window":
                p = f"window_{e['name']}.png"
                if e["name"] in window_maps:
                    ll = window_maps[e["name"]][0]
                    title = f"window {e['name']}: solved distant light shaped by the photos"
                else:
                    basis = CubemapBasis(result.cubemap_n)
                    ll = latlong_from_cubemap(np.asarray(e["distribution"]["cells"]), basis)
                    title = f"window {e['name']}: solved distant light"
                _cubemap_plot(out / p, ll, title)
                pics.append(p)
    clusters = []
    for i, name in enumerate(result.cluster_names):
        clusters.append(
            {
                "name": name,
                "albedo": None if not solve.cluster_used[i] else solve.albedo[i].tolist(),
                "solved": bool(solve.cluster_used[i]),
            }
        )
    res = solve.residual
    finite = np.isfinite(res).all(axis=1)
    report = {
        "method": solve.method,
        "iterations": solve.iterations,
        "converged": solve.converged,
        "objective": solve.objective,
        "history": solve.history,
        "seconds": solve.seconds,
        "timings_s": result.timings,
        "residual": {
            "rms": res[finite].std(axis=0).tolist() if finite.any() else None,
            "median_abs": np.median(np.abs(res[finite]), axis=0).tolist() if finite.any() else None,
        },
        "weights": {
            "mean": solve.weights[finite].mean(axis=0).tolist() if finite.any() else None,
            "below_0.1": float(np.mean(solve.weights[finite].mean(axis=1) < 0.1))
            if finite.any()
            else None,
        },
        "vertices": {
            "in_cluster": int(flags["in_cluster"].sum()),
            "solved_per_vertex": int(flags["solved_per_vertex"].sum()),
            "nonphysical": int(flags["nonphysical"].sum()),
            "unobserved": int(flags["unobserved"].sum()),
            "near_geometry": int(flags.get("near_geometry", np.zeros(0, bool)).sum()),
        },
        "warnings": result.warnings,
        **meta,
    }
    atomic_write_json(out / "report.json", report)
    scene = {
        "format": FORMAT,
        "version": VERSION,
        "units": {"length": "m", "radiance": "relative (the HDR mesh's)"},
        "complete": not any("left out" in w or "no observed" in w for w in result.warnings),
        "lights": lights,
        "materials": clusters,
        "albedo_file": "albedo.ply",
        "report_file": "report.json",
        "pictures": pics,
        "warnings": result.warnings,
    }
    if getattr(result, "surroundings", None):
        # reroom.invert.surroundings: the light of what the scan does not hold
        scene["surroundings"] = result.surroundings
    if getattr(result, "textures", None):
        from reroom.invert.textures import write_textures

        textures, stats = result.textures
        scene["textures"] = write_textures(textures, out)
        report["textures"] = {k: v for k, v in stats.items() if k != "notes"}
        atomic_write_json(out / "report.json", report)
    return atomic_write_json(out / "scene.json", scene)
