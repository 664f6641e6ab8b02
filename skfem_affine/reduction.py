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

from ._kernels import reduced_upper


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


def reduced_matrix(sim, data, vcluster, Gam, n_bodies, elastic_dofs, affine=True, G=None, upper=False):
    """G^T A G (CSR) with A = (1 + h alpha) M + (h beta + h^2) H (eq. 10).

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
    G : the mapping of :func:`assemble_G` if already built.
    upper : return only the upper triangle (what a Cholesky solver reads).

    The product is formed in two sparse passes, Y = A G (every nonzero of A meets at
    most four entries of G) and the upper triangle of G^T Y in one compiled pass
    (:func:`_kernels.reduced_upper`), so the cost is linear in the nonzeros of A. Elements inside one
    affine body are left out of A and enter as V_e C_e: for them B_e G_e = [0 | I_9]
    because sum_k r_k (x) grad phi_k = I, so their 12 x 12 triple product is never formed.
    """
    sysm, h, d = sim.system, sim.dt, sim.damping
    cm, ck = 1.0 + h * d.alpha, h * d.beta + h * h
    pat = sysm.pattern
    w = Gam.shape[2]
    if G is None:
        G = assemble_G(sysm.free, vcluster, Gam, elastic_dofs, n_bodies, w)
    vc = vcluster[sysm.t]  # (4, m)
    blocks = np.zeros((0, w, w))
    if data.He is None:
        interior = (vc[0] >= 0) & np.all(vc == vc[0], axis=0) if (affine and n_bodies) else np.zeros(sysm.m, bool)
        _, Hdata = sysm.partial_stiffness(data, np.flatnonzero(~interior))
        if np.any(interior):
            e_in = np.flatnonzero(interior)
            K9 = group_sum(vc[0, e_in], sysm.volumes[e_in, None] * data.C[e_in].reshape(-1, 81), n_bodies)
            blocks = np.zeros((n_bodies, w, w))
            blocks[:, 3:, 3:] = ck * K9.reshape(-1, 9, 9)
    else:
        Hdata = data.H
    Adata = cm * sysm.mass_data + ck * Hdata
    if not n_bodies and not upper:  # G = I
        return pat.matrix(Adata)
    G = sp.csr_matrix(G)
    Y = pat.matrix(Adata) @ G  # scipy's SpGEMM: 1.7x a numba Gustavson pass here
    Gt = G.T.tocsr()
    indptr, indices, vals = reduced_upper(Gt.indptr, Gt.indices, Gt.data, Y.indptr, Y.indices, Y.data,
                                          elastic_dofs.size, blocks)
    U = sp.csr_matrix((vals, indices, indptr), shape=(G.shape[1],) * 2)
    if upper:
        return U
    return (U + U.T - sp.diags(U.diagonal())).tocsr()
