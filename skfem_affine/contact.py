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
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from numba import njit
from scipy.spatial import cKDTree

from .colliders import check_colliders


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
        length. Vertices within ``margin + 2 h |v|`` of an obstacle become contacts.
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
    block: int = 512

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
    """A^-1 applied to many columns with the frame's factorization, through G when reduced (sec. 3.3).

    ``solver`` has already factorised the frame's system (full A, or G^T A G of a
    reducer); ``G`` (n_free x r) is the reducer's mapping, or None in full space.
    """

    def __init__(self, solver, G=None, block=512):
        self.solver, self.G, self.block = solver, G, int(block)
        current = getattr(solver, "_current", solver)
        self.iterative = bool(getattr(current, "iterative", False))

    def _solve(self, R):
        if self.iterative:  # CG takes one right-hand side at a time
            return np.column_stack([self.solver.solve(np.ascontiguousarray(R[:, j])) for j in range(R.shape[1])])
        return np.asarray(self.solver.solve(R)).reshape(R.shape)

    def delassus(self, J):
        """W = J A^-1 J^T (dense, symmetric), A^-1 ~ G A_r^-1 G^T in a reduced frame."""
        self.Jr = sp.csr_matrix(J @ self.G) if self.G is not None else J
        JrT = self.Jr.T.tocsc()
        k = J.shape[0]
        W = np.empty((k, k))
        for s in range(0, k, self.block):
            cols = slice(s, min(s + self.block, k))
            W[:, cols] = self.Jr @ self._solve(JrT[:, cols].toarray())
        return 0.5 * (W + W.T)

    def apply(self, lam):
        """dv = A^-1 J^T lambda on the free DOFs (through G when reduced)."""
        y = self._solve((self.Jr.T @ lam)[:, None])[:, 0]
        return self.G @ y if self.G is not None else y


@njit(cache=True)
def projected_gauss_seidel(W, u0, lam, mu, iterations, tolerance):
    """PGS on 0 <= lam_n _|_ u_n >= 0, ||lam_t|| <= mu lam_n with u = u0 + W lam (3 rows per contact).

    ``lam`` (3k,) holds the warm start and is updated in place. Per contact: the
    normal row by a projected Gauss-Seidel step, then both tangent rows, projected
    jointly onto the disk of radius mu lam_n. Returns the sweeps done.
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
            t1 = lam[r + 1] - u[r + 1] / W[r + 1, r + 1] if W[r + 1, r + 1] > 0.0 else 0.0
            t2 = lam[r + 2] - u[r + 2] / W[r + 2, r + 2] if W[r + 2, r + 2] > 0.0 else 0.0
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
        self.current = None
        self.prediction = None

    # -------------------------------------------------------------- detection
    def find(self, x, v, dt):
        """All contacts at positions x (n, 3) with vertex velocities v (detection radius margin + 2 h |v|)."""
        sv = self.surface
        xs = x[sv]
        speed = np.linalg.norm(v[sv], axis=1)
        radius = self.margin + 2.0 * dt * speed
        sets = []
        for ci, col in enumerate(self.colliders):
            d, n = col.query(xs)
            hit = np.flatnonzero(d < radius)
            if hit.size:
                vtx = sv[hit]
                sets.append(ContactSet(vtx, np.repeat(vtx[:, None], 3, axis=1), np.zeros((hit.size, 3)), n[hit],
                                       d[hit], vtx * self.n_kinds + ci))
        if self.body_pairs:
            sets += self._body_contacts(x, xs, 2.0 * radius.max() if sv.size else self.margin)
        if not sets:
            return None
        return _concat(sets)

    def _body_contacts(self, x, xs, radius):
        """Surface vertices of every body against the boundary triangles of each other body."""
        sv, out = self.surface, []
        owner = self.body_of_vertex[sv]
        for b in np.unique(self.tri_body):
            tris = self.tris[self.tri_body == b]
            a, bb, c = x[tris[:, 0]], x[tris[:, 1]], x[tris[:, 2]]
            lo = np.minimum(np.minimum(a, bb), c).min(axis=0) - radius
            hi = np.maximum(np.maximum(a, bb), c).max(axis=0) + radius
            cand = np.flatnonzero((owner != b) & np.all((xs >= lo) & (xs <= hi), axis=1))
            if not cand.size:
                continue
            centroid = (a + bb + c) / 3.0
            reach = np.sqrt(np.max([np.einsum("ij,ij->i", q - centroid, q - centroid) for q in (a, bb, c)]))
            tree = cKDTree(centroid)
            kq = min(12, len(tris))
            dist, idx = tree.query(xs[cand], k=kq, distance_upper_bound=radius + reach)
            dist, idx = dist.reshape(len(cand), kq), idx.reshape(len(cand), kq)
            ok = idx < len(tris)
            rows, cols = np.nonzero(ok)
            if not rows.size:
                continue
            pv, tri = cand[rows], idx[rows, cols]
            p = xs[pv]
            Wb = closest_points_on_triangles(p, a[tri], bb[tri], c[tri])
            q = Wb[:, :1] * a[tri] + Wb[:, 1:2] * bb[tri] + Wb[:, 2:] * c[tri]
            gap = np.linalg.norm(p - q, axis=1)
            # per vertex: the closest candidate triangle
            order = np.lexsort((gap, pv))
            first = order[np.r_[True, pv[order][1:] != pv[order][:-1]]]
            pv, tri, Wb, q, gap = pv[first], tri[first], Wb[first], q[first], gap[first]
            fn = np.cross(bb[tri] - a[tri], c[tri] - a[tri])
            fn /= np.linalg.norm(fn, axis=1, keepdims=True)
            side = np.where(np.einsum("ij,ij->i", xs[pv] - q, fn) < 0, -1.0, 1.0)
            d = side * gap
            hit = d < radius
            if not np.any(hit):
                continue
            vtx = sv[pv[hit]]
            out.append(ContactSet(vtx, tris[tri[hit]], Wb[hit], fn[hit], d[hit],
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
