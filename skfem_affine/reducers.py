r"""Adaptive reducers: the one place where the methods differ (paper Algorithm 1).

A reducer is handed the simulation each frame and returns the full-space velocity
change of the free DOFs. :class:`Affinification` (sec. 3) clusters elements
with alike deformation rates into affine bodies; :class:`Rigidification` is the
adaptive-rigidification baseline (Mercier-Aubin et al. 2022) on the same
integrator, solver and statistics, so that the methods compare fairly.

One affinification frame (Algorithm 1), with the phase names of ``sim.stats``:

1. ``assembly``: f, dP/dF and element blocks at x_t (:meth:`ElasticSystem.evaluate`);
2. ``prediction``: one PCG iteration (eq. 13-14), dv_approx;
3. ``clustering``: F_dot = B v (eq. 4, predicted velocities for previously
   affine elements), BFS of Algorithm 2 (eq. 5-6), resource limiting (sec. 3.5);
4. ``map_assembly``: G (eq. 7-8), projection q = (G^T M G)^-1 G^T M v (eq. 9),
   discrepancy d = G q - v (eq. 11);
5. ``reduced_assembly``: G^T A G and G^T b (eq. 10), assembled per element:
   an element whose four vertices lie in one affine body contributes exactly
   V_e C_e to that body's 9 x 9 affine block (B_e G_e = [0 | I_9] there), so
   only elements on cluster boundaries need the general product;
6. ``factorization`` and ``solve``: the reduced system, direct solver;
7. dv = G dq + d (eq. 12); positions are integrated in full space.
"""
import time

import numpy as np
import scipy.sparse as sp

from . import clustering, oracle, reduction
from ._kernels import reduced_boundary_blocks
from .kinematics import deformation_gradient
from .solvers import make_solver


def _check_threshold(value, name):
    value = float(value)
    if not np.isfinite(value) or value < 0:
        raise ValueError(f"threshold {name} must be finite and >= 0, got {value}")
    return value


class Reducer:
    """Interface: ``attach(sim)`` once, then ``solve(sim, rec)`` -> dv on the free DOFs each frame."""

    name = "reducer"

    def attach(self, sim):
        self.sim = sim

    def solve(self, sim, rec):
        raise NotImplementedError


def reduced_matrix(sim, data, vcluster, Gam, n_bodies, elastic_dofs, affine=True):
    """G^T A G (CSR) with A = (1 + h alpha) M + (h beta + h^2) H, assembled per element (eq. 10).

    Parameters
    ----------
    data : FrameData of the frame (element blocks ``He``, dP/dF ``C``, ``H`` data).
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
    ne = elastic_dofs.size
    size = ne + w * n_bodies
    # elastic-elastic block: the full matrix restricted to elastic DOFs (G = I there)
    red_of_free = np.full(pat.shape[0], -1, dtype=np.int64)
    red_of_free[elastic_dofs] = np.arange(ne)
    Adata = cm * sysm.mass_data + ck * data.H
    rr, cc = red_of_free[pat.rows], red_of_free[pat.indices]
    keep = (rr >= 0) & (cc >= 0)
    parts = [(rr[keep], cc[keep], Adata[keep])]
    if n_bodies:
        t = sysm.t
        vc = vcluster[t]  # (4, m)
        ccol = ne + w * np.arange(n_bodies)
        # lumped mass: sum_i m_i Gamma_i^T Gamma_i per body
        red = np.flatnonzero(vcluster >= 0)
        B = np.zeros((n_bodies, w, w))
        np.add.at(B, vcluster[red], sysm.lumped_mass[red, None, None]
                  * np.einsum("vai,vaj->vij", Gam[red], Gam[red]))
        B *= cm
        touching = np.any(vc >= 0, axis=0)
        if affine:
            # elements inside one affine body: B_e G_e = [0 | I_9], reduced stiffness V_e C_e
            interior = (vc[0] >= 0) & np.all(vc == vc[0], axis=0)
            e_in = np.flatnonzero(interior)
            K9 = np.zeros((n_bodies, 81))
            np.add.at(K9, vc[0, e_in], sysm.volumes[e_in, None] * data.C[e_in].reshape(-1, 81))
            B[:, 3:, 3:] += ck * K9.reshape(-1, 9, 9)
            touching &= ~interior
        idx = ccol[:, None] + np.arange(w)
        parts.append((np.broadcast_to(idx[:, :, None], B.shape).ravel(),
                      np.broadcast_to(idx[:, None, :], B.shape).ravel(), B.ravel()))
        e_b = np.flatnonzero(touching)
        if e_b.size:
            free_of = np.full(3 * sysm.n, -1, dtype=np.int64)
            free_of[sysm.free] = np.arange(sysm.free.size)
            red_dof = np.where(free_of >= 0, red_of_free[np.maximum(free_of, 0)], -1).reshape(-1, 3)
            cap = e_b.size * 16 * w * w
            rows, cols, vals = np.empty(cap, np.int64), np.empty(cap, np.int64), np.empty(cap)
            nb = reduced_boundary_blocks(t, e_b, data.He, vcluster, np.ascontiguousarray(Gam),
                                         red_dof, ccol, rows, cols, vals)
            parts.append((rows[:nb], cols[:nb], ck * vals[:nb]))
    R = np.concatenate([p[0] for p in parts])
    C = np.concatenate([p[1] for p in parts])
    V = np.concatenate([p[2] for p in parts])
    A = sp.csr_matrix((V, (R, C)), shape=(size, size))
    A.sum_duplicates()
    return A
