"""Compiled narrow phase of contact detection (:mod:`skfem_affine.contact.geometry`): closest points on
triangles, per vertex and other body the nearest of its candidate triangles, the edge-edge tests
(:mod:`skfem_affine.contact.edges`), and the triangles' centroids and the edges' normals they use.

A loop per candidate pair is inherent here. The arithmetic is that of the vectorised numpy
formulation, operation for operation (the same sums in the same order, numpy's three-term dot
products included: ``_dot``), so that the contacts found are the same to the last bit.

A triangle without area (``|ab x ac| <= DEGENERATE`` times its longest edge squared: a crushed or
squashed boundary triangle, its corners collinear or equal) is a segment: the closest point on it is
the one on its longest edge, and it has no face normal, so it adds nothing to the pseudo-normal
that decides inside from outside. When none of the triangles as close as the closest has an area,
the sign is that of the direction from the closest point to the point against the sum of the unit
normals of the candidate triangles that have one (the body's outward normal near it); with no such
candidate either, the point is outside, its normal the direction from the closest point (the z axis
when the point is on it). No gap or normal is NaN.
"""
import numpy as np
from numba import njit

from skfem_affine import _compile_notice  # noqa: F401 (one stderr line when the cached kernels compile)

# A triangle has no area when the norm of its corners' cross product is at most this times its
# longest edge squared (the sine of its largest angle, about): it is taken as a segment.
DEGENERATE = 1e-12


@njit(cache=True, error_model="numpy")
def _safe(num, den):
    """num / den, with a denominator of magnitude <= 1e-300 (or NaN) taken as 1e-300."""
    return num / (den if abs(den) > 1e-300 else 1e-300)


@njit(cache=True, error_model="numpy")
def _dot(u0, u1, u2, v0, v1, v2):
    """u . v, summed in the order of numpy's ``einsum("ij,ij->i")`` on rows of three (first and last
    product, then the middle one)."""
    return (u0 * v0 + u2 * v2) + u1 * v1


@njit(cache=True, error_model="numpy")
def triangle_weights(p, a, b, c):
    """Barycentric weights (w0, w1, w2) of the closest point of p (3,) on the triangle (a, b, c):
    the Voronoi-region test of Ericson (Real-Time Collision Detection, 5.1.5). A corner's region
    comes before an edge's and an edge's before the interior; a degenerate triangle (a segment, a
    point) gets finite weights, not always of a closest point: :func:`closest_weights`."""
    ab0, ab1, ab2 = b[0] - a[0], b[1] - a[1], b[2] - a[2]
    ac0, ac1, ac2 = c[0] - a[0], c[1] - a[1], c[2] - a[2]
    d1 = _dot(ab0, ab1, ab2, p[0] - a[0], p[1] - a[1], p[2] - a[2])
    d2 = _dot(ac0, ac1, ac2, p[0] - a[0], p[1] - a[1], p[2] - a[2])
    d3 = _dot(ab0, ab1, ab2, p[0] - b[0], p[1] - b[1], p[2] - b[2])
    d4 = _dot(ac0, ac1, ac2, p[0] - b[0], p[1] - b[1], p[2] - b[2])
    d5 = _dot(ab0, ab1, ab2, p[0] - c[0], p[1] - c[1], p[2] - c[2])
    d6 = _dot(ac0, ac1, ac2, p[0] - c[0], p[1] - c[1], p[2] - c[2])
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
    if d1 <= 0 and d2 <= 0:                           # corner a
        return 1.0, 0.0, 0.0
    if d3 >= 0 and d4 <= d3:                          # corner b
        return 0.0, 1.0, 0.0
    if vc <= 0 and d1 >= 0 and d3 <= 0:               # edge ab
        v = _safe(d1, d1 - d3)
        return 1 - v, v, 0.0
    if d6 >= 0 and d5 <= d6:                          # corner c
        return 0.0, 0.0, 1.0
    if vb <= 0 and d2 >= 0 and d6 <= 0:               # edge ac
        w = _safe(d2, d2 - d6)
        return 1 - w, 0 * w, w
    if va <= 0 and d4 - d3 >= 0 and d5 - d6 >= 0:     # edge bc
        w = _safe(d4 - d3, (d4 - d3) + (d5 - d6))
        return 0 * w, 1 - w, w
    s = va + vb + vc
    v, w = _safe(vb, s), _safe(vc, s)
    return 1.0 - v - w, v, w


@njit(cache=True, error_model="numpy")
def _face(a, b, c):
    """The cross product (ab x ac) of the triangle (a, b, c), its norm, and whether the triangle has
    no area (``DEGENERATE``; NaN corners too)."""
    e0, e1, e2 = b[0] - a[0], b[1] - a[1], b[2] - a[2]
    f0, f1, f2 = c[0] - a[0], c[1] - a[1], c[2] - a[2]
    n0, n1, n2 = e1 * f2 - e2 * f1, e2 * f0 - e0 * f2, e0 * f1 - e1 * f0
    nn = np.sqrt(n0 * n0 + n1 * n1 + n2 * n2)
    g0, g1, g2 = c[0] - b[0], c[1] - b[1], c[2] - b[2]
    longest = max(e0 * e0 + e1 * e1 + e2 * e2, f0 * f0 + f1 * f1 + f2 * f2, g0 * g0 + g1 * g1 + g2 * g2)
    return n0, n1, n2, nn, not nn > DEGENERATE * longest


@njit(cache=True, error_model="numpy")
def segment_weights(p, a, b, c):
    """Barycentric weights of the closest point of p (3,) on the longest edge of the triangle
    (a, b, c) (ab, bc, ca: the first of equally long ones), clamped to the edge: the closest point
    on a triangle whose corners are collinear; a corner when they coincide."""
    ab = (b[0] - a[0]) ** 2 + (b[1] - a[1]) ** 2 + (b[2] - a[2]) ** 2
    bc = (c[0] - b[0]) ** 2 + (c[1] - b[1]) ** 2 + (c[2] - b[2]) ** 2
    ca = (a[0] - c[0]) ** 2 + (a[1] - c[1]) ** 2 + (a[2] - c[2]) ** 2
    if ab >= bc and ab >= ca:
        s, e, length = a, b, ab
    elif bc >= ca:
        s, e, length = b, c, bc
    else:
        s, e, length = c, a, ca
    t = 0.0
    if length > 0:
        t = _dot(e[0] - s[0], e[1] - s[1], e[2] - s[2], p[0] - s[0], p[1] - s[1], p[2] - s[2]) / length
        t = min(max(t, 0.0), 1.0)
    if ab >= bc and ab >= ca:
        return 1.0 - t, t, 0.0
    if bc >= ca:
        return 0.0, 1.0 - t, t
    return t, 0.0, 1.0 - t


@njit(cache=True, error_model="numpy")
def closest_weights(p, a, b, c):
    """Barycentric weights of the closest point of p (3,) on the triangle (a, b, c):
    :func:`triangle_weights`, or :func:`segment_weights` for a triangle without area."""
    if _face(a, b, c)[4]:
        return segment_weights(p, a, b, c)
    return triangle_weights(p, a, b, c)


@njit(cache=True, error_model="numpy")
def weights_of(p, a, b, c):
    """:func:`closest_weights` of points p on triangles (a, b, c) (k, 3 each): (k, 3)."""
    W = np.empty((p.shape[0], 3))
    for k in range(p.shape[0]):
        W[k, 0], W[k, 1], W[k, 2] = closest_weights(p[k], a[k], b[k], c[k])
    return W


@njit(cache=True, error_model="numpy")
def _nearest_face(p, C, m, tiny, W, diff, gap, fn, flat, out_n):
    """The closest of the m triangles C[:m] (M, 3, 3) to p (3,): returns (its index, signed distance)
    and writes the unit normal into out_n (3,); W, diff (M, 3), gap (M,), fn (M, 3), flat (M,):
    scratch.

    The sign is that of the pseudo-normal (the sum of the unit face normals of the triangles with
    an area as close as the closest, summed in order; if none has one, of every candidate with an
    area); the normal is the unit direction from the closest point to p, or the pseudo-normal's
    when the gap is below ``tiny`` (the z axis if no candidate has an area). The first of equally
    close triangles is the closest."""
    first = 0
    for j in range(m):
        a, b, c = C[j, 0], C[j, 1], C[j, 2]
        n0, n1, n2, nn, flat[j] = _face(a, b, c)
        w0, w1, w2 = segment_weights(p, a, b, c) if flat[j] else triangle_weights(p, a, b, c)
        W[j, 0], W[j, 1], W[j, 2] = w0, w1, w2
        for r in range(3):
            diff[j, r] = p[r] - (w0 * a[r] + w1 * b[r] + w2 * c[r])
        gap[j] = np.sqrt(diff[j, 0] * diff[j, 0] + diff[j, 1] * diff[j, 1] + diff[j, 2] * diff[j, 2])
        if not flat[j]:
            fn[j, 0], fn[j, 1], fn[j, 2] = n0 / nn, n1 / nn, n2 / nn
        if gap[j] < gap[first]:
            first = j
    g = gap[first]
    bound = g * (1.0 + 1e-9) + tiny
    s0 = s1 = s2 = 0.0
    faces = 0
    for j in range(m):
        if gap[j] <= bound and not flat[j]:
            s0, s1, s2 = s0 + fn[j, 0], s1 + fn[j, 1], s2 + fn[j, 2]
            faces += 1
    if faces == 0:      # no face with an area as close: the outward normal of the candidates that have one
        for j in range(m):
            if not flat[j]:
                s0, s1, s2 = s0 + fn[j, 0], s1 + fn[j, 1], s2 + fn[j, 2]
                faces += 1
    side = -1.0 if _dot(diff[first, 0], diff[first, 1], diff[first, 2], s0, s1, s2) < 0 else 1.0
    if g > tiny:
        scale = max(g, 1e-300)
        for r in range(3):
            out_n[r] = side * diff[first, r] / scale
    elif faces == 0:
        out_n[0], out_n[1], out_n[2] = 0.0, 0.0, 1.0
    else:
        scale = max(np.sqrt(s0 * s0 + s1 * s1 + s2 * s2), 1e-300)
        out_n[0], out_n[1], out_n[2] = s0 / scale, s1 / scale, s2 / scale
    return first, side * g


@njit(cache=True, error_model="numpy")
def surface_points(points, starts, order, tri, corners, tiny):
    """The nearest triangle of each point with candidates: the candidate pairs ``order`` (k,) grouped
    by point, point p's from ``starts[p]`` to ``starts[p + 1]`` (in their original order), their
    triangles ``tri`` (k,) of ``corners`` (T, 3, 3). Returns (points found, their pair, weights (., 3),
    signed distances, normals (., 3))."""
    n = starts.size - 1
    M = 1
    for q in range(n):
        M = max(M, starts[q + 1] - starts[q])
    C, W, diff, fn = np.empty((M, 3, 3)), np.empty((M, 3)), np.empty((M, 3)), np.empty((M, 3))
    gap, flat = np.empty(M), np.empty(M, np.bool_)
    found, pair = np.empty(n, np.int64), np.empty(n, np.int64)
    Wout, d, normal = np.empty((n, 3)), np.empty(n), np.empty((n, 3))
    k = 0
    for q in range(n):
        m = starts[q + 1] - starts[q]
        if m == 0:
            continue
        for j in range(m):
            C[j] = corners[tri[order[starts[q] + j]]]
        first, d[k] = _nearest_face(points[q], C, m, tiny, W, diff, gap, fn, flat, normal[k])
        Wout[k] = W[first]
        found[k], pair[k] = q, order[starts[q] + first]
        k += 1
    return found[:k], pair[:k], Wout[:k], d[:k], normal[:k]


@njit(cache=True, error_model="numpy")
def body_contacts(x, sv, owner, tris, tri_body, centroid, R, starts, rows, cand, u0, u1, n_fields, margin, dt,
                  tiny, nearest):
    """The contacts of vertices against the triangles of other bodies, from candidate pairs grouped
    by (other body, vertex row) (:func:`~skfem_affine.contact.grid.vertex_pairs`: ``starts``,
    ``rows`` of ``sv``, triangles ``cand``).

    Per group, the candidates whose centroid (``centroid`` (T, 3)) lies within the reach ``R[owner
    of the vertex, body]`` (B, B), the ``nearest`` nearest of them (equal distances by triangle
    index), give the closest point (``_nearest_face``); it is a contact when its signed gap is
    below ``margin + 2 h`` times the normal approach speed of the vertex relative to the closest
    point, the larger over the velocity fields u0 (and u1 when ``n_fields`` is 2), each (n, 3).
    Returns (vertex rows, their other body, triangles, weights (k, 3), signed gaps, normals (k, 3))
    of the contacts, ordered by (body, row)."""
    G = starts.size - 1
    C, W, diff, fn = np.empty((nearest, 3, 3)), np.empty((nearest, 3)), np.empty((nearest, 3)), np.empty((nearest, 3))
    gap, flat = np.empty(nearest), np.empty(nearest, np.bool_)
    best_d, best_t = np.empty(nearest), np.empty(nearest, np.int64)
    o_row, o_body, o_tri = np.empty(G, np.int64), np.empty(G, np.int64), np.empty(G, np.int64)
    o_W, o_d, o_n = np.empty((G, 3)), np.empty(G), np.empty((G, 3))
    k = 0
    for g in range(G):
        i = rows[starts[g]]
        p = x[sv[i]]
        body = tri_body[cand[starts[g]]]
        reach = R[owner[i], body]
        m = 0
        for j in range(starts[g], starts[g + 1]):
            t = cand[j]
            e0, e1, e2 = p[0] - centroid[t, 0], p[1] - centroid[t, 1], p[2] - centroid[t, 2]
            dist = np.sqrt(e0 * e0 + e1 * e1 + e2 * e2)
            if not dist <= reach:
                continue
            if m == nearest and not (dist < best_d[m - 1] or (dist == best_d[m - 1] and t < best_t[m - 1])):
                continue
            pos = m if m < nearest else nearest - 1                # insert in (distance, triangle) order
            while pos > 0 and (dist < best_d[pos - 1] or (dist == best_d[pos - 1] and t < best_t[pos - 1])):
                if pos < nearest:
                    best_d[pos], best_t[pos] = best_d[pos - 1], best_t[pos - 1]
                pos -= 1
            best_d[pos], best_t[pos] = dist, t
            m = min(m + 1, nearest)
        if m == 0:
            continue
        for j in range(m):
            for c in range(3):
                C[j, c] = x[tris[best_t[j], c]]
        first, d = _nearest_face(p, C, m, tiny, W, diff, gap, fn, flat, o_n[k])
        t = best_t[first]
        w0, w1, w2 = W[first, 0], W[first, 1], W[first, 2]
        approach = 0.0
        for f in range(n_fields):
            u = u0 if f == 0 else u1
            a, b, c = u[tris[t, 0]], u[tris[t, 1]], u[tris[t, 2]]
            v = u[sv[i]]
            s = _dot(v[0] - (w0 * a[0] + w1 * b[0] + w2 * c[0]), v[1] - (w0 * a[1] + w1 * b[1] + w2 * c[1]),
                     v[2] - (w0 * a[2] + w1 * b[2] + w2 * c[2]), o_n[k, 0], o_n[k, 1], o_n[k, 2])
            approach = max(approach, max(0.0, -s))
        if d < margin + 2.0 * dt * approach:
            o_row[k], o_body[k], o_tri[k], o_d[k] = i, body, t, d
            o_W[k, 0], o_W[k, 1], o_W[k, 2] = w0, w1, w2
            k += 1
    return o_row[:k], o_body[:k], o_tri[:k], o_W[:k], o_d[:k], o_n[:k]


@njit(cache=True, error_model="numpy")
def _clip01(a):
    return min(max(a, 0.0), 1.0)


@njit(cache=True, error_model="numpy")
def edge_contacts(ea, eb, edges, body, e0, e1, n0, n1, sharp, half, mid, reach, v, held, use_held, dt, margin,
                  cone_tolerance, crossed_tolerance):
    """The speculative contacts of the candidate pairs of surface edges (ea, eb) (k,) with the
    vertex velocities v (n, 3) (:meth:`~skfem_affine.contact.edges.EdgePairs.find`, whose rules
    and arithmetic this follows; ``reach`` (B, B) the broad phase's reach of a pair of bodies less
    the longest edge, ``held`` (n,) the vertices resting on another body when ``use_held``).
    Returns the mask (k,) of contacts and, for every pair, s, t, the normal (k, 3) and the gap."""
    k = ea.size
    hit = np.zeros(k, np.bool_)
    S, T, N, D = np.zeros(k), np.zeros(k), np.zeros((k, 3)), np.zeros(k)
    inside = 1e-6
    for j in range(k):
        a, b = ea[j], eb[j]
        m0, m1, m2 = mid[a, 0] - mid[b, 0], mid[a, 1] - mid[b, 1], mid[a, 2] - mid[b, 2]
        if not (np.sqrt(m0 * m0 + m1 * m1 + m2 * m2) <= reach[body[a], body[b]] + half[a] + half[b]):
            continue
        if not (sharp[a] and sharp[b]):
            continue
        # closest points a0 + s (a1 - a0), b0 + t (b1 - b0) of the two segments
        u0, u1, u2 = e1[a, 0] - e0[a, 0], e1[a, 1] - e0[a, 1], e1[a, 2] - e0[a, 2]
        w0, w1, w2 = e1[b, 0] - e0[b, 0], e1[b, 1] - e0[b, 1], e1[b, 2] - e0[b, 2]
        r0, r1, r2 = e0[a, 0] - e0[b, 0], e0[a, 1] - e0[b, 1], e0[a, 2] - e0[b, 2]
        uu, ww, uw = _dot(u0, u1, u2, u0, u1, u2), _dot(w0, w1, w2, w0, w1, w2), _dot(u0, u1, u2, w0, w1, w2)
        ur, wr = _dot(u0, u1, u2, r0, r1, r2), _dot(w0, w1, w2, r0, r1, r2)
        den = uu * ww - uw * uw
        parallel = den <= 1e-12 * uu * ww
        s = _clip01((uw * wr - ww * ur) / (1.0 if parallel else den))
        t = _clip01((uw * s + wr) / max(ww, 1e-300))
        s = _clip01((uw * t - ur) / max(uu, 1e-300))
        # the normal across both edges (defined when they touch), out of B (edge b) towards A
        c0, c1, c2 = u1 * w2 - u2 * w1, u2 * w0 - u0 * w2, u0 * w1 - u1 * w0
        cn = max(np.sqrt(c0 * c0 + c1 * c1 + c2 * c2), 1e-300)
        c0, c1, c2 = c0 / cn, c1 / cn, c2 / cn
        o0 = (n0[b, 0] + n1[b, 0]) - (n0[a, 0] + n1[a, 0])
        o1 = (n0[b, 1] + n1[b, 1]) - (n0[a, 1] + n1[a, 1])
        o2 = (n0[b, 2] + n1[b, 2]) - (n0[a, 2] + n1[a, 2])
        flip = -1.0 if _dot(c0, c1, c2, o0, o1, o2) < 0 else 1.0
        c0, c1, c2 = c0 * flip, c1 * flip, c2 * flip
        d = _dot(c0, c1, c2, (e0[a, 0] + s * u0) - (e0[b, 0] + t * w0), (e0[a, 1] + s * u1) - (e0[b, 1] + t * w1),
                 (e0[a, 2] + s * u2) - (e0[b, 2] + t * w2))
        # n within B's edge's normal cone and -n within A's; a crossed pair (d < 0) more strictly
        cone = min(_dot(c0, c1, c2, n0[b, 0], n0[b, 1], n0[b, 2]), _dot(c0, c1, c2, n1[b, 0], n1[b, 1], n1[b, 2]),
                   -_dot(c0, c1, c2, n0[a, 0], n0[a, 1], n0[a, 2]), -_dot(c0, c1, c2, n1[a, 0], n1[a, 1], n1[a, 2]))
        if (parallel or not (s > inside and s < 1 - inside and t > inside and t < 1 - inside and d > -margin)
                or not cone > (-crossed_tolerance if d < 0 else -cone_tolerance)):
            continue
        a0, a1, b0, b1 = edges[a, 0], edges[a, 1], edges[b, 0], edges[b, 1]
        rel = _dot(((1 - s) * v[a0, 0] + s * v[a1, 0]) - ((1 - t) * v[b0, 0] + t * v[b1, 0]),
                   ((1 - s) * v[a0, 1] + s * v[a1, 1]) - ((1 - t) * v[b0, 1] + t * v[b1, 1]),
                   ((1 - s) * v[a0, 2] + s * v[a1, 2]) - ((1 - t) * v[b0, 2] + t * v[b1, 2]), c0, c1, c2)
        grow = 2.0 * dt * max(0.0, -rel)
        if use_held and ((held[a0] and held[a1]) or (held[b0] and held[b1])) and grow < margin:
            continue
        if d < margin + grow:
            hit[j] = True
            S[j], T[j], D[j] = s, t, d
            N[j, 0], N[j, 1], N[j, 2] = c0, c1, c2
    return hit, S, T, N, D


@njit(cache=True, error_model="numpy")
def triangle_centroids(x, tris, tri_start):
    """Centroids (T, 3) of the triangles ``tris`` (T, 3) at x (n, 3) and, per body (its triangles
    from ``tri_start[b]`` on), the largest squared distance from a centroid to its corners (B,)."""
    T, B = tris.shape[0], tri_start.size
    centroid, reach = np.empty((T, 3)), np.full(B, -np.inf)
    b = 0
    for t in range(T):
        while b + 1 < B and t >= tri_start[b + 1]:
            b += 1
        i, j, k = tris[t, 0], tris[t, 1], tris[t, 2]
        for c in range(3):
            centroid[t, c] = (x[i, c] + x[j, c] + x[k, c]) / 3.0
        r = 0.0
        for q in (i, j, k):
            e0, e1, e2 = x[q, 0] - centroid[t, 0], x[q, 1] - centroid[t, 1], x[q, 2] - centroid[t, 2]
            r = max(r, e0 * e0 + e1 * e1 + e2 * e2)
        reach[b] = max(reach[b], r)
    return centroid, reach


@njit(cache=True, error_model="numpy")
def edge_shape(x, tris, edges, faces, cos_sharp):
    """The surface edges (E, 2) at x (n, 3) with their two faces (E, 2) of the triangles ``tris``:
    unit face normals n0, n1 (E, 3), sharp (E,) (n0 . n1 < ``cos_sharp``), outward n0 + n1, end
    points e0, e1, midpoints and half lengths (E,)."""
    T, E = tris.shape[0], edges.shape[0]
    fn = np.empty((T, 3))
    for t in range(T):
        a, b, c = x[tris[t, 0]], x[tris[t, 1]], x[tris[t, 2]]
        u0, u1, u2 = b[0] - a[0], b[1] - a[1], b[2] - a[2]
        w0, w1, w2 = c[0] - a[0], c[1] - a[1], c[2] - a[2]
        n0, n1, n2 = u1 * w2 - u2 * w1, u2 * w0 - u0 * w2, u0 * w1 - u1 * w0
        nn = max(np.sqrt(n0 * n0 + n1 * n1 + n2 * n2), 1e-300)
        fn[t, 0], fn[t, 1], fn[t, 2] = n0 / nn, n1 / nn, n2 / nn
    N0, N1, out, e0, e1, mid = np.empty((E, 3)), np.empty((E, 3)), np.empty((E, 3)), np.empty((E, 3)), \
        np.empty((E, 3)), np.empty((E, 3))
    sharp, half = np.empty(E, np.bool_), np.empty(E)
    for e in range(E):
        N0[e], N1[e] = fn[faces[e, 0]], fn[faces[e, 1]]
        sharp[e] = _dot(N0[e, 0], N0[e, 1], N0[e, 2], N1[e, 0], N1[e, 1], N1[e, 2]) < cos_sharp
        e0[e], e1[e] = x[edges[e, 0]], x[edges[e, 1]]
        for c in range(3):
            out[e, c] = N0[e, c] + N1[e, c]
            mid[e, c] = 0.5 * (e0[e, c] + e1[e, c])
        d0, d1, d2 = e1[e, 0] - e0[e, 0], e1[e, 1] - e0[e, 1], e1[e, 2] - e0[e, 2]
        half[e] = 0.5 * np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
    return N0, N1, sharp, out, e0, e1, mid, half
