"""Compiled broad phase of contact detection between bodies: the pairs of points and triangle centroids
(or edge midpoints) of different bodies within a reach, from a uniform grid per body
(:mod:`skfem_affine.contact.geometry`, :mod:`skfem_affine.contact.edges`)."""
import numpy as np
from numba import njit

from skfem_affine import _compile_notice  # noqa: F401 (one stderr line when the cached kernels compile)


@njit(cache=True)
def _grow(a, size):
    """``a`` with room for at least ``size`` entries (doubled), its entries kept."""
    if size <= a.size:
        return a
    out = np.empty(max(size, 2 * a.size, 1024), a.dtype)
    out[:a.size] = a
    return out


@njit(cache=True, error_model="numpy")
def vertex_pairs(xs, owner, centroid, tri_start, r, rows, tris, starts):
    """Every pair (vertex row, triangle) of different bodies whose distance to the triangle's centroid
    is at most ``r[owner of the vertex, body of the triangle]`` (B, B), grouped by (triangle's body,
    row), both ascending: returns (rows, triangles, start of each group, its end last) in the arrays
    ``rows``, ``tris``, ``starts`` (int64, grown when too short), and their lengths.

    ``xs`` (m, 3) the vertices, ``owner`` (m,) their bodies, ``centroid`` (T, 3) the triangles' centroids,
    body b's from ``tri_start[b]`` to ``tri_start[b + 1]``. Each body's centroids are binned in a
    uniform grid of cells a quarter of the largest reach into it wide (at most 64 along its longest
    side), sorted in columns along z, and each vertex scans the part of each column its reach overlaps."""
    B, m = tri_start.size - 1, xs.shape[0]
    k = g = 0
    for b in range(B):
        t0, t1 = tri_start[b], tri_start[b + 1]
        rmax = -np.inf
        for a in range(B):
            if a != b:
                rmax = max(rmax, r[a, b])
        if t1 == t0 or not rmax >= 0.0:
            continue
        lo, hi = centroid[t0].copy(), centroid[t0].copy()
        for t in range(t0, t1):
            for c in range(3):
                lo[c], hi[c] = min(lo[c], centroid[t, c]), max(hi[c], centroid[t, c])
        cell = max(0.25 * rmax, max(hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]) / 64.0, 1e-300)
        dims = np.empty(3, np.int64)
        for c in range(3):
            dims[c] = int((hi[c] - lo[c]) / cell) + 1
        n_cells = dims[0] * dims[1] * dims[2]
        first = np.zeros(n_cells + 1, np.int64)             # the centroids by cell (a counting sort)
        where = np.empty(t1 - t0, np.int64)
        for t in range(t0, t1):
            q = 0
            for c in range(3):
                q = q * dims[c] + min(max(int((centroid[t, c] - lo[c]) / cell), 0), dims[c] - 1)
            where[t - t0] = q
            first[q + 1] += 1
        for q in range(n_cells):
            first[q + 1] += first[q]
        fill, item = first[:-1].copy(), np.empty(t1 - t0, np.int64)
        c0, c1 = np.empty(3, np.int64), np.empty(3, np.int64)
        for t in range(t0, t1):
            item[fill[where[t - t0]]] = t
            fill[where[t - t0]] += 1
        for i in range(m):
            a = owner[i]
            ri = r[a, b] if a != b else -1.0
            if not ri >= 0.0:
                continue
            p = xs[i]
            if (p[0] < lo[0] - ri or p[0] > hi[0] + ri or p[1] < lo[1] - ri or p[1] > hi[1] + ri
                    or p[2] < lo[2] - ri or p[2] > hi[2] + ri):
                continue
            for c in range(3):
                c0[c] = max(int((p[c] - ri - lo[c]) / cell), 0)
                c1[c] = min(int((p[c] + ri - lo[c]) / cell), dims[c] - 1)
            start, r2 = k, ri * ri
            for ix in range(c0[0], c1[0] + 1):
                dx = max(lo[0] + ix * cell - p[0], p[0] - (lo[0] + (ix + 1) * cell), 0.0)
                for iy in range(c0[1], c1[1] + 1):
                    dy = max(lo[1] + iy * cell - p[1], p[1] - (lo[1] + (iy + 1) * cell), 0.0)
                    left = r2 - dx * dx - dy * dy            # the column of cells (ix, iy) within reach in z
                    if left < 0.0:
                        continue
                    h = np.sqrt(left) * (1.0 + 1e-12)
                    z0 = max(int((p[2] - h - lo[2]) / cell), c0[2])
                    z1 = min(int((p[2] + h - lo[2]) / cell), c1[2])
                    if z1 < z0:
                        continue
                    q = (ix * dims[1] + iy) * dims[2]
                    for j in range(first[q + z0], first[q + z1 + 1]):
                        t = item[j]
                        e0, e1, e2 = p[0] - centroid[t, 0], p[1] - centroid[t, 1], p[2] - centroid[t, 2]
                        if e0 * e0 + e1 * e1 + e2 * e2 <= r2:
                            if k == rows.size:
                                rows, tris = _grow(rows, k + 1), _grow(tris, k + 1)
                            rows[k], tris[k] = i, t
                            k += 1
            if k > start:
                starts = _grow(starts, g + 2)
                starts[g] = start
                g += 1
    starts = _grow(starts, g + 1)
    starts[g] = k
    return rows, tris, starts, k, g + 1


@njit(cache=True, error_model="numpy")
def body_speeds(u, rows, owner, n_bodies):
    """Mean velocity (B, 3) of each body's vertices ``rows`` (their bodies ``owner``) in u (n, 3),
    each vertex's speed relative to its body's mean, and each body's largest such speed (B,)."""
    mean, count = np.zeros((n_bodies, 3)), np.zeros(n_bodies, np.int64)
    for k in range(rows.size):
        for c in range(3):
            mean[owner[k], c] += u[rows[k], c]
        count[owner[k]] += 1
    for b in range(n_bodies):
        for c in range(3):
            mean[b, c] /= max(count[b], 1)
    spread, largest = np.empty(rows.size), np.zeros(n_bodies)
    for k in range(rows.size):
        b = owner[k]
        d0, d1, d2 = u[rows[k], 0] - mean[b, 0], u[rows[k], 1] - mean[b, 1], u[rows[k], 2] - mean[b, 2]
        spread[k] = np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
        largest[b] = max(largest[b], spread[k])
    return mean, spread, largest


@njit(cache=True, error_model="numpy")
def largest_move(x, rows, x0):
    """The largest distance of a vertex ``rows`` at x (n, 3) from its place x0 (len(rows), 3)."""
    move = 0.0
    for k in range(rows.size):
        d0, d1, d2 = x[rows[k], 0] - x0[k, 0], x[rows[k], 1] - x0[k, 1], x[rows[k], 2] - x0[k, 2]
        move = max(move, d0 * d0 + d1 * d1 + d2 * d2)
    return np.sqrt(move)


@njit(cache=True, error_model="numpy")
def change_spread(w, v, rows):
    """The range (3,) over the vertices ``rows`` of each component of w - v (n, 3 each), and the
    largest magnitude of a component of w there."""
    lo, hi, scale = np.full(3, np.inf), np.full(3, -np.inf), 0.0
    for k in range(rows.size):
        for c in range(3):
            d = w[rows[k], c] - v[rows[k], c]
            lo[c], hi[c] = min(lo[c], d), max(hi[c], d)
            scale = max(scale, abs(w[rows[k], c]))
    return (hi - lo if rows.size else np.zeros(3)), scale
