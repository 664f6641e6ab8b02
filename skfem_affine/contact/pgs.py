r"""Frictional contact by projected Gauss-Seidel (paper sec. 3.1, 3.3, 3.4 and Algorithm 1).

One frame, in the order of Algorithm 1:

1. **Find contacts** (:meth:`Contact.detect`, at x_t): surface vertices against the static
   colliders (signed distance queries, :mod:`skfem_affine.colliders`) and against the
   boundary triangles of the *other* bodies (a KD-tree on each body's triangle centroids
   as broad phase, exact point-triangle distance as narrow phase; self-contact is not
   detected). A contact i has a signed gap d_i (negative: penetration), a normal n_i
   and two tangents; its three Jacobian rows give the relative velocity
   ``u_i = [n, t1, t2]^T (v_a - sum_k w_k v_k)`` of the vertex a against the closest point
   (barycentric weights w_k; for a collider, against the static obstacle).
2. **Prediction impulses** (sec. 3.4): the oracle's one PCG iteration gets
   ``J^T lambda_pred`` as explicit impulses: the warm-started impulses of contacts
   that persist, and, for new contacts, a cheap bilateral estimate (one Jacobi step
   on J_n v = -b_n with the lumped-mass Delassus J_n M^-1 J_n^T), so that an impact
   elastifies the right region before it happens (:meth:`Contact.prediction_impulse`).
3. The elastic (reduced) solve gives ``dv`` (eq. 10-12).
4. **PGS contact solve** (:meth:`Contact.resolve`): with the Delassus operator
   ``W = J A^-1 J^T``, applied through the frame's factorization and, for a reduced
   frame, through G: ``A^-1 ~ G (G^T A G)^-1 G^T``, so ``W = (J G) A_r^-1 (J G)^T``
   costs solves of the small reduced system (:class:`Resolvent`). PGS finds impulses
   lambda with

   .. math:: u = J(\dot x_t + \Delta\dot x) + b + W\lambda, \qquad
             0 \le \lambda_n \perp u_n \ge 0, \qquad
             \|\lambda_t\| \le \mu \lambda_n \ (\text{Coulomb cone, maximal dissipation}),

   with the bias ``b_n = d / h`` for a gap (speculative contact: the vertex may close it
   within the step but not cross) and ``b_n = erp d / h`` for a penetration (Baumgarte).
   Restitution is zero. The velocity correction is ``dv_c = A^-1 J^T lambda`` (one
   more solve), and v_{t+1} = v_t + dv + dv_c, x_{t+1} = x_t + h v_{t+1}.

Friction is the isotropic Coulomb *cone*: each PGS step projects the tangential
impulse pair onto the disk of radius ``mu lambda_n`` (not a box per tangent).
Impulses are stored in world coordinates and matched next frame by a contact
identity (vertex, collider) or (vertex, other body), so a vertex sliding across
triangles keeps its warm start.
"""
import time
from contextlib import nullcontext as _nothing
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from numba import njit
from scipy.linalg import cho_solve, cholesky, solve_triangular
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from skfem_affine.threads import serial_blas  # small dense blocks (docs/threads.md)
from skfem_affine.contact.colliders import check_colliders
from skfem_affine.reducers.affine.mapping import group_sum

# Blocks (bodies) of the Delassus operator: up to BLOCK_DENSE_MAX unknowns a dense Cholesky
# factor L gives W_b = X^T X, X = L^-1 J_b^T (one triangular solve; 2.5x faster than sparse
# solves on the pills' reduced blocks); below BLOCK_DIRECT_MIN SuperLU, else the direct solver.
BLOCK_DENSE_MAX = 800
# Broad phase: candidate triangles per vertex (nearest centroids within reach).
NEAREST_TRIANGLES = 8
BLOCK_DIRECT_MIN = 2000


@dataclass(frozen=True)
class PGS:
    """Settings of the projected Gauss-Seidel contact solver.

    Parameters
    ----------
    friction : float
        Coulomb coefficient mu >= 0 (the cone ||lambda_t|| <= mu lambda_n).
    iterations : int
        Maximum Gauss-Seidel sweeps per frame (>= 1).
    tolerance : float
        A sweep whose largest impulse change is below ``tolerance`` times the largest
        impulse ends the iteration.
    erp : float
        Baumgarte error reduction in [0, 1]: a penetration d < 0 is pushed out at
        ``erp |d| / h`` per step.
    margin : float, optional
        Speculative contact distance (m); default a fifth of the mean surface edge
        length. A vertex becomes a contact when its gap is below ``margin + 2 h`` times its
        normal approach speed (relative to the other body).
    warm_start : bool
        Start from the previous frame's impulses matched by contact identity.
    body_contact : bool
        Detect contact between different bodies (surface vertices vs boundary triangles).
    block : int
        Columns of J^T solved at once when building the Delassus operator (memory bound).
    """

    friction: float = 0.5
    iterations: int = 50
    tolerance: float = 1e-6
    erp: float = 0.2
    margin: float = None
    warm_start: bool = True
    body_contact: bool = True
    block: int = 64

    def __post_init__(self):
        for name in ("friction", "tolerance"):
            v = getattr(self, name)
            if not isinstance(v, (int, float, np.floating, np.integer)) or not np.isfinite(v) or v < 0:
                raise ValueError(f"PGS {name} must be a finite number >= 0, got {v!r}")
        if not isinstance(self.iterations, (int, np.integer)) or self.iterations < 1:
            raise ValueError(f"PGS iterations must be an integer >= 1, got {self.iterations!r}")
        if not 0.0 <= float(self.erp) <= 1.0:
            raise ValueError(f"PGS erp must lie in [0, 1], got {self.erp!r}")
        if self.margin is not None and not (np.isfinite(self.margin) and self.margin >= 0):
            raise ValueError(f"PGS margin must be finite and >= 0, got {self.margin!r}")
        if int(self.block) < 1:
            raise ValueError(f"PGS block must be >= 1, got {self.block!r}")


# ---------------------------------------------------------------------------- geometry
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

    The Voronoi-region test of Ericson (Real-Time Collision Detection, 5.1.5), vectorised:
    interior, then edges, then vertices (later regions override earlier ones).
    """
    ab, ac, ap, bp, cp = b - a, c - a, p - a, p - b, p - c

    def dot(u, v):
        return np.einsum("ij,ij->i", u, v)

    d1, d2, d3, d4, d5, d6 = dot(ab, ap), dot(ac, ap), dot(ab, bp), dot(ac, bp), dot(ab, cp), dot(ac, cp)
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2

    def safe(num, den):
        return num / np.where(np.abs(den) > 1e-300, den, 1e-300)

    s = va + vb + vc
    v, w = safe(vb, s), safe(vc, s)
    W = np.column_stack([1.0 - v - w, v, w])

    def put(mask, cols):
        W[mask] = np.column_stack(cols)[mask]

    wbc = safe(d4 - d3, (d4 - d3) + (d5 - d6))
    put((va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0), [0 * wbc, 1 - wbc, wbc])
    wac = safe(d2, d2 - d6)
    put((vb <= 0) & (d2 >= 0) & (d6 <= 0), [1 - wac, 0 * wac, wac])
    one, zero = np.ones_like(d1), np.zeros_like(d1)
    put((d6 >= 0) & (d5 <= d6), [zero, zero, one])
    vab = safe(d1, d1 - d3)
    put((vc <= 0) & (d1 >= 0) & (d3 <= 0), [1 - vab, vab, zero])
    put((d3 >= 0) & (d4 <= d3), [zero, one, zero])
    put((d1 <= 0) & (d2 <= 0), [one, zero, zero])
    return W


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
    pseudo-normal when the gap is below ``tiny``).

    Returns ``(points_found, triangle, weights (k, 3), signed distance (k,), normal (k, 3))``.
    """
    a, b, c = corners[tri, 0], corners[tri, 1], corners[tri, 2]
    p = points[rows]
    W = closest_points_on_triangles(p, a, b, c)
    diff = p - (W[:, :1] * a + W[:, 1:2] * b + W[:, 2:] * c)
    gap = np.linalg.norm(diff, axis=1)
    fn = np.cross(b - a, c - a)
    fn /= np.linalg.norm(fn, axis=1, keepdims=True)
    order = np.lexsort((gap, rows))
    first = order[np.r_[True, rows[order][1:] != rows[order][:-1]]]          # the closest pair per point
    gmin = np.zeros(len(points))
    gmin[rows[first]] = gap[first]
    tie = gap <= gmin[rows] * (1.0 + 1e-9) + tiny
    pseudo = group_sum(rows[tie], fn[tie], len(points))
    r, g = rows[first], gap[first]
    side = np.where(np.einsum("ij,ij->i", diff[first], pseudo[r]) < 0, -1.0, 1.0)
    pn = pseudo[r] / np.maximum(np.linalg.norm(pseudo[r], axis=1, keepdims=True), 1e-300)
    normal = np.where((g > tiny)[:, None], side[:, None] * diff[first] / np.maximum(g, 1e-300)[:, None], pn)
    return r, tri[first], W[first], side * g, normal


@dataclass
class ContactSet:
    """The contacts of one frame (k of them), found at x_t."""

    vertex: np.ndarray    # (k,) the vertex a of each contact
    others: np.ndarray    # (k, 3) triangle vertices of the other body (collider contacts: a, weight 0)
    weights: np.ndarray   # (k, 3) barycentric weights of the closest point (zeros for colliders)
    normal: np.ndarray    # (k, 3) unit normal, pointing from the obstacle towards the vertex
    distance: np.ndarray  # (k,) signed gap (negative: penetration)
    key: np.ndarray       # (k,) identity: vertex * n_kinds + (collider index | n_colliders + other body)
    J: sp.csr_matrix = None  # (3k, n_free) rows n, t1, t2 per contact

    @property
    def size(self):
        return self.vertex.size

    def frames(self):
        """(k, 3, 3) rows n, t1, t2 of each contact."""
        t1, t2 = tangent_basis(self.normal)
        return np.stack([self.normal, t1, t2], axis=1)


def _concat(sets):
    fields = ("vertex", "others", "weights", "normal", "distance", "key")
    return ContactSet(*[np.concatenate([getattr(s, f) for s in sets]) for f in fields])


def jacobian(contacts, n_vertices, free):
    """J (3k x n_free): row 3i + r is frame row r of contact i on v_a - sum_k w_k v_k (fixed DOFs dropped)."""
    k = contacts.size
    frames = contacts.frames()                                        # (k, 3, 3)
    verts = np.column_stack([contacts.vertex, contacts.others])       # (k, 4)
    coef = np.column_stack([np.ones(k), -contacts.weights])           # (k, 4)
    vals = coef[:, None, :, None] * frames[:, :, None, :]             # (k, 3 rows, 4 verts, 3 comps)
    rows = np.broadcast_to((3 * np.arange(k)[:, None] + np.arange(3))[:, :, None, None], vals.shape)
    cols = np.broadcast_to((3 * verts[:, :, None] + np.arange(3))[:, None, :, :], vals.shape)
    dof_map = np.full(3 * n_vertices, -1, dtype=np.int64)
    dof_map[free] = np.arange(free.size)
    c = dof_map[cols.ravel()]
    keep = (c >= 0) & (vals.ravel() != 0)
    J = sp.csr_matrix((vals.ravel()[keep], (rows.ravel()[keep], c[keep])), shape=(3 * k, free.size))
    J.sum_duplicates()
    return J


# ---------------------------------------------------------------------------- Delassus
class Resolvent:
    """A^-1 applied to the columns of J^T with the frame's system, through G when reduced (sec. 3.3).

    ``A`` is the frame's system matrix (full A, or A_r = G^T A G of a reducer) and
    ``solver`` has factorised it; ``G`` (n_free x r) is the reducer's mapping, or None in
    full space, so that ``W = (J G) A_r^-1 (J G)^T``. Bodies are not coupled by A, so
    when A has several connected components (several bodies), W is built per
    component from a factorization of that block alone (dense Cholesky up to
    :data:`BLOCK_DENSE_MAX` unknowns, SuperLU below :data:`BLOCK_DIRECT_MIN`, else the
    fastest direct solver), solving only the columns of contacts that touch it;
    components without contacts cost nothing.
    """

    def __init__(self, solver, A, G=None, block=64, cache=None):
        self.solver, self.A, self.G, self.block = solver, A, G, int(block)
        current = getattr(solver, "_current", solver)
        self.iterative = bool(getattr(current, "iterative", False))
        n_comp, labels = connected_components(A, directed=False)
        self.parts = None
        if n_comp > 1:  # renumber component by component, so that blocks are contiguous slices
            self.order = np.argsort(labels, kind="stable")
            self.bounds = np.concatenate([[0], np.cumsum(np.bincount(labels, minlength=n_comp))])
            self.parts = range(n_comp)
        self.cache = {} if cache is None else cache

    def _solve(self, solver, R, iterative=False):
        if iterative:  # CG takes one right-hand side at a time
            return np.column_stack([solver.solve(np.ascontiguousarray(R[:, j])) for j in range(R.shape[1])])
        return np.asarray(solver.solve(R)).reshape(R.shape)

    def _blocks(self, solver, JrT, iterative=False):
        """A^-1 JrT (dense), ``block`` columns at a time."""
        Y = np.empty(JrT.shape)
        for s in range(0, JrT.shape[1], self.block):
            cols = slice(s, min(s + self.block, JrT.shape[1]))
            Y[:, cols] = self._solve(solver, JrT[:, cols].toarray(), iterative)
        return Y

    def _block_solver(self, idx):
        from skfem_affine.solvers import SuperLU, direct_solver
        key = (idx.size, int(idx[0]))  # components keep their unknowns while the pattern is fixed
        if key not in self.cache:
            self.cache[key] = SuperLU() if idx.size < BLOCK_DIRECT_MIN else direct_solver()
        return self.cache[key]

    def delassus(self, J):
        """W = J A^-1 J^T (dense, symmetric), A^-1 ~ G A_r^-1 G^T in a reduced frame."""
        Jr = sp.csr_matrix(J @ self.G) if self.G is not None else sp.csr_matrix(J)
        self.Jr = Jr
        k = J.shape[0]
        if self.parts is None:
            W = Jr @ self._blocks(self.solver, Jr.T.tocsc(), self.iterative)
            return 0.5 * (W + W.T)
        W = np.zeros((k, k))
        Jc = Jr[:, self.order].tocsc()
        Ap = sp.csr_matrix(self.A)[self.order][:, self.order].tocsr()
        self.local = []
        for c in self.parts:
            s, e = self.bounds[c], self.bounds[c + 1]
            Jb = Jc[:, s:e].tocsr()
            rows = np.flatnonzero(np.diff(Jb.indptr))
            if not rows.size:
                continue
            Jb = Jb[rows]
            idx = self.order[s:e]
            if idx.size <= BLOCK_DENSE_MAX:  # W_b = X^T X with X = L^-1 J_b^T, A_b = L L^T dense
                with serial_blas():
                    L = cholesky(Ap[s:e, s:e].toarray(), lower=True)
                    X = solve_triangular(L, Jb.T.toarray(), lower=True)
                    W[np.ix_(rows, rows)] += X.T @ X
                self.local.append((idx, rows, Jb, L))
                continue
            solver = self._block_solver(idx)
            with serial_blas() if idx.size < BLOCK_DIRECT_MIN else _nothing():
                solver.factorize(Ap[s:e, s:e])
                W[np.ix_(rows, rows)] += Jb @ self._blocks(solver, Jb.T.tocsc())
            self.local.append((idx, rows, Jb, solver))
        return 0.5 * (W + W.T)

    def apply(self, lam):
        """dv = A^-1 J^T lambda on the free DOFs (through G when reduced)."""
        if self.parts is None:
            y = self._solve(self.solver, (self.Jr.T @ lam)[:, None], self.iterative)[:, 0]
        else:
            y = np.zeros(self.Jr.shape[1])
            for idx, rows, Jb, solver in self.local:
                r = Jb.T @ lam[rows]
                if isinstance(solver, np.ndarray):  # a dense Cholesky factor
                    y[idx] = cho_solve((solver, True), r)
                    continue
                with serial_blas() if idx.size < BLOCK_DIRECT_MIN else _nothing():
                    y[idx] = self._solve(solver, r[:, None])[:, 0]
        return self.G @ y if self.G is not None else y


@njit(cache=True)
def projected_gauss_seidel(W, u0, lam, mu, iterations, tolerance):
    """PGS on 0 <= lam_n _|_ u_n >= 0, ||lam_t|| <= mu lam_n with u = u0 + W lam (3 rows per contact).

    ``lam`` (3k,) holds the warm start and is updated in place. Per contact: the
    normal row by a projected Gauss-Seidel step, then both tangent rows, projected
    jointly onto the disk of radius mu lam_n (Euclidean projection after a gradient step of
    the 2 x 2 tangent block's largest eigenvalue). Returns the sweeps done.
    """
    m = lam.size
    k = m // 3
    u = u0.copy()
    for i in range(m):
        if lam[i] != 0.0:
            for j in range(m):
                u[j] += W[i, j] * lam[i]
    for sweep in range(iterations):
        change = 0.0
        largest = 0.0
        for c in range(k):
            r = 3 * c
            if W[r, r] <= 0.0:
                continue
            new_n = max(0.0, lam[r] - u[r] / W[r, r])
            dn = new_n - lam[r]
            if dn != 0.0:
                lam[r] = new_n
                for j in range(m):
                    u[j] += W[r, j] * dn
            # one projected gradient step on both tangents with the largest eigenvalue of their
            # 2 x 2 block: its fixed point is exactly Coulomb's maximal dissipation
            a, b, c2 = W[r + 1, r + 1], W[r + 1, r + 2], W[r + 2, r + 2]
            step = 0.5 * (a + c2) + np.sqrt(0.25 * (a - c2) ** 2 + b * b)
            if step <= 0.0:
                continue
            t1 = lam[r + 1] - u[r + 1] / step
            t2 = lam[r + 2] - u[r + 2] / step
            bound = mu * lam[r]
            norm = np.sqrt(t1 * t1 + t2 * t2)
            if norm > bound:
                scale = bound / norm
                t1 *= scale
                t2 *= scale
            d1, d2 = t1 - lam[r + 1], t2 - lam[r + 2]
            if d1 != 0.0 or d2 != 0.0:
                lam[r + 1], lam[r + 2] = t1, t2
                for j in range(m):
                    u[j] += W[r + 1, j] * d1 + W[r + 2, j] * d2
            change = max(change, abs(dn), abs(d1), abs(d2))
            largest = max(largest, lam[r], abs(t1), abs(t2))
        if change <= tolerance * largest or largest == 0.0:
            return sweep + 1
    return iterations


# ---------------------------------------------------------------------------- per simulation
class Contact:
    """Contact state of one :class:`~skfem_affine.Simulation`: detection, warm start, PGS.

    Built by the simulation when it has colliders or several bodies.
    """

    def __init__(self, sim, colliders, settings):
        self.settings = settings or PGS()
        if not isinstance(self.settings, PGS):
            raise TypeError(f"contact must be sa.PGS(...), got {type(settings).__name__}")
        self.colliders = check_colliders(colliders)
        sysm = sim.system
        self.tris, self.tri_body = boundary_surface(sysm)
        self.surface = np.unique(self.tris)
        self.body_of_vertex = np.repeat(np.arange(len(sysm.bodies)), np.diff(sysm.vertex_offsets))
        self.n_kinds = len(self.colliders) + len(sysm.bodies)
        p0 = sysm.p0
        edges = np.concatenate([p0[self.tris[:, i]] - p0[self.tris[:, (i + 1) % 3]] for i in range(3)])
        self.mean_edge = float(np.linalg.norm(edges, axis=1).mean())
        self.margin = 0.2 * self.mean_edge if self.settings.margin is None else float(self.settings.margin)
        self.inv_mass = 1.0 / np.repeat(sysm.lumped_mass, 3)[sysm.free]
        self.body_pairs = self.settings.body_contact and len(sysm.bodies) > 1
        self.previous = None  # (sorted keys, world impulses)
        self.block_solvers = {}  # per-body factorizations of the Delassus operator, reused across frames
        self.current = None
        self.prediction = None

    # -------------------------------------------------------------- detection
    def find(self, x, v, dt):
        """All contacts at positions x (n, 3) with vertex velocities v (n, 3), or None.

        A surface vertex is a contact when its gap is below ``margin + 2 h`` times its
        normal approach speed (towards a collider, or relative to the other body)."""
        sv = self.surface
        xs, vs = x[sv], v[sv]
        sets = []
        for ci, col in enumerate(self.colliders):
            d, n = col.query(xs)
            approach = np.maximum(0.0, -np.einsum("ij,ij->i", vs, n))
            hit = np.flatnonzero(d < self.margin + 2.0 * dt * approach)
            if hit.size:
                vtx = sv[hit]
                sets.append(ContactSet(vtx, np.repeat(vtx[:, None], 3, axis=1), np.zeros((hit.size, 3)), n[hit],
                                       d[hit], vtx * self.n_kinds + ci))
        if self.body_pairs:
            sets += self._body_contacts(x, v, xs, vs, dt)
        if not sets:
            return None
        return _concat(sets)

    def _body_contacts(self, x, v, xs, vs, dt):
        """Surface vertices of every body against the boundary triangles of each other body.

        Broad phase: the other body's bounding box grown by a bound on the relative
        motion within the step, then a KD-tree on its triangle centroids (the
        :data:`NEAREST_TRIANGLES` nearest within reach). Narrow phase:
        :func:`closest_surface_points`; a pair is a contact when its gap may close at the
        relative normal approach speed.
        """
        sv, out = self.surface, []
        owner = self.body_of_vertex[sv]
        nb = int(self.body_of_vertex.max()) + 1
        # |v_i - v_j| <= |v_i - vbar_a| + |vbar_a - vbar_b| + max_j |v_j - vbar_b| for i in a, j in b
        mean_v = group_sum(owner, vs, nb) / np.maximum(np.bincount(owner, minlength=nb), 1)[:, None]
        spread = np.linalg.norm(vs - mean_v[owner], axis=1)
        max_spread = np.zeros(nb)
        np.maximum.at(max_spread, owner, spread)
        for b in np.unique(self.tri_body):
            tris = self.tris[self.tri_body == b]
            corners = x[tris]                                             # (T, 3 corners, 3)
            bound = spread + np.linalg.norm(mean_v[owner] - mean_v[b], axis=1) + max_spread[b]
            radius = self.margin + 2.0 * dt * bound
            lo, hi = corners.min(axis=(0, 1)), corners.max(axis=(0, 1))
            cand = np.flatnonzero((owner != b) & np.all((xs >= lo - radius[:, None]) & (xs <= hi + radius[:, None]),
                                                        axis=1))
            if not cand.size:
                continue
            centroid = corners.mean(axis=1)
            reach = np.sqrt(((corners - centroid[:, None]) ** 2).sum(axis=2).max())
            kq = min(NEAREST_TRIANGLES, len(tris))
            _, idx = cKDTree(centroid).query(xs[cand], k=kq, distance_upper_bound=radius[cand].max() + reach)
            rows, cols = np.nonzero(idx.reshape(len(cand), kq) < len(tris))
            if not rows.size:
                continue
            found, tri, W, d, normal = closest_surface_points(xs[cand], rows, idx.reshape(len(cand), kq)[rows, cols],
                                                              corners, 1e-9 * self.mean_edge)
            vq = np.einsum("kj,kjc->kc", W, v[tris[tri]])
            approach = np.maximum(0.0, -np.einsum("ij,ij->i", vs[cand[found]] - vq, normal))
            hit = d < self.margin + 2.0 * dt * approach
            if np.any(hit):
                vtx = sv[cand[found[hit]]]
                out.append(ContactSet(vtx, tris[tri[hit]], W[hit], normal[hit], d[hit],
                                      vtx * self.n_kinds + len(self.colliders) + b))
        return out

    # -------------------------------------------------------------- frame hooks
    def detect(self, sim, rec):
        """Algorithm 1, "Find contacts": contacts at x_t, their Jacobian, warm start and the
        oracle's prediction impulses J^T lambda_pred (sec. 3.4)."""
        t0 = time.perf_counter()
        s, sysm, h = sim.state, sim.system, sim.dt
        cs = self.find(s.x, s.v, h)
        self.current, self.prediction = cs, None
        if cs is not None:
            cs.J = jacobian(cs, sysm.n, sysm.free)
            self.lam0 = self._warm_start(cs)
            self.bias = self._bias(cs, h)
            vg = s.v.reshape(-1)[sysm.free] + h * np.tile(sim.gravity, sysm.n)[sysm.free]
            self.prediction = cs.J.T @ self._predicted_impulses(cs, vg)
        rec["n_contacts"] = 0 if cs is None else cs.size
        rec["contact"] = rec.get("contact", 0.0) + time.perf_counter() - t0
        return cs

    def _bias(self, cs, h):
        """b_n = d / h for a gap (speculative), erp d / h for a penetration (Baumgarte); tangents 0."""
        d = cs.distance
        b = np.zeros(3 * cs.size)
        b[0::3] = np.where(d > 0, d, self.settings.erp * d) / h
        return b

    def _warm_start(self, cs):
        """Previous impulses of the same contact identities, in the new frames, inside the cone."""
        lam = np.zeros(3 * cs.size)
        if not (self.settings.warm_start and self.previous is not None and self.previous[0].size):
            self.matched = np.zeros(cs.size, dtype=bool)
            return lam
        keys, P = self.previous
        pos = np.minimum(np.searchsorted(keys, cs.key), keys.size - 1)
        self.matched = keys[pos] == cs.key
        local = np.einsum("kij,kj->ki", cs.frames(), np.where(self.matched[:, None], P[pos], 0.0))
        local[:, 0] = np.maximum(local[:, 0], 0.0)
        tn = np.linalg.norm(local[:, 1:], axis=1)
        bound = self.settings.friction * local[:, 0]
        local[:, 1:] *= np.where(tn > bound, bound / np.maximum(tn, 1e-300), 1.0)[:, None]
        return local.ravel()

    def _predicted_impulses(self, cs, v_free):
        """Warm-started impulses, and for new contacts one Jacobi step on the bilateral J_n v = -b_n
        with the lumped-mass Delassus (sec. 3.4): lambda_n = max(0, -(J_n v + b_n)) / (J_n M^-1 J_n^T)."""
        lam = self.lam0.copy()
        Jn = cs.J[0::3]
        un = Jn @ v_free + self.bias[0::3]
        wnn = np.asarray(Jn.multiply(Jn) @ self.inv_mass).ravel()
        new = ~self.matched & (wnn > 0)
        lam[0::3][new] = np.maximum(0.0, -un[new]) / wnn[new]
        return lam

    def prediction_impulse(self):
        """J^T lambda_pred on the free DOFs for the oracle's right-hand side (eq. 13), or 0."""
        return 0.0 if self.prediction is None else self.prediction

    def resolve(self, sim, dv, resolvent, rec):
        """PGS contact solve after the elastic step (Algorithm 1): returns dv_c on the free DOFs."""
        cs = self.current
        if cs is None:
            rec["pgs_iterations"] = 0
            self.previous = None
            return np.zeros_like(dv)
        t0 = time.perf_counter()
        sysm, st = sim.system, self.settings
        v_star = sim.state.v.reshape(-1)[sysm.free] + dv
        W = resolvent.delassus(cs.J)
        t1 = time.perf_counter()
        lam = self.lam0.copy()
        u0 = cs.J @ v_star + self.bias
        sweeps = projected_gauss_seidel(W, u0, lam, float(st.friction), int(st.iterations), float(st.tolerance))
        dvc = resolvent.apply(lam)
        local = lam.reshape(-1, 3)
        world = np.einsum("kij,ki->kj", cs.frames(), local)
        order = np.argsort(cs.key)
        self.previous = (cs.key[order], world[order])
        self.lam = lam
        t2 = time.perf_counter()
        rec.update(pgs_iterations=int(sweeps), delassus=t1 - t0, pgs=t2 - t1)
        rec["contact"] = rec.get("contact", 0.0) + t2 - t0
        return dvc


def make_contact(sim, colliders, settings):
    """The simulation's :class:`Contact`, or None when nothing can touch (one body, no collider)
    or when ``settings is False``."""
    colliders = check_colliders(colliders)
    if settings is False:
        if colliders:
            raise ValueError("contact=False but colliders were given")
        return None
    if settings is not None and not isinstance(settings, PGS):
        raise TypeError(f"contact must be sa.PGS(...), None or False, got {type(settings).__name__}")
    if not colliders and len(sim.system.bodies) < 2:
        return None
    return Contact(sim, colliders, settings)
