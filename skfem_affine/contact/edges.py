r"""Edge-edge contacts between the boundary surfaces of different bodies (speculative).

A vertex-triangle test sees a vertex that crosses a surface, but not two edges that cross
while every vertex stays outside the other body: two bars crossing like an X, a thin plate's
rim cutting through another's. For such a pair of surface edges, of different bodies, the
closest points ``p_a = (1 - s) a0 + s a1`` and ``p_b = (1 - t) b0 + t b1`` at x_t, interior to
both edges, give a separating direction ``n = (p_a - p_b) / |p_a - p_b|``; the contact keeps
``n . (v(p_a) - v(p_b)) >= -d / h`` (d = |p_a - p_b|), so that the two edges may close their gap
within the step but not cross (the same speculative rule as a vertex against a triangle).

Which pairs. Only pairs whose closest points are strictly inside both edges (an endpoint is
a vertex, which the vertex-triangle test handles), not parallel, seen from outside both
bodies (``n`` points out of B at B's edge and into A at A's edge, the outward direction of an
edge being the sum of its two faces' normals: a pair already crossed is left to the vertex
contacts' push-out), and with at least one *sharp* edge
(its two faces turn by more than :data:`SHARP_ANGLE`): where both surfaces are flat around the
edges, the faces' own vertex-triangle contacts already hold them apart, and stacked boxes
would otherwise get one contact per crossing pair of face edges.
"""
import numpy as np
from scipy.spatial import cKDTree

# An edge is sharp when the normals of its two faces differ by more than this angle (radians).
SHARP_ANGLE = np.deg2rad(20.0)


def surface_edges(tris):
    """Unique edges (E, 2) of outward-oriented triangles (T, 3) and their two faces (E, 2).

    An edge of a closed manifold surface has exactly two faces; an edge with one face (an
    open surface) repeats it, and is then never sharp."""
    e = np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]])
    face = np.tile(np.arange(len(tris)), 3)
    key = np.sort(e, axis=1)
    edges, inverse = np.unique(key, axis=0, return_inverse=True)
    inverse = inverse.ravel()
    order = np.argsort(inverse, kind="stable")
    start = np.searchsorted(inverse[order], np.arange(len(edges)))
    count = np.bincount(inverse, minlength=len(edges))
    first = face[order[start]]
    second = face[order[np.minimum(start + 1, len(order) - 1)]]
    second = np.where(count >= 2, second, first)
    return edges, np.column_stack([first, second])


def segment_closest_points(a0, a1, b0, b1):
    """Parameters s, t (k,) of the closest points of segments a0-a1 and b0-b1 (k, 3 each), and
    whether the segments are parallel (k,) (their closest points are then not unique)."""
    u, w, r = a1 - a0, b1 - b0, a0 - b0
    uu, ww, uw = (np.einsum("ij,ij->i", p, q) for p, q in ((u, u), (w, w), (u, w)))
    ur, wr = np.einsum("ij,ij->i", u, r), np.einsum("ij,ij->i", w, r)
    den = uu * ww - uw * uw
    parallel = den <= 1e-12 * uu * ww
    safe = np.where(parallel, 1.0, den)
    s = np.clip((uw * wr - ww * ur) / safe, 0.0, 1.0)
    t = np.clip((uw * s + wr) / np.maximum(ww, 1e-300), 0.0, 1.0)
    s = np.clip((uw * t - ur) / np.maximum(uu, 1e-300), 0.0, 1.0)
    return s, t, parallel


class EdgePairs:
    """Surface edges of every body and their speculative edge-edge contacts with other bodies.

    Parameters
    ----------
    tris : (T, 3) outward boundary triangles (global vertex ids)
    tri_body : (T,) the body of each triangle
    """

    def __init__(self, tris, tri_body):
        self.tris = tris
        self.edges, self.faces = surface_edges(tris)
        self.edge_body = tri_body[self.faces[:, 0]]
        self.cos_sharp = np.cos(SHARP_ANGLE)

    def find(self, x, v, dt, margin, speed_bound):
        """Edge-edge contacts at x (n, 3) with velocities v (n, 3).

        ``speed_bound`` (n_bodies,) bounds each body's vertex speeds relative to its mean, and
        the means are taken from v, so that ``margin + 2 h`` times a bound on any pair's
        relative speed is the reach of the broad phase.

        Returns ``(edge_a, edge_b, s, t, normal, distance)`` (edge a is the one whose closest
        point the normal points to) or None."""
        edges, body = self.edges, self.edge_body
        p = x[self.tris]
        fn = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
        fn /= np.maximum(np.linalg.norm(fn, axis=1, keepdims=True), 1e-300)
        n0, n1 = fn[self.faces[:, 0]], fn[self.faces[:, 1]]
        sharp = np.einsum("ij,ij->i", n0, n1) < self.cos_sharp
        if not sharp.any():
            return None
        outward = n0 + n1
        e0, e1 = x[edges[:, 0]], x[edges[:, 1]]
        mid = 0.5 * (e0 + e1)
        half = 0.5 * np.linalg.norm(e1 - e0, axis=1)
        nb = int(body.max()) + 1
        count = np.maximum(np.bincount(body, minlength=nb), 1)[:, None]
        vm = 0.5 * (v[edges[:, 0]] + v[edges[:, 1]])
        mean_v = np.stack([np.bincount(body, vm[:, k], nb) for k in range(3)], axis=1) / count
        pairs = []
        for b in range(nb):
            mine = np.flatnonzero(body == b)
            if not mine.size:
                continue
            rel = np.linalg.norm(mean_v - mean_v[b], axis=1) + speed_bound + speed_bound[b]
            reach = margin + 2.0 * dt * rel                                   # per other body
            # pairs with at least one sharp edge: (sharp other, any of b) and (flat other, sharp of b)
            for other_mask, mine_sel in ((sharp, mine), (~sharp, mine[sharp[mine]])):
                others = np.flatnonzero(other_mask & (body > b))               # each body pair once
                if not others.size or not mine_sel.size:
                    continue
                radius = reach[body[others]] + half[others] + half[mine_sel].max()
                hits = cKDTree(mid[mine_sel]).query_ball_point(mid[others], radius)
                lens = np.fromiter((len(hh) for hh in hits), int, len(hits))
                if lens.sum():
                    pairs.append(np.column_stack([np.repeat(others, lens),
                                                  mine_sel[np.concatenate(hits).astype(int)]]))
        if not pairs:
            return None
        ea, eb = np.concatenate(pairs).T
        # edges sharing a vertex cannot belong to different bodies; no check needed
        a0, a1, b0, b1 = e0[ea], e1[ea], e0[eb], e1[eb]
        s, t, parallel = segment_closest_points(a0, a1, b0, b1)
        pa = a0 + s[:, None] * (a1 - a0)
        pb = b0 + t[:, None] * (b1 - b0)
        diff = pa - pb
        d = np.linalg.norm(diff, axis=1)
        n = diff / np.maximum(d, 1e-300)[:, None]
        inside = 1e-6
        ok = (~parallel & (s > inside) & (s < 1 - inside) & (t > inside) & (t < 1 - inside) & (d > 0)
              & (np.einsum("ij,ij->i", n, outward[eb]) > 0) & (np.einsum("ij,ij->i", n, outward[ea]) < 0))
        va = (1 - s)[:, None] * v[edges[ea, 0]] + s[:, None] * v[edges[ea, 1]]
        vb = (1 - t)[:, None] * v[edges[eb, 0]] + t[:, None] * v[edges[eb, 1]]
        approach = np.maximum(0.0, -np.einsum("ij,ij->i", va - vb, n))
        hit = np.flatnonzero(ok & (d < margin + 2.0 * dt * approach))
        if not hit.size:
            return None
        return ea[hit], eb[hit], s[hit], t[hit], n[hit], d[hit]
