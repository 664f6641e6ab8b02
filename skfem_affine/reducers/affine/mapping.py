r"""Reduction to affine (or rigid) bodies (paper sec. 3.3, eq. 7-12).

The mapping from reduced to full velocities on the free DOFs,

.. math:: G = \begin{bmatrix} I & 0 \\ 0 & \Gamma \end{bmatrix}, \qquad
          \Gamma_i = \begin{bmatrix} I_3 & I_3 \otimes r_i^T \end{bmatrix}  \quad (7, 8)

(rows of vertex i; r_i from its body's centre of mass in the rest frame), is
stored without reordering: elastic free DOFs keep an identity column each, in
their order, and body b owns the w columns after them (w = 12 for an affine
body: 3 translation + 9 entries of the affine matrix, row-major; w = 6 for a
rigid body of the baseline). Velocities are projected by the mass-weighted
least squares of eq. 9, the discrepancy d = G q - v (eq. 11) is added back
after the reduced solve G^T A G dq = G^T b (eq. 10): dv = G dq + d (eq. 12).

The kind of body lives in the mapping (:class:`BodyKind`: :data:`AFFINE`, :data:`RIGID`): its
width, its rows Gamma_i, the basis the reduced assembly expands them in, and how its vertices'
positions are integrated. Build a frame's mapping with :func:`affine_mapping` or
:func:`rigid_mapping`.
"""
import numpy as np
import scipy.sparse as sp
from numba import njit

from skfem_affine import _compile_notice  # noqa: F401 (one stderr line when the cached kernels compile)
from skfem_affine._extras import require


def group_sum(groups, values, n_groups):
    """Sum rows of ``values`` (k, ...) by group id (k,) into (n_groups, ...); a fast np.add.at."""
    values = np.asarray(values, dtype=float)
    width = int(np.prod(values.shape[1:]))
    flat = (groups[:, None] * width + np.arange(width)).ravel()
    out = np.bincount(flat, weights=values.reshape(-1), minlength=n_groups * width)
    return out.reshape((n_groups,) + values.shape[1:])


@njit(cache=True)
def _vertex_clusters(labels, t, out):
    for e in range(labels.size):
        if labels[e] >= 0:
            for k in range(4):
                out[t[k, e]] = labels[e]


def vertex_clusters(labels, t, n_vertices):
    """Body of each vertex (n,), -1 elastic, from per-element labels (vertex-disjoint clusters)."""
    vc = np.full(n_vertices, -1, dtype=np.int64)
    _vertex_clusters(np.asarray(labels, dtype=np.int64), np.asarray(t, dtype=np.int64), vc)
    return vc


@njit(cache=True)
def _centres(vcluster, positions, mass, n_bodies):
    """Mass centre of every body and r_i = x_i - x_c (zero for elastic vertices)."""
    com = np.zeros((n_bodies, 3))
    mt = np.zeros(n_bodies)
    for i in range(vcluster.size):
        b = vcluster[i]
        if b >= 0:
            mt[b] += mass[i]
            for a in range(3):
                com[b, a] += mass[i] * positions[i, a]
    for b in range(n_bodies):
        for a in range(3):
            com[b, a] /= mt[b]
    r = np.zeros((vcluster.size, 3))
    for i in range(vcluster.size):
        b = vcluster[i]
        if b >= 0:
            for a in range(3):
                r[i, a] = positions[i, a] - com[b, a]
    return com, r


def centre_offsets(vcluster, positions, mass, n_bodies):
    """Reduced vertices, their bodies, the bodies' centres of mass and the offsets r = x - x_c."""
    com, r = _centres(np.asarray(vcluster, dtype=np.int64), np.ascontiguousarray(positions, dtype=float),
                      np.asarray(mass, dtype=float), int(n_bodies))
    red = np.flatnonzero(vcluster >= 0)
    return red, vcluster[red], com, r[red]


def affine_rows(vcluster, rest, mass, n_bodies):
    """Gamma_i = [I_3, I_3 (x) r_i^T] (n, 3, 12), r_i = X_i - X_c in the rest frame (eq. 8)."""
    Gam = np.zeros((vcluster.size, 3, 12))
    if not n_bodies:
        return Gam
    _, r = _centres(np.asarray(vcluster, dtype=np.int64), np.ascontiguousarray(rest, dtype=float),
                    np.asarray(mass, dtype=float), int(n_bodies))
    red = vcluster >= 0
    for a in range(3):
        Gam[red, a, a] = 1.0
        Gam[:, a, 3 + 3 * a: 6 + 3 * a] = r
    return Gam


def rigid_rows(vcluster, x, mass, n_bodies):
    """Gamma_i = [I_3, -[x_i - x_c]_x] (n, 3, 6) in the current configuration; and the centres."""
    Gam = np.zeros((vcluster.size, 3, 6))
    if not n_bodies:
        return Gam, np.zeros((0, 3))
    red, _, com, r = centre_offsets(vcluster, x, mass, n_bodies)
    Gam[red, :, :3] = np.eye(3)
    Gam[red, 0, 4], Gam[red, 0, 5] = r[:, 2], -r[:, 1]
    Gam[red, 1, 3], Gam[red, 1, 5] = -r[:, 2], r[:, 0]
    Gam[red, 2, 3], Gam[red, 2, 4] = r[:, 1], -r[:, 0]
    return Gam, com


@njit(cache=True)
def _buckets(keys, n_keys):
    """Stable counting sort: ``order`` lists the positions of ``keys`` grouped by key, ``ptr`` (n_keys + 1) the groups."""
    ptr = np.zeros(n_keys + 1, dtype=np.int64)
    for i in range(keys.size):
        ptr[keys[i] + 1] += 1
    for k in range(n_keys):
        ptr[k + 1] += ptr[k]
    fill = ptr[:-1].copy()
    order = np.empty(keys.size, dtype=np.int64)
    for i in range(keys.size):
        order[fill[keys[i]]] = i
        fill[keys[i]] += 1
    return ptr, order


@njit(cache=True)
def _mapping_csr(free, vcluster, Gam, n_bodies):
    """G as CSR in one pass (exact zeros of Gamma left out), and the elastic free DOFs."""
    nf, w = free.size, Gam.shape[2]
    ecol = np.full(nf, -1, dtype=np.int64)
    ne = nnz = 0
    for k in range(nf):
        v, a = free[k] // 3, free[k] % 3
        if vcluster[v] < 0:
            ecol[k] = ne
            ne += 1
            nnz += 1
        else:
            for j in range(w):
                if Gam[v, a, j] != 0.0:
                    nnz += 1
    n_red = ne + w * n_bodies
    g_ptr = np.zeros(nf + 1, dtype=np.int32)
    g_ind = np.empty(nnz, dtype=np.int32)
    g_val = np.empty(nnz)
    p = 0
    for k in range(nf):
        if ecol[k] >= 0:
            g_ind[p], g_val[p] = ecol[k], 1.0
            p += 1
        else:
            v, a = free[k] // 3, free[k] % 3
            base = ne + w * vcluster[v]
            for j in range(w):
                if Gam[v, a, j] != 0.0:
                    g_ind[p], g_val[p] = base + j, Gam[v, a, j]
                    p += 1
        g_ptr[k + 1] = p
    elastic = np.empty(ne, dtype=np.int64)
    for k in range(nf):
        if ecol[k] >= 0:
            elastic[ecol[k]] = k
    return g_ptr, g_ind, g_val, elastic


@njit(cache=True)
def _body_normal_equations(g_ptr, g_ind, g_val, mdiag, v, n_elastic, w, n_bodies):
    """Per body G_b^T M G_b (w x w) and G_b^T M v (w) of eq. 9, lumped M."""
    MG = np.zeros((n_bodies, w, w))
    rhs = np.zeros((n_bodies, w))
    for k in range(g_ptr.size - 1):
        s, e = g_ptr[k], g_ptr[k + 1]
        if g_ind[s] < n_elastic:
            continue
        b = (g_ind[s] - n_elastic) // w
        o = n_elastic + w * b
        for p in range(s, e):
            gp = mdiag[k] * g_val[p]
            rhs[b, g_ind[p] - o] += gp * v[k]
            for q in range(s, e):
                MG[b, g_ind[p] - o, g_ind[q] - o] += gp * g_val[q]
    return MG, rhs


class Mapping:
    """The mapping G (free DOFs x reduced DOFs, eq. 7) of one frame.

    Elastic free DOFs keep an identity column each, in their order (``elastic_dofs``);
    body b owns the ``width`` columns ``n_elastic + width b + [0, width)``. G is built by one
    compiled pass over the free DOFs; products with G^T use ``G.T`` (scipy's transposed view,
    no copy).

    Parameters
    ----------
    free : (n_free,) int array
        The free DOFs.
    vcluster : (n,) int array
        Body of each vertex, -1 elastic.
    Gam : (n, 3, width) array
        The rows Gamma_i of reduced vertices, built from ``BodyKind.basis``.
    n_bodies : int
    kind : BodyKind
        :data:`AFFINE` or :data:`RIGID`.
    mass : (n,) array
        Lumped vertex masses (the rigid position update needs them).
    centres : (n_bodies, 3) array, optional
        The bodies' centres of mass the rows are taken about (rigid bodies).
    """

    def __init__(self, free, vcluster, Gam, n_bodies, kind, mass=None, centres=None):
        free = np.asarray(free, dtype=np.int64)
        vcluster = np.asarray(vcluster, dtype=np.int64)
        if Gam.shape[2] != kind.width:
            raise ValueError(f"rows of width {Gam.shape[2]} do not fit {kind.name} bodies (width {kind.width})")
        g_ptr, g_ind, g_val, el = _mapping_csr(free, vcluster, np.ascontiguousarray(Gam, float), int(n_bodies))
        self.kind, self.width, self.n_bodies = kind, kind.width, int(n_bodies)
        self.free, self.vcluster, self.rows = free, vcluster, Gam
        self.mass, self.centres = mass, centres
        self.elastic_dofs, self.n_elastic = el, el.size
        shape = (free.size, el.size + self.width * self.n_bodies)
        self.G = sp.csr_matrix((g_val, g_ind, g_ptr), shape=shape)

    @property
    def shape(self):
        return self.G.shape

    def project(self, mdiag, v):
        """q = (G^T M G)^-1 G^T M v (eq. 9), lumped M: elastic entries copied, one w x w solve per body."""
        v = np.asarray(v, dtype=float)
        q = np.empty(self.G.shape[1])
        q[:self.n_elastic] = v[self.elastic_dofs]
        if self.n_bodies:
            G = self.G
            MG, rhs = _body_normal_equations(G.indptr, G.indices, G.data, np.asarray(mdiag, float), v,
                                             self.n_elastic, self.width, self.n_bodies)
            q[self.n_elastic:] = np.linalg.solve(MG, rhs[..., None])[..., 0].ravel()
        return q

    def positions(self, x, v, dt):
        """x_{t+1} (n, 3) from x_t and v_{t+1}: the body kind's update (:meth:`BodyKind.positions`)."""
        return self.kind.positions(self, x, v, dt)

    def velocities(self, x, v, x_new):
        """v_{t+1} (n, 3) at x_new from the solved v (:meth:`BodyKind.velocities`)."""
        return self.kind.velocities(self, x, v, x_new)

    def elimination_order(self, vertex_rank):
        """A fill-reducing order of the reduced DOFs inherited from the full mesh's order.

        Elastic DOFs keep their vertex's rank in ``vertex_rank`` (a nested-dissection order of
        the free vertices, :func:`nested_dissection_rank`); a body's DOFs come right after its
        latest vertex, as if the body were part of the separator that vertex belongs to. Our
        choice (the paper is silent): it spares the direct solver its ordering step, which on
        reduced systems whose clusters change every frame costs as much as the factorisation,
        and the resulting order is as good as the solver's own (measurements: the user guide's
        Affinification page). Returns the reduced DOFs in elimination order (int32).
        """
        free, vcluster = self.free, self.vcluster
        ne, w = self.n_elastic, self.width
        key = np.empty(self.shape[1])
        fe = np.asarray(free)[self.elastic_dofs]
        key[:ne] = 3 * vertex_rank[fe // 3] + fe % 3
        if self.n_bodies:
            red = np.flatnonzero(vcluster >= 0)
            top = np.full(self.n_bodies, -1.0)
            np.maximum.at(top, vcluster[red], vertex_rank[red])
            key[ne:] = ((3 * top + 2)[:, None] + (np.arange(w) + 1.0) / (w + 1)).ravel()
        return np.argsort(key, kind="stable").astype(np.int32)


def nested_dissection_rank(system):
    """Position of every vertex in a nested-dissection order (METIS) of the free vertices' graph; -1 if fixed."""
    vptr, vind = system.pattern.vertex_graph()
    nv = vptr.size - 1
    P = sp.csr_matrix((np.ones(vind.size), vind, vptr), shape=(nv, nv))
    P.setdiag(0)  # METIS takes no self-loops
    P.eliminate_zeros()
    pymetis = require("pymetis", "the Pardiso solver's METIS ordering of reduced frames", "fast")
    try:
        _, iperm = pymetis.nested_dissection(adjacency=pymetis.CSRAdjacency(P.indptr, P.indices))
        iperm = np.asarray(iperm, dtype=np.int64)
    except Exception:  # tiny or edgeless graphs: the given order
        iperm = np.arange(nv)
    rank = np.full(system.n, -1, dtype=np.int64)
    rank[system.free[::3] // 3] = iperm
    return rank


def affine_mapping(free, vcluster, rest, mass, n_bodies):
    """G of eq. 7 for affine bodies: rows of :func:`affine_rows` about the rest centres of mass."""
    return Mapping(free, vcluster, affine_rows(vcluster, rest, mass, n_bodies), n_bodies, AFFINE, mass=mass)


def rigid_mapping(free, vcluster, x, mass, n_bodies):
    """G for rigid bodies (6 DOFs each): rows of :func:`rigid_rows` about the current centres of mass."""
    Gam, com = rigid_rows(vcluster, x, mass, n_bodies)
    return Mapping(free, vcluster, Gam, n_bodies, RIGID, mass=mass, centres=com)


def interior_elements(vcluster, t):
    """(m,) bool: the elements whose four vertices belong to one body."""
    vt = vcluster[t]
    return (vt[0] >= 0) & np.all(vt == vt[0], axis=0)


def discrepancy(G, q, v):
    """d = G q - v (eq. 11)."""
    return G @ q - v


def lift(G, dq, d):
    """dv = G dq + d (eq. 12)."""
    return G @ dq + d


@njit(cache=True)
def _reduced_layout(vc, n_bodies, w, vptr, vind):
    """Nodes of the reduced system and the upper-triangle CSR pattern of G^T A G.

    Free vertex u is node ``node[u]``: its own (3 DOFs, columns 3 e .. 3 e + 2 for the e-th
    elastic vertex) when elastic, else its body's (w DOFs after all elastic ones); node ids
    follow column order. Nodes couple when two of their vertices do in the vertex graph
    (vptr, vind). Returns node, start, size, the members of each node (CSR mptr, members),
    the node graph (upper, diagonal first, then ascending; ``noff`` = offset of each coupled
    node's columns in a row after the diagonal block) and the scalar CSR (indptr, indices).
    """
    nv = vc.size
    node = np.empty(nv, dtype=np.int64)
    n_el = 0
    for u in range(nv):
        if vc[u] < 0:
            node[u] = n_el
            n_el += 1
    N = n_el + n_bodies
    start = np.empty(N, dtype=np.int64)
    size = np.empty(N, dtype=np.int64)
    for u in range(nv):
        if vc[u] >= 0:
            node[u] = n_el + vc[u]
        else:
            start[node[u]], size[node[u]] = 3 * node[u], 3
    for b in range(n_bodies):
        start[n_el + b], size[n_el + b] = 3 * n_el + w * b, w
    mptr, members = _buckets(node, N)  # the vertices of each node
    # node graph, upper part
    nptr = np.zeros(N + 1, dtype=np.int64)
    nind = np.empty(vind.size + N, dtype=np.int64)
    marker = np.full(N, -1, dtype=np.int64)
    k = 0
    for R in range(N):
        nind[k] = R
        k += 1
        first = k
        marker[R] = R
        for p in range(mptr[R], mptr[R + 1]):
            u = members[p]
            for q in range(vptr[u], vptr[u + 1]):
                C = node[vind[q]]
                if C > R and marker[C] != R:
                    marker[C] = R
                    nind[k] = C
                    k += 1
        nind[first:k] = np.sort(nind[first:k])
        nptr[R + 1] = k
    nind = nind[:k].copy()
    noff = np.zeros(k, dtype=np.int64)
    n_red = 3 * n_el + w * n_bodies
    indptr = np.zeros(n_red + 1, dtype=np.int32)
    for R in range(N):
        off = 0
        for p in range(nptr[R] + 1, nptr[R + 1]):
            noff[p] = off
            off += size[nind[p]]
        for i in range(size[R]):
            indptr[start[R] + i + 1] = indptr[start[R] + i] + size[R] - i + off
    indices = np.empty(indptr[n_red], dtype=np.int32)
    for R in range(N):
        for i in range(size[R]):
            c = indptr[start[R] + i]
            for j in range(i, size[R]):
                indices[c] = start[R] + j
                c += 1
            for p in range(nptr[R] + 1, nptr[R + 1]):
                C = nind[p]
                for j in range(size[C]):
                    indices[c] = start[C] + j
                    c += 1
    return node, start, size, mptr, members, nptr, nind, noff, indptr, indices


@njit(cache=True, inline="always")
def _entry(nptr, nind, R, C):
    """Position of node C in node R's row of the node graph (C >= R): the diagonal first, then bisection."""
    if C == R:
        return nptr[R]
    lo, hi = nptr[R] + 1, nptr[R + 1]
    while lo < hi:
        mid = (lo + hi) // 2
        if nind[mid] < C:
            lo = mid + 1
        else:
            hi = mid
    return lo


def _basis(entries):
    """The nonzeros (s, row a, column p, value) of the E_s in Gamma_i = sum_s rho_i[s] E_s,
    rho_i = (1, r_i), as the arrays (s, a, p) int64 and values float64 of :func:`_reduced_upper_data`."""
    return np.array([e[:3] for e in entries], dtype=np.int64).T, np.array([e[3] for e in entries])


class BodyKind:
    """How the vertices of one kind of reduced body move.

    Attributes
    ----------
    name : str
    width : int
        Reduced DOFs per body.
    basis : ((3, k) int array, (k,) array)
        Gamma_i = sum_s rho_i[s] E_s with rho_i = (1, r_i): the nonzeros of the E_s.
    interior_exact : bool
        Elements inside one body have B_e G_e = [0 | I_9] (affine bodies), so that
        :func:`reduced_matrix` may add their V_e C_e to the body's columns without their blocks.
    """

    name, width, basis, interior_exact = "body", 0, None, False

    def offsets(self, Gam):
        """r_i back from the rows Gamma_i (n, 3, width)."""
        raise NotImplementedError

    def positions(self, mapping, x, v, dt):
        """x_{t+1} = x + h v (symplectic Euler, Algorithm 1)."""
        return x + dt * v

    def velocities(self, mapping, x, v, x_new):
        """v_{t+1} at the new positions x_new, from the solved v at x_t: v itself."""
        return v


class AffineBody(BodyKind):
    """12 DOFs: translation and the 9 entries of the affine matrix (row-major), about the rest centre."""

    name, width, interior_exact = "affine", 12, True
    basis = _basis([(0, a, a, 1.0) for a in range(3)] + [(q + 1, a, 3 + 3 * a + q, 1.0)
                                                         for a in range(3) for q in range(3)])

    def offsets(self, Gam):
        return Gam[:, 0, 3:6]


class RigidBody(BodyKind):
    """6 DOFs: velocity of the centre and angular velocity, v_i = v_c + omega x (x_i - x_c).

    Positions rotate exactly (exponential map) about the centre, so that bodies do not grow.
    """

    name, width = "rigid", 6
    basis = _basis([(0, a, a, 1.0) for a in range(3)] + [(3, 0, 4, 1.0), (2, 0, 5, -1.0), (3, 1, 3, -1.0),
                                                         (1, 1, 5, 1.0), (2, 2, 3, 1.0), (1, 2, 4, -1.0)])

    def offsets(self, Gam):
        return np.stack([Gam[:, 1, 5], Gam[:, 2, 3], Gam[:, 0, 4]], axis=1)

    @staticmethod
    def _motion(mapping, x, v):
        """The rigid vertices, their bodies, masses and offsets r from the centres, and each body's
        centre velocity and angular velocity w = I^-1 L about its centre, from the (rigid) vertex
        velocities v (n, 3) at x."""
        vc = mapping.vcluster
        red = np.flatnonzero(vc >= 0)
        c = vc[red]
        n_bodies = mapping.centres.shape[0]
        m = mapping.mass[red]
        mt = np.bincount(c, weights=m, minlength=n_bodies)
        vcom = group_sum(c, m[:, None] * v[red], n_bodies) / mt[:, None]
        r = x[red] - mapping.centres[c]
        L = group_sum(c, m[:, None] * np.cross(r, v[red] - vcom[c]), n_bodies)
        return red, c, m, r, vcom, np.linalg.solve(_inertia(c, m, r, n_bodies), L[..., None])[..., 0], L

    def positions(self, mapping, x, v, dt):
        """x + h v for elastic vertices; exact rotation about the centre for rigid ones."""
        x_new = x + dt * v
        if not np.any(mapping.vcluster >= 0):
            return x_new
        red, c, m, r, vcom, w, L = self._motion(mapping, x, v)
        # turn by the mean of w at x_t and w = I^-1 L at the body turned by h w (L kept): the rotation
        # then follows a torque-free body's precession to second order, its energy drifting less
        I = _inertia(c, m, r, mapping.centres.shape[0])
        R = rotation(dt * w)
        w_end = np.linalg.solve(R @ I @ np.swapaxes(R, 1, 2), L[..., None])[..., 0]
        R = rotation(0.5 * dt * (w + w_end))
        x_new[red] = mapping.centres[c] + dt * vcom[c] + np.einsum("vij,vj->vi", R[c], r)
        return x_new

    def velocities(self, mapping, x, v, x_new):
        """v_{t+1} of rigid vertices at their new positions x_new: the centre velocity and the angular
        momentum L = I(x_t) w of v at x_t kept, w_{t+1} = I(x_new)^-1 L, v_i = v_c + w_{t+1} x r_i(x_new).

        A rigid body's rotation turns its inertia; carrying w unchanged (or the vertex velocities of
        x_t) to the turned body would change L without a torque."""
        if not np.any(mapping.vcluster >= 0):
            return v
        red, c, m, _, vcom, _, L = self._motion(mapping, x, v)
        n_bodies = mapping.centres.shape[0]
        mt = np.bincount(c, weights=m, minlength=n_bodies)
        centres = group_sum(c, m[:, None] * x_new[red], n_bodies) / mt[:, None]
        r = x_new[red] - centres[c]
        w = np.linalg.solve(_inertia(c, m, r, n_bodies), L[..., None])[..., 0]
        v_new = v.copy()
        v_new[red] = vcom[c] + np.cross(w[c], r)
        return v_new


def _inertia(c, m, r, n_bodies):
    """Inertia tensors sum m (|r|^2 I - r r^T) of the bodies c of vertices with masses m, offsets r."""
    rr = np.einsum("vi,vi->v", r, r)
    I = group_sum(c, m[:, None, None] * (rr[:, None, None] * np.eye(3) - r[:, :, None] * r[:, None, :]), n_bodies)
    return I + 1e-300 * np.eye(3)


AFFINE, RIGID = AffineBody(), RigidBody()


def rotation(phi):
    """Rotation matrices exp([phi]_x) (Rodrigues), phi (k, 3)."""
    theta = np.linalg.norm(phi, axis=1)
    small = theta < 1e-12
    k = np.where(small[:, None], 0.0, phi / np.where(small, 1.0, theta)[:, None])
    K = np.zeros((phi.shape[0], 3, 3))
    K[:, 0, 1], K[:, 0, 2], K[:, 1, 2] = -k[:, 2], k[:, 1], -k[:, 0]
    K[:, 1, 0], K[:, 2, 0], K[:, 2, 1] = k[:, 2], -k[:, 1], k[:, 0]
    s, c = np.sin(theta)[:, None, None], np.cos(theta)[:, None, None]
    return np.eye(3) + s * K + (1 - c) * (K @ K)


@njit(cache=True)
def _reduced_upper_data(layout, vptr, vind, a_ptr, h_val, m_val, lumped, ck, cm, rho, b_s, b_a, b_p, b_g):
    """Values of the upper triangle of G^T A G on the pattern of :func:`_reduced_layout` (eq. 10).

    With Gamma_v = sum_s rho_v[s] E_s (rho_v = (1, r_v); elastic vertices: rho = (1), E_0 = I),
    the block of nodes (R, C) is sum_{s', s} E_s'^T T_RC[s', s] E_s with
    T_RC[s', s] = sum_{u in R, v in C} rho_u[s'] rho_v[s] A_uv (A_uv the 3 x 3 blocks of the
    assembled A = cm M + ck H: ``h_val`` on the pattern, ``m_val`` the mass on the pattern too or,
    if ``lumped``, its diagonal per free DOF, which spares reading a second array of the pattern's
    size (the data arrive cold from memory in a frame); T stored as
    [s', a, b, s]). T is gathered vertex by vertex u in two dense stages, S = sum_v A_uv rho_v[s]
    per coupled node (36 multiply-adds per neighbour) and T += rho_u (x) S, then expanded once
    per node pair through the nonzeros (b_s, b_a, b_p, b_g) of the body basis E_s. A's rows
    must hold the 3 x 3 block of each vertex neighbour in vertex-graph order (as the assembly
    pattern does).
    """
    node, start, size, mptr, members, nptr, nind, noff, indptr, indices = layout
    N = start.size
    nr = np.empty(N, dtype=np.int64)
    for R in range(N):
        nr[R] = 1 if size[R] == 3 else 4
    toff = np.zeros(nind.size + 1, dtype=np.int64)
    for R in range(N):
        for p in range(nptr[R], nptr[R + 1]):
            toff[p + 1] = toff[p] + 9 * nr[R] * nr[nind[p]]
    T = np.zeros(toff[nind.size])
    deg = 0
    for u in range(vptr.size - 1):
        deg = max(deg, vptr[u + 1] - vptr[u])
    S = np.zeros((deg, 36))
    touched = np.empty(nind.size, dtype=np.int64)
    slot = np.empty(nind.size, dtype=np.int64)
    seen = np.full(nind.size, -1, dtype=np.int64)
    for R in range(N):
        for mp in range(mptr[R], mptr[R + 1]):
            u = members[mp]
            nt = 0
            for q in range(vptr[u], vptr[u + 1]):
                v = vind[q]
                C = node[v]
                if C < R:
                    continue
                pe = _entry(nptr, nind, R, C)
                if seen[pe] != u:
                    seen[pe] = u
                    slot[pe] = nt
                    touched[nt] = pe
                    for x in range(9 * nr[C]):
                        S[nt, x] = 0.0
                    nt += 1
                c = slot[pe]
                k = q - vptr[u]
                r0, r1, r2 = rho[v, 1], rho[v, 2], rho[v, 3]
                for a in range(3):
                    row = a_ptr[3 * u + a] + 3 * k
                    for b in range(3):
                        val = ck * h_val[row + b]
                        if not lumped:
                            val += cm * m_val[row + b]
                        elif v == u and a == b:
                            val += cm * m_val[3 * u + a]
                        if nr[C] == 1:
                            S[c, 3 * a + b] += val
                        else:
                            o = 4 * (3 * a + b)
                            S[c, o] += val
                            S[c, o + 1] += val * r0
                            S[c, o + 2] += val * r1
                            S[c, o + 3] += val * r2
            for c in range(nt):
                pe = touched[c]
                n9 = 9 * nr[nind[pe]]
                for s2 in range(nr[R]):
                    f = rho[u, s2]
                    base = toff[pe] + s2 * n9
                    for x in range(n9):
                        T[base + x] += f * S[c, x]
    data = np.zeros(indices.size)
    nb = b_s.size
    for R in range(N):
        tr = 3 if nr[R] == 1 else nb
        for pe in range(nptr[R], nptr[R + 1]):
            C = nind[pe]
            tc = 3 if nr[C] == 1 else nb
            for i1 in range(tr):
                s1, a, p1, g1 = (0, i1, i1, 1.0) if nr[R] == 1 else (b_s[i1], b_a[i1], b_p[i1], b_g[i1])
                row = indptr[start[R] + p1]
                for i2 in range(tc):
                    s2, b, p2, g2 = (0, i2, i2, 1.0) if nr[C] == 1 else (b_s[i2], b_a[i2], b_p[i2], b_g[i2])
                    val = g1 * g2 * T[toff[pe] + 9 * nr[C] * s1 + (3 * a + b) * nr[C] + s2]
                    if C == R:
                        if p2 >= p1:
                            data[row + p2 - p1] += val
                    else:
                        data[row + size[R] - p1 + noff[pe] + p2] += val
    return data


def reduced_matrix(model, data, gmap, upper=False):
    """G^T A G (CSR) with A = (1 + h alpha) M + (h beta + h^2) H (eq. 10), never forming A G.

    Parameters
    ----------
    model : Model
        The system and the coefficients of A (:func:`~skfem_affine.integrators.problem.system_coefficients`).
    data : FrameData
        The frame's evaluation (``H`` data on the system's pattern). Without H
        (``data.He is None``, from :meth:`ElasticSystem.evaluate_tangent`), element blocks are
        assembled here for the elements that need them (below).
    gmap : Mapping
        The frame's G; its body kind says whether the interior shortcut below applies.
    upper : bool
        Return only the upper triangle, rows sorted (what a Cholesky solver reads).

    Notes
    -----
    The pattern (:func:`_reduced_layout`) is the vertex graph contracted by the bodies; the
    values (:func:`_reduced_upper_data`) come vertex by vertex from the 3 x 3 blocks of A,
    weighted by (1, r_v) in dense per-node-pair buffers and expanded once per pair of nodes:
    the cost is linear in the nonzeros of A. When the blocks are not at hand, elements inside
    one affine body are left out of A and add V_e C_e to the body's 9 affine columns instead: for them
    B_e G_e = [0 | I_9] because sum_k r_k (x) grad phi_k = I, so their 12 x 12 triple
    product is never formed.
    """
    sysm = model.system
    cm, ck = model.coefficients
    vcluster = gmap.vcluster
    pat = sysm.pattern
    w, n_bodies = gmap.width, gmap.n_bodies
    K9 = None
    if data.He is None:
        vt = vcluster[sysm.t]  # (4, m)
        inside = interior_elements(vcluster, sysm.t) if (gmap.kind.interior_exact and n_bodies) else np.zeros(sysm.m, bool)
        _, Hdata = sysm.partial_stiffness(data, np.flatnonzero(~inside))
        if np.any(inside):
            e_in = np.flatnonzero(inside)
            K9 = group_sum(vt[0, e_in], sysm.volumes[e_in, None] * data.C[e_in].reshape(-1, 81), n_bodies)
    else:
        Hdata = data.H
    if not n_bodies and not upper:  # G = I
        return pat.matrix(cm * sysm.mass_data + ck * Hdata)
    fv = sysm.free[::3] // 3  # free vertex u owns free DOFs 3u, 3u + 1, 3u + 2
    vptr, vind = pat.vertex_graph()
    layout = _reduced_layout(np.ascontiguousarray(vcluster[fv], dtype=np.int64), n_bodies, w, vptr, vind)
    G = gmap.G
    rho = np.ones((fv.size, 4))
    rho[:, 1:] = gmap.kind.offsets(gmap.rows[fv])
    (b_s, b_a, b_p), b_g = gmap.kind.basis
    lumped = sysm.mass_kind == "lumped"
    mass = sysm.Mff.diagonal() if lumped else sysm.mass_data
    vals = _reduced_upper_data(layout, vptr, vind, pat.indptr, Hdata, mass, lumped, ck, cm, rho, b_s, b_a, b_p, b_g)
    indptr, indices = layout[8], layout[9]
    if K9 is not None:  # V_e C_e of interior elements on each body's 9 affine columns (upper part)
        r, c = np.triu_indices(9)
        rows = gmap.n_elastic + w * np.arange(n_bodies)[:, None] + 3 + r  # (n_bodies, 45)
        vals[indptr[rows] + (c - r)] += ck * K9[:, 9 * r + c]
    U = sp.csr_matrix((vals, indices, indptr), shape=(G.shape[1],) * 2)
    if upper:
        return U
    return (U + U.T - sp.diags(U.diagonal())).tocsr()
