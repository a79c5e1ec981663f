"""Numba kernels of the transfer: hemisphere rays, per-ray accumulation, line-light pieces.

Plain single-threaded loops (the ray casting between them already uses every
core); ``cache=True`` keeps the compiled code between runs. Their logic is that
of :func:`reroom.rays.sample_hemisphere` (jittered grid, concentric map, Duff et
al.'s frame) and :func:`reroom.invert.windows.rays_through_windows`, which stay
the readable references (``tests/test_invert_transfer.py`` compares them).
:func:`line_phi_integrals` is eq. 5.11's closed form of
:func:`reroom.invert.direct._line_integral`, split by ``phi`` bin.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np


@nb.njit(cache=True)
def hemisphere_rays(
    starts: np.ndarray, normals: np.ndarray, nx: int, ny: int, jitter: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Cosine-weighted rays, ``nx * ny`` per point on a jittered grid.

    ``jitter`` is ``(n * nx * ny, 2)`` uniform in ``[0, 1)``. Returns ``(origins,
    directions)``, each ``(n * nx * ny, 3)``, point-major.
    """
    n = starts.shape[0]
    per = nx * ny
    org = np.empty((n * per, 3))
    out = np.empty((n * per, 3))
    for i in range(n):
        zx, zy, zz = normals[i, 0], normals[i, 1], normals[i, 2]
        s = 1.0 if zz >= 0.0 else -1.0
        a = -1.0 / (s + zz)
        b = zx * zy * a
        tx, ty, tz = 1.0 + s * zx * zx * a, s * b, -s * zx
        bx, by, bz = b, s + zy * zy * a, -zy
        for k in range(per):
            r = i * per + k
            u1 = ((k % nx) + jitter[r, 0]) / nx * 2.0 - 1.0
            u2 = ((k // nx) + jitter[r, 1]) / ny * 2.0 - 1.0
            if u1 == 0.0 and u2 == 0.0:
                dx, dy = 0.0, 0.0
            elif abs(u1) > abs(u2):
                phi = (math.pi / 4.0) * (u2 / u1)
                dx, dy = u1 * math.cos(phi), u1 * math.sin(phi)
            else:
                phi = math.pi / 2.0 - (math.pi / 4.0) * (u1 / u2)
                dx, dy = u2 * math.cos(phi), u2 * math.sin(phi)
            dz = math.sqrt(max(0.0, 1.0 - dx * dx - dy * dy))
            out[r, 0] = dx * tx + dy * bx + dz * zx
            out[r, 1] = dx * ty + dy * by + dz * zy
            out[r, 2] = dx * tz + dy * bz + dz * zz
            org[r, 0] = starts[i, 0]
            org[r, 1] = starts[i, 1]
            org[r, 2] = starts[i, 2]
    return org, out


@nb.njit(cache=True, parallel=True)
def accumulate(
    rays_per_point: int,
    org: np.ndarray,
    dirs: np.ndarray,
    t_hit: np.ndarray,
    face: np.ndarray,
    uv: np.ndarray,
    faces: np.ndarray,
    face_normals: np.ndarray,
    vdata: np.ndarray,
    win_centre: np.ndarray,
    win_u: np.ndarray,
    win_v: np.ndarray,
    win_hu: np.ndarray,
    win_hv: np.ndarray,
    win_normal: np.ndarray,
    tolerance: float,
    reg_origin: np.ndarray,
    reg_u: np.ndarray,
    reg_v: np.ndarray,
    reg_poly: np.ndarray,
    reg_n: np.ndarray,
    ind: np.ndarray,
    p_obs: np.ndarray,
    p_unobs: np.ndarray,
    p_light: np.ndarray,
    area: np.ndarray,
    through: np.ndarray,
    pane: np.ndarray,
) -> None:
    """Classify each ray and add its shares to its point's sums (see ``transfer.py``).

    ``reg_*`` are the area lights' outlines (:mod:`reroom.invert.area_region`): origin,
    plane axes, counter-clockwise polygon (padded) and its corner count (0: none). A hit
    on a triangle with corners both on an outlined light and off it is light inside the
    outline and the off-light corners' surface outside it, not shared by barycentric
    weight.

    ``vdata`` is ``(V, 8)`` per mesh vertex: radiance times the surface weight (3),
    surface weight (1 for observed non-light vertices), unobserved weight, area light
    (-1: none), window (-1: none), padding -- packed so that a corner costs one cache
    line rather than seven scattered reads.

    Writes ``through[r]`` (window crossed, or -1) and ``pane[r]`` (whether a
    front hit touches a window-flagged vertex: those shares are left to the caller,
    which knows the distant basis). Sums are raw counts (not yet divided by R).

    Points run in parallel (numba ``prange``), each point's rays in order, so the sums
    equal a serial loop's to the bit. The loop is bound by memory latency (three
    scattered vertex records per ray): the 300-frame scan's 26.5 M rays take 8.3 s
    serial, 4.9 s on two cores (``benchmarks/bench_hemisphere_bookkeeping.py``).
    """
    n_win = win_centre.shape[0]
    for p in nb.prange(dirs.shape[0] // rays_per_point):
        for r in range(p * rays_per_point, (p + 1) * rays_per_point):
            dx, dy, dz = dirs[r, 0], dirs[r, 1], dirs[r, 2]
            th = t_hit[r]
            # Window openings crossed before the hit (rays_through_windows).
            best, best_t = -1, np.inf
            for w in range(n_win):
                denom = dx * win_normal[w, 0] + dy * win_normal[w, 1] + dz * win_normal[w, 2]
                if denom >= -1e-9:
                    continue
                t = (
                    (win_centre[w, 0] - org[r, 0]) * win_normal[w, 0]
                    + (win_centre[w, 1] - org[r, 1]) * win_normal[w, 1]
                    + (win_centre[w, 2] - org[r, 2]) * win_normal[w, 2]
                ) / denom
                if not (t > 0.0 and t <= th + tolerance and t < best_t):
                    continue
                rx = org[r, 0] + t * dx - win_centre[w, 0]
                ry = org[r, 1] + t * dy - win_centre[w, 1]
                rz = org[r, 2] + t * dz - win_centre[w, 2]
                su = abs(rx * win_u[w, 0] + ry * win_u[w, 1] + rz * win_u[w, 2]) - win_hu[w]
                sv = abs(rx * win_v[w, 0] + ry * win_v[w, 1] + rz * win_v[w, 2]) - win_hv[w]
                inside = su <= 0.0 and sv <= 0.0
                margin = su <= tolerance and sv <= tolerance and th > t + tolerance
                if inside or margin:
                    best, best_t = w, t
            through[r] = best
            pane[r] = False
            if best >= 0:
                p_light[p] += 1.0
                continue
            f = face[r]
            if f < 0:
                p_unobs[p] += 1.0
                continue
            if face_normals[f, 0] * dx + face_normals[f, 1] * dy + face_normals[f, 2] * dz >= 0.0:
                p_unobs[p] += 1.0  # back face (or edge-on)
                continue
            u, v = uv[r, 0], uv[r, 1]
            # A rim triangle of an outlined area light: inside the outline all light,
            # outside it all surface (the off-light corners' share, renormalised).
            lit_a, off_w = -1, 0.0
            for k in range(3):
                a = int(vdata[faces[f, k], 5])
                if a >= 0 and reg_n[a] > 0:
                    lit_a = a
                elif a < 0:
                    off_w += 1.0 - u - v if k == 0 else (u if k == 1 else v)
            rim = lit_a >= 0 and off_w < 1.0
            if rim:
                qx = org[r, 0] + th * dx - reg_origin[lit_a, 0]
                qy = org[r, 1] + th * dy - reg_origin[lit_a, 1]
                qz = org[r, 2] + th * dz - reg_origin[lit_a, 2]
                qa = qx * reg_u[lit_a, 0] + qy * reg_u[lit_a, 1] + qz * reg_u[lit_a, 2]
                qb = qx * reg_v[lit_a, 0] + qy * reg_v[lit_a, 1] + qz * reg_v[lit_a, 2]
                nk = reg_n[lit_a]
                inside = True
                for i in range(nk):
                    j = (i + 1) % nk
                    ea = reg_poly[lit_a, j, 0] - reg_poly[lit_a, i, 0]
                    eb = reg_poly[lit_a, j, 1] - reg_poly[lit_a, i, 1]
                    if ea * (qb - reg_poly[lit_a, i, 1]) - eb * (qa - reg_poly[lit_a, i, 0]) < 0.0:
                        inside = False
                        break
                if inside:
                    area[p, lit_a] += 1.0
                    p_light[p] += 1.0
                    continue
                if off_w <= 1e-12:
                    p_unobs[p] += 1.0
                    continue
            for k in range(3):
                c = faces[f, k]
                bk = 1.0 - u - v if k == 0 else (u if k == 1 else v)
                if rim:
                    # Outside the outline: the off-light corners share the whole hit.
                    if vdata[c, 5] >= 0:
                        continue
                    bk /= off_w
                ind[p, 0] += bk * vdata[c, 0]
                ind[p, 1] += bk * vdata[c, 1]
                ind[p, 2] += bk * vdata[c, 2]
                p_obs[p] += bk * vdata[c, 3]
                p_unobs[p] += bk * vdata[c, 4]
                a = int(vdata[c, 5])
                if a >= 0:
                    area[p, a] += bk
                    p_light[p] += bk
                if vdata[c, 6] >= 0:
                    pane[r] = True
                    p_light[p] += bk


@nb.njit(cache=True, inline="always")
def _line_primitive(h: float, c0: float, c1: float, s: float) -> float:
    """Primitive in ``s`` of ``h (c0 + c1 s) / (h^2 + s^2)^2`` (see ``direct._line_integral``)."""
    q = h * h + s * s
    i0 = s / (2.0 * h * h * q) + math.atan2(s, h) / (2.0 * h * h * h)
    i1 = -1.0 / (2.0 * q)
    return h * (c0 * i0 + c1 * i1)


@nb.njit(cache=True)
def line_phi_integrals(
    h: np.ndarray,
    c0: np.ndarray,
    c1: np.ndarray,
    s_foot: np.ndarray,
    seg_edges: np.ndarray,
    tan_edges: np.ndarray,
    fold: bool,
    out: np.ndarray,
) -> None:
    """Eq. 5.11's unoccluded integral of every line piece, split by ``phi`` bin.

    For receiver ``i`` (distance ``h[i]`` from the line, foot point ``s_foot[i]`` along
    it, ``n . a = c0[i] + c1[i] s`` with ``s`` the position relative to the foot) and
    piece ``k`` (``seg_edges[k] .. seg_edges[k + 1]`` along the line), writes to
    ``out[i, k, j]`` the integral of ``h max(0, c0 + c1 s) / (h^2 + s^2)^2`` over the
    part of the piece whose emission angle ``phi`` lies in bin ``j``.

    The direction from the line point at ``s`` to the receiver has ``tan(phi) = -s / h``
    (``phi > 0`` towards the line's end ``p1``), so bin ``j`` (edges ``phi_j, phi_j+1``,
    ``tan_edges[j] = tan(phi_j)``, infinite at ``+-pi/2``) is ``s in [-h tan(phi_j+1),
    -h tan(phi_j)]``; folded (``|phi|`` bins from 0), also its mirror image
    ``s in [h tan(phi_j), h tan(phi_j+1)]``. Each piece is clipped to where the receiver
    faces the line, then to each bin's interval, and integrated in closed form.
    """
    n = h.shape[0]
    n_seg = seg_edges.shape[0] - 1
    n_phi = tan_edges.shape[0] - 1
    for i in range(n):
        hi_, a0, a1 = h[i], c0[i], c1[i]
        # Where the receiver faces the line: c0 + c1 s > 0.
        lo_f, hi_f = -np.inf, np.inf
        if a1 > 0.0:
            lo_f = -a0 / a1
        elif a1 < 0.0:
            hi_f = -a0 / a1
        elif a0 <= 0.0:
            for k in range(n_seg):
                for j in range(n_phi):
                    out[i, k, j] = 0.0
            continue
        for k in range(n_seg):
            sa = max(seg_edges[k] - s_foot[i], lo_f)
            sb = min(seg_edges[k + 1] - s_foot[i], hi_f)
            for j in range(n_phi):
                total = 0.0
                # signed bin: s in [-h tan(phi_j+1), -h tan(phi_j)]
                a = max(sa, -hi_ * tan_edges[j + 1])
                b = min(sb, -hi_ * tan_edges[j])
                if b > a:
                    total += _line_primitive(hi_, a0, a1, b) - _line_primitive(hi_, a0, a1, a)
                if fold:  # mirror image: s in [h tan(phi_j), h tan(phi_j+1)]
                    a = max(sa, hi_ * tan_edges[j])
                    b = min(sb, hi_ * tan_edges[j + 1])
                    if b > a:
                        total += _line_primitive(hi_, a0, a1, b) - _line_primitive(hi_, a0, a1, a)
                out[i, k, j] = total


@nb.njit(cache=True)
def portal_samples(
    points: np.ndarray,
    normals: np.ndarray,
    centre: np.ndarray,
    half_u: np.ndarray,
    half_v: np.ndarray,
    n_in: np.ndarray,
    k: int,
    jitter: np.ndarray,
    eps: float,
    tolerance: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, int]:
    """The live samples of :func:`reroom.invert.portal.window_portal_transfer`.

    ``k x k`` jittered points on the rectangle ``centre + s half_u + t half_v`` per point
    (``jitter`` is ``(n, k * k, 2)`` uniform in ``[0, 1)``). A sample is live where both
    cosines are positive; for those returns the owner (point index), the shadow ray's
    start (lifted by ``eps`` along the normal), its segment to the sample, its length
    less ``tolerance``, ``cos_x cos_y / d^2`` and the direction ``y - x``. Arrays are
    sized for every sample; the first ``count`` rows are filled.
    """
    n = points.shape[0]
    per = k * k
    total = n * per
    owner = np.empty(total, np.int64)
    start = np.empty((total, 3))
    seg = np.empty((total, 3))
    stop = np.empty(total)
    value = np.empty(total)
    direction = np.empty((total, 3))
    count = 0
    for i in range(n):
        px, py, pz = points[i, 0], points[i, 1], points[i, 2]
        nx, ny, nz = normals[i, 0], normals[i, 1], normals[i, 2]
        for a in range(k):
            for b in range(k):
                j = a * k + b
                s = 2.0 * (a + jitter[i, j, 0]) / k - 1.0
                t = 2.0 * (b + jitter[i, j, 1]) / k - 1.0
                yx = centre[0] + s * half_u[0] + t * half_v[0]
                yy = centre[1] + s * half_u[1] + t * half_v[1]
                yz = centre[2] + s * half_u[2] + t * half_v[2]
                dx, dy, dz = yx - px, yy - py, yz - pz
                d2 = dx * dx + dy * dy + dz * dz
                if d2 <= 0.0:
                    continue
                dist = math.sqrt(d2)
                cx = (nx * dx + ny * dy + nz * dz) / dist
                cy = -(n_in[0] * dx + n_in[1] * dy + n_in[2] * dz) / dist
                if cx <= 0.0 or cy <= 0.0:
                    continue
                ox, oy, oz = px + eps * nx, py + eps * ny, pz + eps * nz
                sx, sy, sz = yx - ox, yy - oy, yz - oz
                owner[count] = i
                start[count, 0], start[count, 1], start[count, 2] = ox, oy, oz
                seg[count, 0], seg[count, 1], seg[count, 2] = sx, sy, sz
                stop[count] = math.sqrt(sx * sx + sy * sy + sz * sz) - tolerance
                value[count] = cx * cy / d2
                direction[count, 0], direction[count, 1], direction[count, 2] = dx, dy, dz
                count += 1
    return owner, start, seg, stop, value, direction, count


@nb.njit(cache=True)
def area_samples(
    points: np.ndarray,
    normals: np.ndarray,
    tri: np.ndarray,
    front: np.ndarray,
    share3: np.ndarray,
    mean_share: np.ndarray,
    face: np.ndarray,
    r1: np.ndarray,
    r2: np.ndarray,
    samples: int,
) -> tuple[np.ndarray, np.ndarray]:
    """Area-light samples of :func:`reroom.invert.area.area_light_transfer`, one pass.

    For receiver ``i`` and sample ``k`` (row ``r = i * samples + k``): the point ``y`` on
    triangle ``face[r]`` at the square-root barycentrics of ``(r1[r], r2[r])`` and the
    integrand ``w cos_x cos_y / d^2`` (0 behind either surface), ``w`` the barycentric
    light share over the triangle's mean share. Returns ``(value, y)``.
    """
    n = points.shape[0]
    value = np.zeros(n * samples)
    ys = np.empty((n * samples, 3))
    for i in range(n):
        px, py, pz = points[i, 0], points[i, 1], points[i, 2]
        nx, ny, nz = normals[i, 0], normals[i, 1], normals[i, 2]
        for k in range(samples):
            r = i * samples + k
            f = face[r]
            s1 = math.sqrt(r1[r])
            b0, b1, b2 = 1.0 - s1, s1 * (1.0 - r2[r]), s1 * r2[r]
            yx = b0 * tri[f, 0, 0] + b1 * tri[f, 1, 0] + b2 * tri[f, 2, 0]
            yy = b0 * tri[f, 0, 1] + b1 * tri[f, 1, 1] + b2 * tri[f, 2, 1]
            yz = b0 * tri[f, 0, 2] + b1 * tri[f, 1, 2] + b2 * tri[f, 2, 2]
            ys[r, 0], ys[r, 1], ys[r, 2] = yx, yy, yz
            dx, dy, dz = yx - px, yy - py, yz - pz
            d2 = dx * dx + dy * dy + dz * dz
            if d2 <= 0.0:
                continue
            dist = math.sqrt(d2)
            cos_x = (nx * dx + ny * dy + nz * dz) / dist
            cos_y = -(front[f, 0] * dx + front[f, 1] * dy + front[f, 2] * dz) / dist
            if cos_x > 0.0 and cos_y > 0.0:
                w = (b0 * share3[f, 0] + b1 * share3[f, 1] + b2 * share3[f, 2]) / mean_share[f]
                v = w * cos_x * cos_y / d2
                if math.isfinite(v):
                    value[r] = v
    return value, ys
