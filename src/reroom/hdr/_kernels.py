"""Numba kernels of the HDR stage: projection, depth tests, gradients, weighted medians.

They are plain loops over arrays; the Python side keeps all the logic that is not
hot. ``cache=True`` keeps the compiled code between runs (first compile: a few
seconds). The per-frame kernels run on one thread: they take a few ms each, the
ray casting between them already uses every core, and on a busy machine
(``prange`` waits for its slowest thread) two threads measured 2-3x *slower*
than one. Only the once-per-run medians use ``prange``.
"""

from __future__ import annotations

import numba as nb
import numpy as np

_LUMA = (0.2126, 0.7152, 0.0722)


@nb.njit(cache=True)
def project_vertices(
    verts: np.ndarray,
    normals: np.ndarray,
    perm: np.ndarray,
    chunk_offsets: np.ndarray,
    chunk_centers: np.ndarray,
    chunk_radii: np.ndarray,
    rot: np.ndarray,
    trans: np.ndarray,
    center: np.ndarray,
    intr: np.ndarray,
    margin: float,
    min_cos: float,
    near: float,
    u_out: np.ndarray,
    v_out: np.ndarray,
    g_out: np.ndarray,
    z_out: np.ndarray,
    ok_out: np.ndarray,
) -> None:
    """Project every vertex into one frame; flag those in the image and facing the camera.

    Vertices come in spatial chunks (``perm[chunk_offsets[c]:chunk_offsets[c+1]]``
    with bounding spheres): a chunk wholly outside the view frustum is skipped
    without touching its vertices. ``rot, trans`` map world points to OpenCV
    camera coordinates (z = depth); ``intr = [fx, fy, cx, cy, w, h, k1, k2, p1, p2]``.
    For each vertex in view the kernel writes its pixel position, its depth, the
    projected-area weight g of the thesis's eq. 3.2
    (``cos(normal) * cos(optical axis) / distance^2``) and ``ok_out`` = at least
    ``margin`` pixels inside the image, in front of the camera, and
    ``cos(normal, to camera) >= min_cos``. ``ok_out`` must be all False on entry.
    """
    fx, fy, cx, cy, w, h = intr[0], intr[1], intr[2], intr[3], intr[4], intr[5]
    k1, k2, p1, p2 = intr[6], intr[7], intr[8], intr[9]
    distort = k1 != 0.0 or k2 != 0.0 or p1 != 0.0 or p2 != 0.0
    # Side planes of the frustum through the camera centre, as x/z and y/z bounds.
    xa, xb = (margin - cx) / fx, (w - margin - cx) / fx
    ya, yb = (margin - cy) / fy, (h - margin - cy) / fy
    na, nb_ = np.sqrt(1.0 + xa * xa), np.sqrt(1.0 + xb * xb)
    ma, mb = np.sqrt(1.0 + ya * ya), np.sqrt(1.0 + yb * yb)
    for ch in range(chunk_offsets.shape[0] - 1):
        r = chunk_radii[ch]
        qx, qy, qz = chunk_centers[ch, 0], chunk_centers[ch, 1], chunk_centers[ch, 2]
        cz = rot[2, 0] * qx + rot[2, 1] * qy + rot[2, 2] * qz + trans[2]
        if cz + r <= near:
            continue
        if not distort:
            cxx = rot[0, 0] * qx + rot[0, 1] * qy + rot[0, 2] * qz + trans[0]
            cyy = rot[1, 0] * qx + rot[1, 1] * qy + rot[1, 2] * qz + trans[1]
            if (cxx - xa * cz) / na < -r or (xb * cz - cxx) / nb_ < -r:
                continue
            if (cyy - ya * cz) / ma < -r or (yb * cz - cyy) / mb < -r:
                continue
        for k in range(chunk_offsets[ch], chunk_offsets[ch + 1]):
            i = perm[k]
            x, y, zw = verts[i, 0], verts[i, 1], verts[i, 2]
            pz = rot[2, 0] * x + rot[2, 1] * y + rot[2, 2] * zw + trans[2]
            z_out[i] = pz
            if pz <= near:
                continue
            dx, dy, dz = center[0] - x, center[1] - y, center[2] - zw
            d2 = dx * dx + dy * dy + dz * dz
            dist = np.sqrt(d2)
            cos_n = (normals[i, 0] * dx + normals[i, 1] * dy + normals[i, 2] * dz) / dist
            if cos_n < min_cos:
                continue
            px = rot[0, 0] * x + rot[0, 1] * y + rot[0, 2] * zw + trans[0]
            py = rot[1, 0] * x + rot[1, 1] * y + rot[1, 2] * zw + trans[1]
            xn = px / pz
            yn = py / pz
            if distort:
                r2 = xn * xn + yn * yn
                radial = 1.0 + k1 * r2 + k2 * r2 * r2
                xd = xn * radial + 2.0 * p1 * xn * yn + p2 * (r2 + 2.0 * xn * xn)
                yd = yn * radial + p1 * (r2 + 2.0 * yn * yn) + 2.0 * p2 * xn * yn
                xn, yn = xd, yd
            u = fx * xn + cx
            v = fy * yn + cy
            if u < margin or v < margin or u >= w - margin or v >= h - margin:
                continue
            u_out[i] = u
            v_out[i] = v
            # cos(optical axis, ray) = depth / distance.
            g_out[i] = cos_n * (pz / dist) / d2
            ok_out[i] = True


@nb.njit(cache=True)
def relative_gradient(
    image: np.ndarray, luma_lut: np.ndarray, floor: float, smooth: int = 0
) -> np.ndarray:
    """Sobel gradient magnitude of the linear luminance, relative to the pixel's own.

    ``luma_lut[c, level]`` is channel ``c``'s contribution to the linear luminance.
    The result ``|grad L| / (L + floor)`` approximates ``|grad log L|``: a texture or
    depth edge reads the same at any exposure, while Sobel's smoothing across
    the derivative keeps per-pixel noise from triggering it (no logarithms: this
    runs once per frame). With ``smooth = 1`` the luminance is first averaged over
    3x3 pixels, which keeps the per-pixel noise of noisy frames from reading as
    edges. Border pixels use replicated neighbours.
    """
    h, w = image.shape[0], image.shape[1]
    raw = np.empty((h, w), np.float32)
    for r in range(h):
        for c in range(w):
            raw[r, c] = (
                luma_lut[0, image[r, c, 0]]
                + luma_lut[1, image[r, c, 1]]
                + luma_lut[2, image[r, c, 2]]
            )
    if smooth > 0:
        lum = np.empty((h, w), np.float32)
        for r in range(h):
            for c in range(w):
                acc = np.float32(0.0)
                cnt = 0
                for rr in range(max(r - smooth, 0), min(r + smooth + 1, h)):
                    for cc in range(max(c - smooth, 0), min(c + smooth + 1, w)):
                        acc += raw[rr, cc]
                        cnt += 1
                lum[r, c] = acc / cnt
    else:
        lum = raw
    out = np.empty((h, w), np.float32)
    for r in range(h):
        # Clamped neighbours: border pixels get one-sided (replicated) differences.
        ra, rb = max(r - 1, 0), min(r + 1, h - 1)
        for c in range(w):
            ca, cb = max(c - 1, 0), min(c + 1, w - 1)
            gx = (
                lum[ra, cb]
                + 2.0 * lum[r, cb]
                + lum[rb, cb]
                - lum[ra, ca]
                - 2.0 * lum[r, ca]
                - lum[rb, ca]
            )
            gy = (
                lum[rb, ca]
                + 2.0 * lum[rb, c]
                + lum[rb, cb]
                - lum[ra, ca]
                - 2.0 * lum[ra, c]
                - lum[ra, cb]
            )
            out[r, c] = np.sqrt(gx * gx + gy * gy) / (8.0 * (lum[r, c] + floor))
    return out


@nb.njit(cache=True)
def max_in_window(grad: np.ndarray, rows: np.ndarray, cols: np.ndarray, radius: int) -> np.ndarray:
    """The largest ``grad`` value within ``radius`` pixels (a square) of each sample pixel."""
    h, w = grad.shape
    out = np.empty(rows.shape[0], np.float32)
    for k in range(rows.shape[0]):
        best = np.float32(0.0)
        for r in range(max(rows[k] - radius, 0), min(rows[k] + radius + 1, h)):
            for c in range(max(cols[k] - radius, 0), min(cols[k] + radius + 1, w)):
                if grad[r, c] > best:
                    best = grad[r, c]
        out[k] = best
    return out


@nb.njit(cache=True)
def depth_edges(inv_depth: np.ndarray, tol: float) -> np.ndarray:
    """Mark depth-buffer samples at depth discontinuities, creases and holes.

    1/depth is affine across a plane, so its second differences vanish there; a
    sample is an edge when a second difference along x or y exceeds ``tol`` times
    its own value, or when it or a neighbour saw nothing (0).
    """
    gh, gw = inv_depth.shape
    edge = np.zeros((gh, gw), np.bool_)
    for r in range(gh):
        for c in range(gw):
            x = inv_depth[r, c]
            if x <= 0.0:
                edge[r, c] = True
                continue
            lim = tol * x
            if c > 0 and c < gw - 1:
                a, b = inv_depth[r, c - 1], inv_depth[r, c + 1]
                if a <= 0.0 or b <= 0.0 or abs(a - 2.0 * x + b) > lim:
                    edge[r, c] = True
                    continue
            if r > 0 and r < gh - 1:
                a, b = inv_depth[r - 1, c], inv_depth[r + 1, c]
                if a <= 0.0 or b <= 0.0 or abs(a - 2.0 * x + b) > lim:
                    edge[r, c] = True
    return edge


@nb.njit(cache=True)
def depth_test(
    inv_depth: np.ndarray,
    edges: np.ndarray,
    stride: int,
    u: np.ndarray,
    v: np.ndarray,
    z: np.ndarray,
    rel_tol: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Test vertices against an inverse-depth buffer sampled every ``stride`` pixels.

    ``inv_depth[a, b]`` is 1 / depth of the surface seen through pixel centre
    ``(stride * b + stride / 2, stride * a + stride / 2)`` (0 for no hit); 1/depth
    is affine across a plane, so its bilinear interpolation is exact on flat
    surfaces. A vertex is visible when it is not behind the interpolated surface
    by more than ``rel_tol`` (relative depth). ``near_edge`` marks vertices with
    an ``edges`` sample (:func:`depth_edges`) among their four buffer samples;
    there the test uses the nearest of the four surfaces.
    """
    gh, gw = inv_depth.shape
    n = u.shape[0]
    visible = np.zeros(n, np.bool_)
    near_edge = np.zeros(n, np.bool_)
    for k in range(n):
        gx = u[k] / stride - 0.5
        gy = v[k] / stride - 0.5
        x0 = min(max(int(np.floor(gx)), 0), max(gw - 2, 0))
        y0 = min(max(int(np.floor(gy)), 0), max(gh - 2, 0))
        x1 = min(x0 + 1, gw - 1)
        y1 = min(y0 + 1, gh - 1)
        fx = min(max(gx - x0, 0.0), 1.0)
        fy = min(max(gy - y0, 0.0), 1.0)
        a = inv_depth[y0, x0]
        b = inv_depth[y0, x1]
        c = inv_depth[y1, x0]
        d = inv_depth[y1, x1]
        if edges[y0, x0] or edges[y0, x1] or edges[y1, x0] or edges[y1, x1]:
            near_edge[k] = True
            surf = max(max(a, b), max(c, d))
            if surf <= 0.0:
                continue
        else:
            surf = (a * (1 - fx) + b * fx) * (1 - fy) + (c * (1 - fx) + d * fx) * fy
        # Not behind the surface: 1/z_vertex >= (1/z_surface) / (1 + tol).
        visible[k] = 1.0 / z[k] * (1.0 + rel_tol) >= surf
    return visible, near_edge


@nb.njit(cache=True)
def schur_outer(
    offsets: np.ndarray,
    frames: np.ndarray,
    a: np.ndarray,
    d: np.ndarray,
    n_frames: int,
) -> np.ndarray:
    """``M = sum_i a_i a_i^T / d_i`` over vertices, as a dense ``(F, F)`` matrix.

    ``a_i`` is vertex ``i``'s row of the frame-vertex coupling block of the normal
    equations (entries ``a[offsets[i]:offsets[i+1]]`` at columns ``frames[...]``)
    and ``d_i`` its diagonal: eliminating every vertex unknown (the Schur
    complement, as in bundle adjustment) leaves ``U - M`` for the frames.
    The cost is ``sum_i n_i^2`` for ``n_i`` samples of vertex ``i``.
    """
    m = np.zeros((n_frames, n_frames))
    for i in range(offsets.shape[0] - 1):
        s, e = offsets[i], offsets[i + 1]
        if d[i] <= 0.0:
            continue
        inv = 1.0 / d[i]
        for k in range(s, e):
            fk = a[k] * inv
            if fk == 0.0:
                continue
            row = frames[k]
            for q in range(s, e):
                m[row, frames[q]] += fk * a[q]
    return m


@nb.njit(cache=True)
def group_by(keys: np.ndarray, n_groups: int) -> tuple[np.ndarray, np.ndarray]:
    """Counting sort: ``order`` such that ``keys[order]`` is grouped, and group offsets."""
    counts = np.zeros(n_groups + 1, np.int64)
    for k in keys:
        counts[k + 1] += 1
    for g in range(n_groups):
        counts[g + 1] += counts[g]
    pos = counts[:-1].copy()
    order = np.empty(keys.shape[0], np.int64)
    for s in range(keys.shape[0]):
        k = keys[s]
        order[pos[k]] = s
        pos[k] += 1
    return order, counts


@nb.njit(parallel=True, cache=True)
def reproject_medians(
    offsets: np.ndarray,
    order: np.ndarray,
    frames: np.ndarray,
    levels: np.ndarray,
    codes: np.ndarray,
    geometry: np.ndarray,
    flags: np.ndarray,
    decode: np.ndarray,
    confidence: np.ndarray,
    inv_scale: np.ndarray,
    prior: np.ndarray,
    level_linear: np.ndarray,
    out: np.ndarray,
    count: np.ndarray,
) -> None:
    """Per-vertex, per-channel weighted median of ``X_ij / t_j`` (thesis §3.6).

    Sample ``order[k]`` for ``offsets[i] <= k < offsets[i+1]`` belongs to vertex
    ``i``; its linear value is ``decode[codes[...]]`` and its weight in channel
    ``c`` is ``confidence[level] * geometry`` (eq. 3.4). Samples of frames whose
    ``inv_scale`` is not finite are skipped, and each vertex uses only its samples of
    the best tier (:func:`_sample_tier`): its clean samples if it has any, else those
    near an image or depth edge (bits 1 | 2 of ``flags``). Samples whose pixels all see
    another surface (bit 128) are never used. Vertices without samples keep ``out = 0``
    and ``count = 0``.

    With an empty ``prior`` (shape ``(0, 3)``), ``level`` is the sample's own 8-bit
    level (the thesis). Otherwise it is the level that ``prior[i, c] / inv_scale``
    gives through the response ``level_linear``, and a clipped sample (level 255) is
    censored (+inf in the median). Where clipped samples hold half the weight or more,
    that median is +inf: the data bound the radiance only from below, and the vertex
    gets the smallest median they allow, each clipped sample at its bound
    ``level_linear[255] * inv_scale`` (what the frame would have recorded at white),
    or the ``out`` it came with (the first pass's) where that is larger.
    """
    n = offsets.shape[0] - 1
    predicted = prior.shape[0] > 0
    top = confidence.shape[0] - 1
    for i in nb.prange(n):
        s, e = offsets[i], offsets[i + 1]
        best = -1
        m = 0
        for k in range(s, e):
            smp = order[k]
            if np.isfinite(inv_scale[frames[smp], 0]):
                tier = _sample_tier(flags[smp])
                if tier > best:
                    best, m = tier, 0
                if tier == best:
                    m += 1
        if best <= 0:  # only samples of other surfaces
            m = 0
        count[i] = m
        if m == 0:
            continue
        vals = np.empty(m)
        wts = np.empty(m)
        bounds = np.empty(m)
        for c in range(3):
            q = 0
            for k in range(s, e):
                smp = order[k]
                j = frames[smp]
                if not np.isfinite(inv_scale[j, 0]) or _sample_tier(flags[smp]) != best:
                    continue
                vals[q] = decode[codes[smp, c]] * inv_scale[j, c]
                bounds[q] = vals[q]
                level = levels[smp, c]
                if predicted:
                    if level >= top:
                        vals[q] = np.inf
                        bounds[q] = level_linear[top] * inv_scale[j, c]
                    level = np.searchsorted(level_linear, prior[i, c] / inv_scale[j, c])
                    level = min(max(level, 0), top)
                wts[q] = confidence[level] * geometry[smp]
                q += 1
            total = wts.sum()
            res = _weighted_median(vals, wts, m) if total > 0.0 else vals.max()
            if np.isfinite(res):
                out[i, c] = res
            elif predicted and total > 0.0:
                # Censored at the median: the smallest median the bounds allow.
                low = _weighted_median(bounds, wts, m)
                if low > out[i, c]:
                    out[i, c] = low


@nb.njit(cache=True)
def _sample_tier(flag: np.uint8) -> int:
    """How much a sample is trusted, from its flags (``reroom.hdr.observe``): 2 clean,
    1 near an image or depth edge, 0 none of its pixels on its vertex's surface (bit
    128, never used)."""
    if flag & 128:
        return 0
    if (flag & 3) == 0:
        return 2
    return 1


@nb.njit(cache=True)
def sample_tiers(flags: np.ndarray) -> np.ndarray:
    """:func:`_sample_tier` of every sample."""
    out = np.empty(flags.shape[0], np.int64)
    for k in range(flags.shape[0]):
        out[k] = _sample_tier(flags[k])
    return out


@nb.njit(cache=True)
def _weighted_median(vals: np.ndarray, wts: np.ndarray, m: int) -> float:
    """The weighted median of ``vals[:m]`` (the first value whose cumulative weight
    reaches half the total, in ascending order)."""
    idx = np.argsort(vals[:m])
    half = 0.5 * wts[:m].sum()
    acc = 0.0
    for k in idx:
        acc += wts[k]
        if acc >= half:
            return vals[k]
    return vals[idx[m - 1]]


@nb.njit(parallel=True, cache=True)
def best_samples(
    offsets: np.ndarray,
    order: np.ndarray,
    score: np.ndarray,
) -> np.ndarray:
    """Per group, the sample with the highest ``score`` (-1 for empty groups)."""
    n = offsets.shape[0] - 1
    out = np.full(n, -1, np.int64)
    for i in nb.prange(n):
        best = -np.inf
        for k in range(offsets[i], offsets[i + 1]):
            smp = order[k]
            if score[smp] > best:
                best = score[smp]
                out[i] = smp
    return out


@nb.njit(cache=True)
def masked_bincount(keys: np.ndarray, mask: np.ndarray, n: int) -> np.ndarray:
    """``np.bincount(keys[mask], minlength=n)`` without the intermediate copy."""
    out = np.zeros(n, np.int64)
    for k in range(keys.shape[0]):
        if mask[k]:
            out[keys[k]] += 1
    return out


@nb.njit(cache=True)
def sample_pixels(
    image: np.ndarray,
    lut: np.ndarray,
    u: np.ndarray,
    v: np.ndarray,
    mode: int,
) -> tuple[np.ndarray, np.ndarray]:
    """Linear values of an 8-bit image at continuous pixel positions ``(u, v)``.

    ``mode`` 0: the pixel containing the point (thesis §3.5); 1: bilinear
    interpolation of the four nearest pixel centres; 2: mean of the 3x3 pixels
    around the containing one. Pixels are linearised (``lut``) before they are
    averaged. Also returns whether any pixel used was clipped (level 0 or 255 in
    some channel): its average is then biased.
    """
    h, w = image.shape[0], image.shape[1]
    n = u.shape[0]
    out = np.zeros((n, 3), np.float64)
    clipped = np.zeros(n, np.bool_)
    for k in range(n):
        col = min(max(int(np.floor(u[k])), 0), w - 1)
        row = min(max(int(np.floor(v[k])), 0), h - 1)
        if mode == 0:
            for c in range(3):
                lv = image[row, col, c]
                out[k, c] = lut[lv]
                if lv == 0 or lv == 255:
                    clipped[k] = True
        elif mode == 1:
            gx = u[k] - 0.5
            gy = v[k] - 0.5
            x0 = min(max(int(np.floor(gx)), 0), max(w - 2, 0))
            y0 = min(max(int(np.floor(gy)), 0), max(h - 2, 0))
            fx = min(max(gx - x0, 0.0), 1.0)
            fy = min(max(gy - y0, 0.0), 1.0)
            x1, y1 = min(x0 + 1, w - 1), min(y0 + 1, h - 1)
            for c in range(3):
                a, b = image[y0, x0, c], image[y0, x1, c]
                d, e = image[y1, x0, c], image[y1, x1, c]
                out[k, c] = (lut[a] * (1 - fx) + lut[b] * fx) * (1 - fy) + (
                    lut[d] * (1 - fx) + lut[e] * fx
                ) * fy
                for lv in (a, b, d, e):
                    if lv == 0 or lv == 255:
                        clipped[k] = True
        else:
            r0, r1 = max(row - 1, 0), min(row + 1, h - 1)
            c0, c1 = max(col - 1, 0), min(col + 1, w - 1)
            cnt = (r1 - r0 + 1) * (c1 - c0 + 1)
            for c in range(3):
                acc = 0.0
                for r in range(r0, r1 + 1):
                    for q in range(c0, c1 + 1):
                        lv = image[r, q, c]
                        acc += lut[lv]
                        if lv == 0 or lv == 255:
                            clipped[k] = True
                out[k, c] = acc / cnt
    return out, clipped


@nb.njit(cache=True)
def pair_differences(
    offsets: np.ndarray,
    frames: np.ndarray,
    logv: np.ndarray,
    keys: np.ndarray,
    n_frames: int,
) -> tuple[np.ndarray, np.ndarray]:
    """Differences ``logv[a] - logv[b]`` for samples of one vertex seen by frames ``j < k``.

    Only frame pairs whose key ``j * n_frames + k`` is in ``keys`` are emitted (looked
    up in a dense table of the ``n_frames**2`` pairs). Returns ``(pair_keys,
    differences)``.
    """
    wanted = np.zeros(n_frames * n_frames, np.bool_)
    for key in keys:
        wanted[key] = True
    count = 0
    for i in range(offsets.shape[0] - 1):
        for a in range(offsets[i], offsets[i + 1]):
            for b in range(offsets[i], offsets[i + 1]):
                if frames[a] < frames[b] and wanted[frames[a] * n_frames + frames[b]]:
                    count += 1
    out_k = np.empty(count, np.int64)
    out_d = np.empty(count, np.float64)
    q = 0
    for i in range(offsets.shape[0] - 1):
        for a in range(offsets[i], offsets[i + 1]):
            for b in range(offsets[i], offsets[i + 1]):
                if frames[a] < frames[b]:
                    key = frames[a] * n_frames + frames[b]
                    if wanted[key]:
                        out_k[q] = key
                        out_d[q] = logv[a] - logv[b]
                        q += 1
    return out_k, out_d


@nb.njit(cache=True)
def group_medians_by_key(
    key: np.ndarray, values: np.ndarray, n_keys: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Keys present in ``key`` (in ``[0, n_keys)``), their counts and the median of
    ``values`` per key.

    A counting sort groups the values in O(n) (the keys are small integers: frame
    pairs), and numba's ``np.median`` selects each group's median rather than sorting.
    """
    counts = np.zeros(n_keys, np.int64)
    for k in key:
        counts[k] += 1
    starts = np.zeros(n_keys + 1, np.int64)
    for k in range(n_keys):
        starts[k + 1] = starts[k] + counts[k]
    fill = starts[:-1].copy()
    grouped = np.empty(values.shape[0], np.float64)
    for i in range(key.shape[0]):
        grouped[fill[key[i]]] = values[i]
        fill[key[i]] += 1
    present = np.flatnonzero(counts)
    med = np.empty(present.shape[0], np.float64)
    for g in range(present.shape[0]):
        k = present[g]
        med[g] = np.median(grouped[starts[k] : starts[k + 1]])
    return present.astype(np.int64), counts[present], med
