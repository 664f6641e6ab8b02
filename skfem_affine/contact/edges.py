r"""Edge-edge contacts between the boundary surfaces of different bodies (speculative).

A vertex-triangle test sees a vertex that crosses a surface, but not two edges that cross
while every vertex stays outside the other body: two bars crossing like an X, a thin plate's
rim cutting through another's. For such a pair of surface edges a0-a1 (body A) and b0-b1 (body
B), with closest points ``p_a = (1 - s) a0 + s a1`` and ``p_b = (1 - t) b0 + t b1`` at x_t
interior to both edges, the separating direction is across both edges,
``n = (a1 - a0) x (b1 - b0) / |...|``, turned to point out of B towards A (an edge's outward
direction is the sum of its two faces' normals); it stays defined when the edges touch, where
``p_a - p_b`` vanishes. The signed gap is ``d = n . (p_a - p_b)`` and the contact keeps
``n . (v(p_a) - v(p_b)) >= -max(d, 0) / h``: the edges may close their gap within the step but
not cross (the speculative rule of a vertex against a triangle), and a pair that has crossed
(d < 0) may not cross further and is pushed back like a penetration (its gap is not counted in
the recorded penetration, a depth of vertices).

Which pairs. Only pairs whose closest points are strictly inside both edges (an endpoint is
a vertex, which the vertex-triangle test handles), not parallel, with ``n`` inside the normal
cone of B's edge (making an angle below 90 degrees, up to :data:`CONE_TOLERANCE`, with both of its
faces' normals) and ``-n`` inside A's (the edges face each other), for a crossed pair (d < 0)
within :data:`CROSSED_TOLERANCE` (each closest point is inside the other edge's wedge: the
edges have crossed, they do not merely lie side by side), gap below
``margin + 2 h`` times the approach speed and above ``-margin``, and both edges *sharp* (their
two faces turn by more than :data:`SHARP_ANGLE`). An edge inside a flat region of a surface
cannot be crossed alone: the region's vertex contacts hold it, and an edge crossing the region
without a vertex entering it must cross the region's border, a sharp edge. The rule keeps
stacked boxes from getting one contact per crossing pair of face edges. A slow pair (it cannot
close ``margin`` within two steps) one of whose edges rests on the other body at both ends
(vertex contacts within ``margin``) is held by those two vertex contacts and skipped too: resting
stacks then get no edge contacts where their vertex contacts suffice.
"""
import numpy as np

from skfem_affine.contact import grid, narrow

# An edge is sharp when the normals of its two faces differ by more than this angle (radians).
SHARP_ANGLE = np.deg2rad(20.0)
# How far (cosine) a face normal of either edge may turn away from the pair's normal.
CONE_TOLERANCE = 0.2
CROSSED_TOLERANCE = 0.05


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


class EdgePairs:
    """Surface edges of every body and their speculative edge-edge contacts with other bodies.

    Parameters
    ----------
    tris : (T, 3) outward boundary triangles (global vertex ids)
    tri_body : (T,) the body of each triangle
    """

    def __init__(self, tris, tri_body):
        self.tris = tris
        edges, faces = surface_edges(tris)
        body = tri_body[faces[:, 0]]
        order = np.argsort(body, kind="stable")                  # each body's edges contiguous
        self.edges, self.faces, self.edge_body = edges[order], faces[order], body[order]
        self.n_bodies = int(body.max()) + 1
        self.starts = np.searchsorted(self.edge_body, np.arange(self.n_bodies))
        self.cos_sharp = np.cos(SHARP_ANGLE)

    def shape(self, x):
        """The edges at x (n, 3): a dict of their face normals ``n0``, ``n1``, ``sharp`` (E,) mask,
        ``outward`` directions, end points ``e0``, ``e1``, midpoints ``mid`` and half lengths ``half``."""
        g = narrow.edge_shape(x, self.tris, self.edges, self.faces, self.cos_sharp)
        return dict(zip(("n0", "n1", "sharp", "outward", "e0", "e1", "mid", "half"), g))

    def frame(self, x, v, dt, margin, speed_bound, shape=None):
        """The edges at x (n, 3) with velocities v (n, 3): :meth:`shape` (or ``shape``, that of x if
        known) and the broad phase's ``grow`` (B, B): ``margin + 2 h`` times a bound on the relative
        speed of each pair of bodies plus the longest edge.

        ``speed_bound`` (n_bodies,) bounds each body's vertex speeds relative to its mean, and
        the means are taken from v."""
        g = dict(self.shape(x) if shape is None else shape)
        edges, body = self.edges, self.edge_body
        count = np.maximum(np.diff(np.append(self.starts, len(body))), 1)[:, None]
        vm = 0.5 * (v[edges[:, 0]] + v[edges[:, 1]])
        mean_v = np.add.reduceat(vm, self.starts) / count
        # reach of each pair of bodies: margin + 2 h |relative speed| bound
        rel = np.linalg.norm(mean_v[:, None] - mean_v[None], axis=2) + speed_bound[:, None] + speed_bound[None]
        g["grow"] = margin + 2.0 * dt * rel + 2.0 * g["half"].max()
        return g

    def pairs(self, g, grow):
        """Every pair (edge a, edge b) (k,) each of sharp surface edges of bodies a < b whose
        midpoints lie within ``grow`` (B, B) of each other, edges as in :meth:`frame`'s ``g``
        (the compiled grid search of :func:`~skfem_affine.contact.grid.vertex_pairs`, midpoints against midpoints)."""
        sharp = np.flatnonzero(g["sharp"])
        body, nb = self.edge_body[sharp], self.n_bodies
        reach = np.where(np.triu(np.ones((nb, nb), dtype=bool), 1), grow * (1.0 + 1e-9), -np.inf)
        empty = np.zeros(0, dtype=np.int64)
        mid = np.ascontiguousarray(g["mid"][sharp])
        a, b, _, k, _ = grid.vertex_pairs(mid, body, mid, np.searchsorted(body, np.arange(nb + 1)), reach,
                                            empty, empty, empty)
        return sharp[a[:k]], sharp[b[:k]]

    def find(self, x, v, dt, margin, speed_bound, held=None, pairs=None, g=None):
        """Edge-edge contacts at x (n, 3) with velocities v (n, 3).

        ``speed_bound`` (n_bodies,) bounds each body's vertex speeds relative to its mean, and
        the means are taken from v, so that ``margin + 2 h`` times a bound on any pair's
        relative speed is the reach of the broad phase.

        ``held`` (n,) marks vertices touching another body (a vertex contact within ``margin``):
        a slow pair with an edge held at both ends is skipped (see the module docstring).

        ``pairs`` (edge a, edge b), optional: candidate pairs (bodies a < b) holding every pair
        of sharp edges within the broad phase's reach (else :meth:`pairs` searches them); ``g``:
        :meth:`frame` at (x, v) if known.

        Returns ``(edge_a, edge_b, s, t, normal, distance)`` (edge a is the one whose closest
        point the normal points to) or None."""
        g = self.frame(x, v, dt, margin, speed_bound) if g is None else g
        if not g["sharp"].any():
            return None
        ea, eb = self.pairs(g, g["grow"]) if pairs is None else pairs
        hit, s, t, n, d = narrow.edge_contacts(
            ea, eb, self.edges, self.edge_body, g["e0"], g["e1"], g["n0"], g["n1"], g["sharp"], g["half"], g["mid"],
            g["grow"] - 2.0 * g["half"].max(), v, np.zeros(1, dtype=bool) if held is None else held, held is not None,
            float(dt), float(margin), CONE_TOLERANCE, CROSSED_TOLERANCE)
        hit = np.flatnonzero(hit)
        if not hit.size:
            return None
        return ea[hit], eb[hit], s[hit], t[hit], n[hit], d[hit]
