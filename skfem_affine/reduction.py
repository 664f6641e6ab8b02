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
"""
import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg  # noqa: F401  (sp.linalg)

from ._kernels import reduced_boundary_blocks


def group_sum(groups, values, n_groups):
    """Sum rows of ``values`` (k, ...) by group id (k,) into (n_groups, ...); a fast np.add.at."""
    values = np.asarray(values, dtype=float)
    width = int(np.prod(values.shape[1:]))
    flat = (groups[:, None] * width + np.arange(width)).ravel()
    out = np.bincount(flat, weights=values.reshape(-1), minlength=n_groups * width)
    return out.reshape((n_groups,) + values.shape[1:])


def vertex_clusters(labels, t, n_vertices):
    """Body of each vertex (n,), -1 elastic, from per-element labels (vertex-disjoint clusters)."""
    vc = np.full(n_vertices, -1, dtype=np.int64)
    red = np.flatnonzero(labels >= 0)
    vc[t[:, red].ravel()] = np.tile(labels[red], 4)
    return vc


def centre_offsets(vcluster, positions, mass, n_bodies):
    """Reduced vertices, their bodies, the bodies' centres of mass and the offsets r = x - x_c."""
    red = np.flatnonzero(vcluster >= 0)
    c = vcluster[red]
    m = mass[red]
    com = group_sum(c, m[:, None] * positions[red], n_bodies) / np.bincount(c, weights=m, minlength=n_bodies)[:, None]
    return red, c, com, positions[red] - com[c]


def affine_rows(vcluster, rest, mass, n_bodies):
    """Gamma_i = [I_3, I_3 (x) r_i^T] (n, 3, 12), r_i = X_i - X_c in the rest frame (eq. 8)."""
    Gam = np.zeros((vcluster.size, 3, 12))
    if not n_bodies:
        return Gam
    red, _, _, r = centre_offsets(vcluster, rest, mass, n_bodies)
    Gam[red, :, :3] = np.eye(3)
    Gam[red, :, 3:] = np.einsum("ab,vq->vabq", np.eye(3), r).reshape(-1, 3, 9)
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


def assemble_G(free, vcluster, Gam, elastic_dofs, n_bodies, w):
    """Sparse G (free DOFs x reduced DOFs): identity on elastic DOFs, Gamma_i rows on reduced vertices (eq. 7)."""
    nf = free.size
    ne = elastic_dofs.size
    rows = [elastic_dofs]
    cols = [np.arange(ne)]
    vals = [np.ones(ne)]
    if n_bodies:
        red = np.flatnonzero(vcluster[free // 3] >= 0)  # free DOFs of reduced vertices
        v, a = free[red] // 3, free[red] % 3
        c = vcluster[v]
        rows.append(np.repeat(red, w))
        cols.append((ne + w * c[:, None] + np.arange(w)).ravel())
        vals.append(Gam[v, a].ravel())
    G = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                      shape=(nf, ne + w * n_bodies))
    G.eliminate_zeros()
    return G


def project(G, mdiag, v):
    """q = (G^T M G)^-1 G^T M v (eq. 9), lumped M; G^T M G is block diagonal."""
    GtMG = (G.T @ sp.diags(mdiag) @ G).tocsc()
    return sp.linalg.spsolve(GtMG, G.T @ (mdiag * v))


def discrepancy(G, q, v):
    """d = G q - v (eq. 11)."""
    return G @ q - v


def lift(G, dq, d):
    """dv = G dq + d (eq. 12)."""
    return G @ dq + d


def reduced_matrix(sim, data, vcluster, Gam, n_bodies, elastic_dofs, affine=True, blocks=None):
    """G^T A G (CSR) with A = (1 + h alpha) M + (h beta + h^2) H, assembled per element (eq. 10).

    Parameters
    ----------
    data : FrameData of the frame (element blocks ``He``, dP/dF ``C``, ``H`` data). Without
        blocks (``data.He is None``, from :meth:`ElasticSystem.evaluate_tangent`), blocks are
        assembled here for the elements that need them: all but those inside one affine body.
    vcluster : (n,) body of each vertex, -1 elastic.
    Gam : (n, 3, w) the rows of G of each reduced vertex (eq. 8; w = 12 affine, 6 rigid).
    n_bodies : number of reduced bodies.
    elastic_dofs : free-DOF indices that stay elastic, in the order of the reduced
        columns; body b then owns columns ``len(elastic_dofs) + w b + [0, w)``.
    affine : use the exact shortcut for elements inside one affine body, whose
        reduced stiffness is V_e C_e on the body's 9 affine columns.
    """
    sysm, h, d = sim.system, sim.dt, sim.damping
    cm, ck = 1.0 + h * d.alpha, h * d.beta + h * h
    pat = sysm.pattern
    w = Gam.shape[2]
    vc = vcluster[sysm.t]  # (4, m)
    interior = (vc[0] >= 0) & np.all(vc == vc[0], axis=0) if (affine and n_bodies) else np.zeros(sysm.m, bool)
    if data.He is None:
        need = np.flatnonzero(~interior)
        He, Hdata = sysm.partial_stiffness(data, need)
        he_row = np.full(sysm.m, -1, dtype=np.int64)
        he_row[need] = np.arange(need.size)
    else:
        He, Hdata, he_row = data.He, data.H, np.arange(sysm.m)
    ne = elastic_dofs.size
    size = ne + w * n_bodies
    # elastic-elastic block: the full matrix restricted to elastic DOFs (G = I there)
    red_of_free = np.full(pat.shape[0], -1, dtype=np.int64)
    red_of_free[elastic_dofs] = np.arange(ne)
    Adata = cm * sysm.mass_data + ck * Hdata
    rr, cc = red_of_free[pat.rows], red_of_free[pat.indices]
    keep = (rr >= 0) & (cc >= 0)
    # a row/column subset of a CSR pattern in increasing order is itself sorted CSR
    indptr = np.concatenate([[0], np.cumsum(np.bincount(rr[keep], minlength=size))])
    A_ee = sp.csr_matrix((Adata[keep], cc[keep], indptr), shape=(size, size))
    parts = []
    if n_bodies:
        ccol = ne + w * np.arange(n_bodies)
        # lumped mass: sum_i m_i Gamma_i^T Gamma_i per body
        red = np.flatnonzero(vcluster >= 0)
        B = cm * group_sum(vcluster[red], sysm.lumped_mass[red, None, None]
                           * np.einsum("vai,vaj->vij", Gam[red], Gam[red]), n_bodies)
        touching = np.any(vc >= 0, axis=0)
        if affine:
            # elements inside one affine body: B_e G_e = [0 | I_9], reduced stiffness V_e C_e
            e_in = np.flatnonzero(interior)
            K9 = group_sum(vc[0, e_in], sysm.volumes[e_in, None] * data.C[e_in].reshape(-1, 81), n_bodies)
            B[:, 3:, 3:] += ck * K9.reshape(-1, 9, 9)
            touching &= ~interior
        e_b = np.flatnonzero(touching)
        if e_b.size:
            parts += _boundary_parts(sysm, e_b, He, he_row[e_b], vcluster, Gam, n_bodies, red_of_free, ccol, B, ck)
        idx = ccol[:, None] + np.arange(w)
        parts.append((np.broadcast_to(idx[:, :, None], B.shape).ravel(),
                      np.broadcast_to(idx[:, None, :], B.shape).ravel(), B.ravel()))
    if not parts:
        return A_ee
    R = np.concatenate([p[0] for p in parts])
    C = np.concatenate([p[1] for p in parts])
    V = np.concatenate([p[2] for p in parts])
    A = A_ee + sp.csr_matrix((V, (R, C)), shape=(size, size))
    A.sort_indices()
    return A


def _pair_index(valid, key):
    """Index of each valid (4, 4, nb) key among the unique valid keys (-1 elsewhere), as (nb, 4, 4)."""
    idx = np.full(key.shape, -1, dtype=np.int64)
    u, inv = np.unique(key[valid], return_inverse=True)
    idx[valid] = inv
    return idx.transpose(2, 0, 1), u


def _boundary_parts(sysm, e_b, He, he_row, vcluster, Gam, n_bodies, red_of_free, ccol, B, ck):
    """Reduced stiffness of elements on body boundaries, summed per (elastic vertex, body) and
    (body, body) pair before it becomes COO entries; body-internal pairs go into B in place."""
    w = Gam.shape[2]
    V = sysm.t[:, e_b]                               # (4, nb)
    Cv = vcluster[V]
    ck_, cl_ = Cv[:, None, :], Cv[None, :, :]        # (4, 4, nb) row and column bodies
    vk = np.broadcast_to(V[:, None, :], ck_.shape[:1] + (4,) + V.shape[1:])
    is_eb = (ck_ < 0) & (cl_ >= 0)
    is_bb = (ck_ >= 0) & (cl_ >= 0) & (ck_ != cl_)
    pair_eb, u_eb = _pair_index(is_eb, vk * n_bodies + cl_)
    pair_bb, u_bb = _pair_index(is_bb, ck_ * n_bodies + cl_)
    EB = np.zeros((u_eb.size, 3, w))
    BB = np.zeros((u_bb.size, w, w))
    Bk = np.zeros_like(B)
    reduced_boundary_blocks(sysm.t, e_b, he_row, He, vcluster, np.ascontiguousarray(Gam),
                            np.ascontiguousarray(pair_eb), np.ascontiguousarray(pair_bb), Bk, EB, BB)
    B += ck * Bk
    parts = []
    if u_eb.size:
        vtx, body = u_eb // n_bodies, u_eb % n_bodies
        free_of = np.full(3 * sysm.n, -1, dtype=np.int64)
        free_of[sysm.free] = np.arange(sysm.free.size)
        fo = free_of.reshape(-1, 3)[vtx]             # (p, 3) free index of the elastic DOFs
        rows = np.where(fo >= 0, red_of_free[np.maximum(fo, 0)], -1)
        rr = np.broadcast_to(rows[:, :, None], EB.shape)
        cc = np.broadcast_to((ccol[body][:, None] + np.arange(w))[:, None, :], EB.shape)
        ok = rr >= 0
        vals = ck * EB[ok]
        parts += [(rr[ok], cc[ok], vals), (cc[ok], rr[ok], vals)]  # and the transpose
    if u_bb.size:
        b1, b2 = u_bb // n_bodies, u_bb % n_bodies
        rr = np.broadcast_to((ccol[b1][:, None] + np.arange(w))[:, :, None], BB.shape)
        cc = np.broadcast_to((ccol[b2][:, None] + np.arange(w))[:, None, :], BB.shape)
        parts.append((rr.ravel(), cc.ravel(), ck * BB.ravel()))
    return parts
