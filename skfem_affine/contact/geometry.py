"""Contact detection: boundary surfaces, closest points, and the contacts of one frame (Algorithm 1).

Every free vertex (interior ones too) is tested against the static colliders (signed distance
queries, :mod:`skfem_affine.contact.colliders`) and against the boundary triangles of the *other*
bodies (the nearest triangle centroids within reach as broad phase, exact point-triangle
distance as narrow phase), and sharp surface edges of different bodies against each other
(:mod:`skfem_affine.contact.edges`); self-contact is not detected. The pairs between bodies
come from a candidate list, searched within their reach plus a skin and kept while the bodies
barely move (:class:`Detector`). A contact i has a signed gap d_i (negative: penetration), a
normal n_i pointing from the obstacle towards the vertex (or edge), and two tangents. A pair
becomes a contact when its gap is below ``margin + 2 h`` times its normal approach speed
(speculative contact).
"""
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp

from skfem_affine.contact import grid, narrow
from skfem_affine.contact.edges import EdgePairs

# Broad phase: candidate triangles per vertex (nearest centroids within reach).
NEAREST_TRIANGLES = 8


def boundary_surface(system):
    """Outward-oriented boundary triangles (T, 3) of every body (global vertex ids) and their bodies (T,)."""
    tris, owner = [], []
    for i, (body, off) in enumerate(zip(system.bodies, system.vertex_offsets)):
        mesh = body.mesh
        bf = mesh.boundary_facets()
        f = mesh.facets[:, bf].T.copy()                       # (nb, 3)
        tet = mesh.t[:, mesh.f2t[0, bf]].T                    # the element behind each facet
        opposite = tet.sum(axis=1) - f.sum(axis=1)
        p = mesh.p.T
        nrm = np.cross(p[f[:, 1]] - p[f[:, 0]], p[f[:, 2]] - p[f[:, 0]])
        inward = np.einsum("ij,ij->i", nrm, p[opposite] - p[f[:, 0]]) > 0
        f[inward] = f[inward][:, [0, 2, 1]]
        tris.append(f + off)
        owner.append(np.full(len(f), i))
    return np.concatenate(tris), np.concatenate(owner)


def closest_points_on_triangles(p, a, b, c):
    """Closest points of points p (k, 3) on triangles (a, b, c) (k, 3 each), as barycentric weights (k, 3).

    The Voronoi-region test of Ericson (Real-Time Collision Detection, 5.1.5)
    (:func:`~skfem_affine.contact.narrow.triangle_weights`); on a triangle without area (collinear
    or equal corners), the closest point on its longest edge
    (:func:`~skfem_affine.contact.narrow.closest_weights`).
    """
    p, a, b, c = (np.ascontiguousarray(q, dtype=float) for q in (p, a, b, c))
    if p.ndim != 2 or p.shape[1] != 3 or any(q.shape != p.shape for q in (a, b, c)):
        raise ValueError(f"p, a, b, c must each have shape (k, 3), got {[q.shape for q in (p, a, b, c)]}")
    return narrow.weights_of(p, a, b, c)


def tangent_basis(n):
    """Two unit tangents (k, 3) each completing the unit normals n (k, 3) to a right-handed frame."""
    axis = np.zeros_like(n)
    axis[np.arange(len(n)), np.argmin(np.abs(n), axis=1)] = 1.0
    t1 = np.cross(n, axis)
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    return t1, np.cross(n, t1)


def closest_surface_points(points, rows, tri, corners, tiny):
    """Signed distance of each point to a closed triangle surface, from candidate pairs.

    ``rows[j]`` is the point and ``tri[j]`` the triangle of candidate pair j; ``corners``
    (T, 3, 3) are the outward-oriented triangles. For every point with candidates, the
    closest triangle gives the gap, barycentric weights and direction; the sign comes from
    the pseudo-normal (the sum of the face normals of all equally close triangles, which
    share the closest edge or vertex), so that a point beside an edge or a corner is not
    taken for one inside. The normal points from the surface to the point (the face
    pseudo-normal when the gap is below ``tiny``). A triangle without area (squashed to a
    segment or a point) adds nothing to the pseudo-normal; when no equally close triangle has
    an area, the sign comes from the normals of the point's candidate triangles that have one,
    else the point is outside (:mod:`~skfem_affine.contact.narrow`). No gap or normal is NaN.

    Returns ``(points_found, triangle, weights (k, 3), signed distance (k,), normal (k, 3))``.
    """
    rows, tri = np.asarray(rows, dtype=np.int64), np.asarray(tri, dtype=np.int64)
    for name, index, size in (("rows", rows, len(points)), ("tri", tri, len(corners))):
        if index.shape != (len(rows),) or (index.size and not 0 <= index.min() <= index.max() < size):
            raise ValueError(f"{name} must be {len(rows)} indices in [0, {size}), got shape {index.shape}"
                             f"{f' and values {index.min()}..{index.max()}' if index.size else ''}")
    order = np.argsort(rows, kind="stable")
    starts = np.searchsorted(rows[order], np.arange(len(points) + 1))
    found, pair, W, d, normal = narrow.surface_points(np.ascontiguousarray(points, dtype=float), starts, order, tri,
                                                      np.ascontiguousarray(corners, dtype=float), float(tiny))
    return found, tri[pair], W, d, normal


@dataclass
class ContactSet:
    """The contacts of one frame (k of them), found at x_t."""

    vertex: np.ndarray    # (k,) the vertex a of each contact
    others: np.ndarray    # (k, 3) triangle vertices of the other body (collider contacts: a, weight 0)
    weights: np.ndarray   # (k, 3) barycentric weights of the closest point (zeros for colliders)
    normal: np.ndarray    # (k, 3) unit normal, pointing from the obstacle towards the vertex
    distance: np.ndarray  # (k,) signed gap (negative: penetration)
    key: np.ndarray       # (k,) identity: vertex * n_kinds + (collider index | n_colliders + other body),
    #                       or, for an edge-edge contact, n_vertices * n_kinds + edge_a * n_edges + edge_b
    J: sp.csr_matrix = None  # (3k, n_free) rows n, t1, t2 per contact
    own: np.ndarray = None   # (k,) weight of ``vertex`` in the contact point (None: all 1); an edge-edge
    #                          contact is the point (1 - s) a0 + s a1: vertex a0, own 1 - s, others
    #                          (a1, b0, b1) with weights (-s, 1 - t, t)
    impact: np.ndarray = None  # (k,) bool: set by the contact solver, contacts that start an impact
    near: np.ndarray = None    # sorted vertices that reach a collider within ``Detector.lookahead`` more frames
    #                            at their approach speed, with the contacts' own vertices (None: not predicted)
    near_unknowns: np.ndarray = None  # sorted free unknowns of ``near`` (set with J; columns of J)
    _frames: np.ndarray = field(default=None, init=False, repr=False, compare=False)

    @property
    def size(self):
        return self.vertex.size

    def frames(self):
        """(k, 3, 3) rows n, t1, t2 of each contact (computed once per contact set; read only)."""
        if self._frames is None:
            t1, t2 = tangent_basis(self.normal)
            self._frames = np.stack([self.normal, t1, t2], axis=1)
            self._frames.flags.writeable = False
        return self._frames


def concat(sets):
    """One ContactSet from several."""
    fields = ("vertex", "others", "weights", "normal", "distance", "key")
    out = ContactSet(*[np.concatenate([getattr(s, f) for s in sets]) for f in fields])
    if any(s.own is not None for s in sets):
        out.own = np.concatenate([np.ones(s.size) if s.own is None else s.own for s in sets])
    return out



def _uniform(w, v, rows):
    """Whether the velocity changes w - v (n, 3 each) of the vertices ``rows`` are one vector up to
    the rounding of velocities of their magnitude (``v + h a - v`` for a uniform ``a`` differs from
    ``h a`` by a few ulps)."""
    spread, scale = grid.change_spread(w, v, rows)
    return bool(np.all(spread <= 16.0 * np.finfo(float).eps * scale))


class Detector:
    """Finds the contacts of a system's vertices and edges against colliders and other bodies.

    Parameters
    ----------
    system : ElasticSystem
    colliders : list of colliders (checked)
    margin : float or None
        Speculative contact distance; None: a fifth of the mean surface edge length.
    body_contact : bool
        Detect contact between different bodies.
    edge_contact : bool
        Detect edge-edge contacts between different bodies too.
    skin : float or None
        The pairs between bodies are searched within their reach plus this distance and kept
        (a candidate list) until a vertex has moved by half of it since, less any growth of the
        reach: resting bodies skip the broad phase, and the contacts are exactly those of a
        search from scratch (0: search every frame). None: a quarter of the mean surface edge.
        The list is a cache, rebuilt when needed (it is not part of a checkpoint).
    """

    def __init__(self, system, colliders, margin=None, body_contact=True, edge_contact=True, skin=None):
        self.colliders = colliders
        self.tris, self.tri_body = boundary_surface(system)
        self.surface = np.unique(self.tris)
        # vertices tested against the other bodies' triangles: the surface and every free vertex
        self.body_vertices = np.union1d(self.surface, np.flatnonzero(~system.fixed))
        # every vertex that can move is tested against the colliders, interior ones too: an impact
        # faster than the material's wave speed inverts elements and would carry interior vertices
        # through a collider that the surface vertices never cross
        self.collider_vertices = np.flatnonzero(~system.fixed)
        self.body_of_vertex = system.body_of_vertex
        self.n_kinds = len(self.colliders) + len(system.bodies)
        p0 = system.p0
        edges = np.concatenate([p0[self.tris[:, i]] - p0[self.tris[:, (i + 1) % 3]] for i in range(3)])
        self.mean_edge = float(np.linalg.norm(edges, axis=1).mean())
        self.margin = 0.2 * self.mean_edge if margin is None else float(margin)
        self.body_pairs = bool(body_contact) and len(system.bodies) > 1
        self.n_vertices = system.n
        self.edge_pairs = EdgePairs(self.tris, self.tri_body) if self.body_pairs and edge_contact else None
        self.tri_start = np.searchsorted(self.tri_body, np.arange(len(system.bodies)))  # tris are body by body
        self.skin = 0.25 * self.mean_edge if skin is None else float(skin)
        if not np.isfinite(self.skin) or self.skin < 0.0:
            raise ValueError(f"skin must be a finite distance >= 0, got {skin!r}")
        self._list = None   # the candidate list (vertex pairs) and where the vertices were at its build
        self._buffers = [np.zeros(0, dtype=np.int64)] * 3  # the memory of its vertex pairs
        # frames ahead of :attr:`ContactSet.near`, a predicted superset of the touched vertices for the Schur
        # complement's analysis to serve later frames (None: not predicted; on the landing octopus it
        # cost more than it saved: docs/contact.md)
        self._lookahead = None
        self.builds = 0     # how many times the list was built

    @property
    def lookahead(self):
        """Frames ahead that :attr:`ContactSet.near` predicts (a number >= 0), or None: no prediction."""
        return self._lookahead

    @lookahead.setter
    def lookahead(self, value):
        if value is not None and not (isinstance(value, (int, float, np.integer, np.floating))
                                      and not isinstance(value, bool) and np.isfinite(value) and value >= 0):
            raise ValueError(f"lookahead must be a number of frames >= 0 or None, got {value!r}")
        self._lookahead = None if value is None else float(value)

    def body_contacts(self, cs, edges=True):
        """Mask (k,) of the contacts of ``cs`` between two bodies (not with a collider), with or
        without the edge-edge ones."""
        base = self.n_vertices * self.n_kinds
        vertex = (cs.key < base) & (cs.key % self.n_kinds >= len(self.colliders))
        return vertex | (cs.key >= base) if edges else vertex

    def find(self, x, v, dt, w=None):
        """All contacts at positions x (n, 3) with vertex velocities v (n, 3), or None.

        A vertex (or a pair of edges) is a contact when its gap is below ``margin + 2 h`` times
        its normal approach speed (towards a collider, or relative to the other body). ``w``
        (n, 3), optional: the velocity the step's own acceleration leads to, v + h a; the
        approach speed is then the larger of the two, so that a vertex at rest that gravity or a
        force takes to a collider within the step is found."""
        sets, near = [], []
        cv = self.collider_vertices
        fields = [v] if w is None else [v, w]
        for ci, col in enumerate(self.colliders):
            d, n = col.query(x[cv])
            approach = np.maximum.reduce([np.maximum(0.0, -np.einsum("ij,ij->i", u[cv], n)) for u in fields])
            if self.lookahead is not None:
                near.append(cv[d < self.margin + (2.0 + self.lookahead) * dt * approach])
            hit = np.flatnonzero(d < self.margin + 2.0 * dt * approach)
            if hit.size:
                vtx = cv[hit]
                sets.append(ContactSet(vtx, np.repeat(vtx[:, None], 3, axis=1), np.zeros((hit.size, 3)), n[hit],
                                       d[hit], vtx * self.n_kinds + ci))
        if self.body_pairs:
            sv = self.body_vertices
            if w is not None and _uniform(w, v, sv):
                fields = [v]  # a uniform acceleration (gravity alone) leaves relative approach speeds as they are
            speeds = [self._speeds(u) for u in fields]
            reach = self._reach(x, speeds, dt)
            shape = None if self.edge_pairs is None else self.edge_pairs.shape(x)
            edges = [] if shape is None else [self.edge_pairs.frame(x, u, dt, self.margin, s[2], shape)
                                              for u, s in zip(fields, speeds)]
            vertex_pairs, edge_pairs = self._candidates(x, reach, edges)
            vertex_sets = self._body_contacts(x, fields, dt, speeds, vertex_pairs, reach)
            held = np.zeros(len(x), dtype=bool)
            for cs in vertex_sets:
                held[cs.vertex[np.abs(cs.distance) < self.margin]] = True
            sets += vertex_sets
            found = None if edge_pairs is None else self._edge_contacts(x, fields, dt, held,
                                                                        [s[2] for s in speeds], edges, edge_pairs)
            if found is not None:
                sets.append(found)
        if not sets:
            return None
        out = concat(sets)
        if self.lookahead is not None:
            out.near = np.unique(np.concatenate(near + [out.vertex, out.others.ravel()]))
        return out

    def max_penetration(self, x, bodies=True):
        """Largest penetration depth (m, >= 0) of a vertex into a collider or (``bodies``) into
        another body at x."""
        depth = 0.0
        for col in self.colliders:
            d, _ = col.query(x[self.collider_vertices])
            depth = max(depth, float(-d.min(initial=0.0)))
        if bodies and self.body_pairs:
            zero = np.zeros_like(x)
            speeds = [self._speeds(zero)]
            for cs in self._body_contacts(x, [zero], 0.0, speeds):
                depth = max(depth, float(-cs.distance.min(initial=0.0)))
        return depth

    def _speeds(self, u):
        """Mean velocity (B, 3) of each body's vertices :attr:`body_vertices` in u (n, 3), each
        vertex's speed relative to its body's mean, and its body's largest such speed (B,)."""
        sv = self.body_vertices
        return grid.body_speeds(u, sv, self.body_of_vertex[sv], len(self.tri_start))

    def _edge_contacts(self, x, fields, dt, held, max_spreads, frames, pairs):
        """Speculative edge-edge contacts between sharp surface edges of different bodies
        (:mod:`~skfem_affine.contact.edges`), within reach of any of the velocity ``fields``
        (their edges' ``frames``), from the candidate ``pairs``."""
        ep = self.edge_pairs
        found = [f for f in (ep.find(x, u, dt, self.margin, spread, held, pairs, g)
                             for u, spread, g in zip(fields, max_spreads, frames)) if f is not None]
        if not found:
            return None
        ea, eb, s, t, normal, d = (np.concatenate(parts) for parts in zip(*found))
        # ordered by pair, a pair found with both velocities counting once
        _, first = np.unique(ea * len(ep.edges) + eb, return_index=True)
        ea, eb, s, t, normal, d = (a[first] for a in (ea, eb, s, t, normal, d))
        a0, a1 = ep.edges[ea, 0], ep.edges[ea, 1]
        others = np.column_stack([a1, ep.edges[eb]])
        weights = np.column_stack([-s, 1.0 - t, t])
        key = self.n_vertices * self.n_kinds + ea * len(ep.edges) + eb
        return ContactSet(a0, others, weights, normal, d, key, own=1.0 - s)

    def _reach(self, x, speeds, dt):
        """Broad-phase reach (B, B) of each pair of bodies (vertices of a, triangle centroids of b):
        ``margin + 2 h`` times a bound on their relative speed (the largest over the velocity
        fields ``speeds``) plus b's largest centroid-to-corner distance; -inf on the diagonal.
        Also the triangles' centroids (T, 3) at x."""
        if not np.all(np.isfinite(x[self.body_vertices])):
            raise ValueError(f"positions x contain non-finite (NaN/inf) coordinates at "
                             f"{int((~np.isfinite(x[self.body_vertices])).any(axis=1).sum())} vertices")
        centroid, reach = narrow.triangle_centroids(x, self.tris, self.tri_start)
        # |v_i - v_j| <= |v_i - vbar_a| + |vbar_a - vbar_b| + max_j |v_j - vbar_b| for i in a, j in b
        bound = np.maximum.reduce([ms[:, None] + np.linalg.norm(mv[:, None] - mv[None], axis=2) + ms[None]
                                   for mv, _, ms in speeds])
        R = self.margin + 2.0 * dt * bound + np.sqrt(reach)[None]
        np.fill_diagonal(R, -np.inf)
        return R, centroid

    def _vertex_pairs(self, x, R, centroid, buffers=None):
        """Every pair (vertex row of :attr:`body_vertices`, triangle) of different bodies whose
        distance to the triangle's ``centroid`` (T, 3) may be within ``R`` (B, B), grouped by
        (triangle's body, row): ``(rows, triangles, group starts)`` (:func:`~skfem_affine.contact.grid.vertex_pairs`),
        written into the three int64 ``buffers`` (a list, updated when they grow) if given: a list
        rebuilt every frame then reuses its memory instead of touching fresh pages."""
        empty = np.zeros(0, dtype=np.int64)
        rows, tris, starts, k, g = grid.vertex_pairs(
            x[self.body_vertices], self.body_of_vertex[self.body_vertices], centroid,
            np.append(self.tri_start, len(self.tris)), R * (1.0 + 1e-9) + 1e-9 * self.mean_edge,
            *(buffers if buffers is not None else (empty, empty, empty)))
        if buffers is not None:
            buffers[:] = rows, tris, starts
        return rows[:k], tris[:k], starts[:g]

    def _edge_pairs(self, frames, skin):
        """Candidate edge pairs for the edges' ``frames`` (one per velocity field) with their
        reach grown by ``skin``, or None (no sharp edge)."""
        if not frames or not frames[0]["sharp"].any():
            return None
        return self.edge_pairs.pairs(frames[0], np.maximum.reduce([g["grow"] for g in frames]) + skin)

    def _candidates(self, x, reach, frames):
        """The vertex-triangle pairs (:meth:`_vertex_pairs`) and edge pairs (or None) to search at
        x for the vertices' ``reach`` (:meth:`_reach`) and the edges' ``frames``: from scratch, or (with a skin)
        from the candidate list while it covers them: no vertex has moved since its build by more
        than half of what the reach has left of the skin, and no edge has turned sharp."""
        R, centroid = reach
        if self.skin <= 0.0:
            return self._vertex_pairs(x, R, centroid), self._edge_pairs(frames, 0.0)
        lst = self._list
        if lst is not None:
            moved = 2.0 * grid.largest_move(x, self.body_vertices, lst["x"])
            if (np.all(R + moved <= lst["R"]) and all(np.all(g["grow"] + moved <= lst["grow"]) for g in frames)
                    and not (frames and np.any(frames[0]["sharp"] & ~lst["sharp"]))):
                return lst["vertex"], lst["edge"]
        lst = {"x": x[self.body_vertices], "R": R + self.skin,
               "vertex": self._vertex_pairs(x, R + self.skin, centroid, self._buffers),
               "edge": self._edge_pairs(frames, self.skin)}
        if frames:
            lst["grow"] = np.maximum.reduce([g["grow"] for g in frames]) + self.skin
            lst["sharp"] = frames[0]["sharp"]
        self._list = lst
        self.builds += 1
        return lst["vertex"], lst["edge"]

    def _body_contacts(self, x, fields, dt, speeds, pairs=None, reach=None):
        """The vertices :attr:`body_vertices` (surface and free interior) of every body against the
        boundary triangles of each other body, with the vertex velocities of each of ``fields`` (a
        list of (n, 3)) and their ``speeds`` (:meth:`_speeds`)).

        Broad phase: the triangles of each other body b whose centroids lie within the reach
        (:meth:`_reach`) of the vertex, the :data:`NEAREST_TRIANGLES` nearest of them (equal
        distances by triangle index), from ``pairs`` (:meth:`_vertex_pairs` of any superset of
        them, else a search from scratch; ``reach``: :meth:`_reach` at x if known). Narrow phase:
        the closest of them (:func:`closest_surface_points`, compiled:
        :func:`~skfem_affine.contact.narrow.body_contacts`); a pair is a contact when its gap may close at the relative
        normal approach speed (the largest over the fields). The contacts come by other body, then
        by vertex.
        """
        sv, out = self.body_vertices, []
        R, centroid = self._reach(x, speeds, dt) if reach is None else reach
        rows, cand, starts = self._vertex_pairs(x, R, centroid) if pairs is None else pairs
        i, body, tri, W, d, normal = narrow.body_contacts(
            x, sv, self.body_of_vertex[sv], self.tris, self.tri_body, centroid, R, starts, rows, cand, fields[0],
            fields[-1], len(fields), self.margin, float(dt), 1e-9 * self.mean_edge, NEAREST_TRIANGLES)
        if not i.size:
            return out
        vtx = sv[i]
        cut = np.flatnonzero(np.r_[True, body[1:] != body[:-1], True])   # the contacts are by body, then vertex
        for lo, hi in zip(cut[:-1], cut[1:]):
            out.append(ContactSet(vtx[lo:hi], self.tris[tri[lo:hi]], W[lo:hi], normal[lo:hi], d[lo:hi],
                                  vtx[lo:hi] * self.n_kinds + len(self.colliders) + body[lo]))
        return out
