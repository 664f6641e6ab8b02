r"""The error/progress oracle of the adaptive-subspace paper (sec. 3.3-3.5, eq. 5-17).

All quantities are per vertex over the whole mesh; fixed vertices never become candidates.
With the incremental potential's weight :math:`w = a h^2` (h^2 for implicit Euler, 4h^2/9 for
BDF2, where the paper writes h^2):

* error scaling (eq. 5): :math:`n_i = w\,A_i\,\bar H_i`, with :math:`A_i` the area of the
  surface of node i's one-ring (the sum of the faces opposite i, :math:`A_{ei} = 3V_e\|\nabla\phi_i\|`)
  and :math:`\bar H_i` the mean over the one-ring of :math:`\|\partial^2 W_e(I)/\partial F^2\|_F`,
  the rest Hessian norm of the energy density;
* progress scaling (eq. 8): :math:`m_i = w\,V_i\,\bar H_i`, :math:`V_i = \sum_{e \ni i} V_e/4`;
* nodal error (eq. 9-10): :math:`G_i = \|g_i\|/n_i` where :math:`g_i` is the gradient of the
  one-ring's energy :math:`\sum_{e\ni i} w V_e W_e` over all one-ring DOFs, plus node i's own
  inertia, gravity, damping and contact-barrier gradient (point stencils);
* nodal progress (eq. 7, 11): :math:`E_i = \Delta E_i / m_i`, :math:`\Delta E_i = E_i(x) - E_i(x + d_u)`
  with :math:`E_i` node i's share of E: point terms and a quarter of each one-ring element energy
  (the shares sum to E, the "stencil-size weighting");
* modal error and progress for blocks of modes (eq. 12-17): the gradient projected on the block's
  (orthonormal) columns, :math:`G_j = \max_i \|g_j^i\|/n_i`, and the energy change projected on
  the per-vertex coordinate averages :math:`\bar u`, :math:`E_j = \sum_i \Delta E_j^i / m_i`.
"""
import numpy as np
import scipy.sparse as sp


def rest_hessian_norms(system):
    """||d^2 W_e / dF^2 (I)||_F per element (the rest Hessian of the energy density)."""
    eye = np.broadcast_to(np.eye(3), (system.m, 3, 3)).copy()
    _, C = system.stresses(eye, tangent=True, project=False)
    return np.linalg.norm(C.reshape(system.m, -1), axis=1)


def node_scaling(system):
    """Geometric-material parts A_i H_i (eq. 5) and V_i H_i (eq. 8), per vertex; multiply by w."""
    t, n = system.t, system.n
    Hn = rest_hessian_norms(system)
    count = np.bincount(t.ravel(), minlength=n)
    Hbar = np.bincount(t.ravel(), weights=np.repeat(Hn[None, :], 4, 0).ravel(), minlength=n) / np.maximum(count, 1)
    opposite = 3.0 * system.volumes[:, None] * np.linalg.norm(system.grads, axis=2)  # (m, 4)
    area = np.bincount(t.T.ravel(), weights=opposite.ravel(), minlength=n)
    vol = np.bincount(t.ravel(), weights=np.repeat(system.volumes[None, :] / 4.0, 4, 0).ravel(), minlength=n)
    return area * Hbar, vol * Hbar


def element_energies(system, x):
    """V_e W_e(F_e) per element at positions x (n, 3)."""
    F = system.deformation_gradients(x)
    W = np.empty(system.m)
    for mat, idx in system.groups:
        W[idx] = mat.energy_density(F[idx])
    return system.volumes * W


def element_gradients(system, P):
    """d(V_e W_e)/dx per element and vertex, (m, 4, 3) = V_e P_e grad phi_k."""
    return np.einsum("eaj,ekj->eka", P, system.volumes[:, None, None] * system.grads, optimize=True)


class OneRing:
    """Node pairs (i, j) sharing an element: the support of the one-ring gradients g_i (eq. 9)."""

    def __init__(self, system):
        t = system.t
        i = np.repeat(t[:, None, :], 4, axis=1)  # i = t[k], j = t[l]
        j = np.repeat(t[None, :, :], 4, axis=0)
        key = (i.astype(np.int64) * system.n + j).transpose(2, 0, 1).ravel()  # (m, 4, 4)
        ukey, self.slot = np.unique(key, return_inverse=True)
        self.row, self.col = ukey // system.n, ukey % system.n
        self.diag = np.flatnonzero(self.row == self.col)
        self.npairs, self.n = ukey.size, system.n
        self.fixed = system.fixed

    def gradient_norms(self, ge, nodal):
        """||g_i|| per vertex from element gradients ge (m, 4, 3) and point-stencil gradients (n, 3)."""
        m = ge.shape[0]
        sq = np.zeros(self.npairs)
        for c in range(3):
            vals = np.broadcast_to(ge[:, None, :, c], (m, 4, 4)).ravel()  # value of vertex l, for every k
            gc = np.bincount(self.slot, weights=vals, minlength=self.npairs)
            gc[self.diag] += nodal[self.row[self.diag], c]
            gc[self.fixed[self.col]] = 0.0  # fixed DOFs are not unknowns of E
            sq += gc * gc
        return np.sqrt(np.bincount(self.row, weights=sq, minlength=self.n))


def nodal_shares(ip, x, elem_energy):
    """Each vertex's share E_i of the incremental potential E(x) (sum_i E_i = E up to constants)."""
    sysm, free, w = ip.system, ip.free, ip.weight
    n = sysm.n
    dof = np.zeros(3 * n)
    r = (x - ip.x_tilde)[free]
    dof[free] += 0.5 * r * (sysm.Mff @ r)
    dof[free] -= w * ip.f_ext[free] * x[free]
    if ip.damping_matrix is not None:
        z = (x - ip.x_hat)[free]
        dof[free] += 0.5 * w * z * (ip.damping_matrix @ z)
    share = dof.reshape(n, 3).sum(axis=1)
    if ip.barrier is not None:
        share += w * ip.barrier.vertex_energy(x)
    share += w * np.bincount(sysm.t.ravel(), weights=np.repeat(elem_energy[None, :] / 4.0, 4, 0).ravel(),
                             minlength=n)
    return share


def point_gradients(ip, x):
    """Gradient of the point stencils (inertia, gravity, damping, contact) per vertex, (n, 3):
    grad E without the elastic part."""
    g = np.zeros(3 * ip.system.n)
    g[ip.free] = ip.gradient(x, np.zeros(x.size))
    return g.reshape(-1, 3)


class ModalQueries:
    """Error (eq. 12, 14, 16) and progress (eq. 13, 15, 17) of blocks of candidate modes."""

    def __init__(self, U, blocks):
        n = U.shape[0] // 3
        self.U = U
        self.blocks = blocks
        self.Ubar = U.reshape(n, 3, -1).mean(axis=1)  # per-vertex average over coordinates (eq. 13)
        self.ubar_sq = np.einsum("ic,ic->c", self.Ubar, self.Ubar)
        self.colnorm_sq = np.einsum("ic,ic->c", U, U)
        size = blocks[0].size if blocks else 0
        self.uniform = all(np.array_equal(b, np.arange(j * size, (j + 1) * size)) for j, b in enumerate(blocks)) \
            and size * len(blocks) == U.shape[1]

    def measure(self, which, grad_full, dE, n_scale, m_scale):
        """Errors G_j and progress E_j of the blocks ``which``; grad_full (3n,), dE (n,)."""
        if not len(which):
            return np.zeros(0), np.zeros(0)
        if self.uniform:  # contiguous equal blocks: measure all of them without gathering columns
            err, prog = self._measure_all(grad_full, dE, n_scale, m_scale)
            return err[which], prog[which]
        sizes = [self.blocks[j].size for j in which]
        cols = np.concatenate([self.blocks[j] for j in which])
        starts = np.cumsum([0] + sizes)[:-1]
        Uc = self.U[:, cols]
        coef = (grad_full @ Uc) / np.where(self.colnorm_sq[cols] > 0, self.colnorm_sq[cols], 1.0)
        if len(set(sizes)) == 1:  # equal blocks: sum within each by a reshape
            proj = (Uc * coef).reshape(Uc.shape[0], len(which), sizes[0]).sum(axis=2)  # g_j (eq. 16)
        else:
            member = sp.csr_matrix((np.ones(cols.size), (np.arange(cols.size), np.repeat(np.arange(len(which)), sizes))),
                                   shape=(cols.size, len(which)))
            proj = np.asarray((member.T @ (Uc * coef).T).T)
        n = grad_full.size // 3
        norms = np.linalg.norm(proj.reshape(n, 3, -1), axis=1) / n_scale[:, None]
        error = norms.max(axis=0)  # eq. 14
        Ub = self.Ubar[:, cols]
        ok = self.ubar_sq[cols] > 0
        c2 = np.where(ok, (Ub.T @ dE) / np.where(ok, self.ubar_sq[cols], 1.0), 0.0)  # eq. 17
        progress = np.add.reduceat(c2 * (Ub.T @ (1.0 / m_scale)), starts)  # eq. 15
        return error, progress

    def _measure_all(self, grad_full, dE, n_scale, m_scale):
        nb, n = len(self.blocks), grad_full.size // 3
        safe = np.where(self.colnorm_sq > 0, self.colnorm_sq, 1.0)
        coef = np.einsum("i,ic->c", grad_full, self.U) / safe  # no BLAS gemv: see potential.vdot
        proj = np.einsum("ikbc,bc->ikb", self.U.reshape(n, 3, nb, -1), coef.reshape(nb, -1))  # g_j (eq. 16)
        error = (np.sqrt(np.einsum("icb,icb->ib", proj, proj)) / n_scale[:, None]).max(axis=0)  # eq. 14
        ok = self.ubar_sq > 0
        c2 = np.where(ok, np.einsum("i,ic->c", dE, self.Ubar) / np.where(ok, self.ubar_sq, 1.0), 0.0)  # eq. 17
        progress = (c2 * np.einsum("i,ic->c", 1.0 / m_scale, self.Ubar)).reshape(nb, -1).sum(axis=1)  # eq. 15
        return error, progress
