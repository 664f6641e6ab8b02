r"""Affine bodies that contain fixed or prescribed vertices (``Affinification(pinned_bodies=True)``).

The paper keeps every element touching a fixed vertex elastic. Here a body may contain pinned
vertices p (fixed, or prescribed with velocity :math:`w_p` over the step): its 12 DOFs q must then
satisfy :math:`\Gamma_p q = w_p` for each of them (eq. 8). The constraint is eliminated: with
:math:`C_b` the stacked rows :math:`\Gamma_p` of body b and :math:`C_b = U \Sigma V^T`,

.. math:: q_b = q_b^0 + N_b z_b, \qquad q_b^0 = C_b^+ w_b, \qquad N_b = V_{:, r:}

(r = rank of :math:`C_b`), so a body keeps :math:`12 - r` DOFs: 9 with one pinned vertex, 3 with
pinned vertices on a plane, none (fully prescribed) with four or more non-coplanar ones. With
:math:`G_N = G\,\mathrm{diag}(I, N_1, \dots)` and :math:`g_0 = G\,(0, q^0_1, \dots)`, the free
velocities at t + 1 are :math:`v = G_N y + g_0`, and the Galerkin condition of eq. 10 on
:math:`A (v - v_t) = b` gives

.. math:: G_N^T A G_N\, y = G_N^T\big(b + A (v_t - g_0)\big).

Without pins this is the paper's reduced step (eq. 9-12): there :math:`G^T M d = 0` for the
mass-weighted projection, so solving for v directly or for dq after projecting gives the same
v. A body whose pinned vertices do not move affinely (constraints without an exact solution)
is dissolved into elastic elements.
"""
import numpy as np
import scipy.sparse as sp

# relative singular-value cut for the rank of C_b, and the tolerance of an exact constraint solution
RANK_TOL = 1e-10
CONSISTENCY_TOL = 1e-9


def pinned_velocities(problem, pinned):
    """Velocities at t + 1 of the pinned vertices (k,) (zero if fixed, the path's if prescribed), (k, 3)."""
    w = np.zeros((pinned.size, 3))
    targets = problem.targets
    if targets is not None:
        where = {int(v): i for i, v in enumerate(targets.vertices)}
        for j, p in enumerate(pinned):
            i = where.get(int(p))
            if i is not None:
                w[j] = targets.v[i]
    return w


def constraints(gmap, pinned, w):
    """Per body with pinned vertices: ``{body: (N_b, q0_b)}``, and the bodies whose pins do not move affinely.

    ``pinned`` are the pinned vertices that lie in bodies (k,), ``w`` their velocities (k, 3).
    """
    bodies = gmap.vcluster[pinned]
    out, bad = {}, []
    for b in np.unique(bodies):
        sel = bodies == b
        C = gmap.rows[pinned[sel]].reshape(-1, gmap.width)
        rhs = w[sel].reshape(-1)
        U, S, Vt = np.linalg.svd(C, full_matrices=True)
        r = int(np.sum(S > RANK_TOL * S[0])) if S.size else 0
        q0 = Vt[:r].T @ ((U[:, :r].T @ rhs) / S[:r])
        scale = max(np.abs(rhs).max(initial=0.0), 1e-300)
        if np.abs(C @ q0 - rhs).max(initial=0.0) > CONSISTENCY_TOL * scale and np.abs(rhs).max(initial=0.0) > 0:
            bad.append(int(b))
            continue
        out[int(b)] = (Vt[r:].T, q0)
    return out, bad


def constrained_mapping(gmap, cons):
    """(G_N, g0): the mapping with the pinned bodies' constraints eliminated (module docstring)."""
    ne, w = gmap.n_elastic, gmap.width
    blocks, q0 = [sp.identity(ne, format="csr")], np.zeros(gmap.G.shape[1])
    for b in range(gmap.n_bodies):
        if b in cons:
            N, q = cons[b]
            blocks.append(sp.csr_matrix(N) if N.shape[1] else sp.csr_matrix((w, 0)))
            q0[ne + w * b: ne + w * (b + 1)] = q
        else:
            blocks.append(sp.identity(w, format="csr"))
    T = sp.block_diag(blocks, format="csr")
    return (gmap.G @ T).tocsr(), gmap.G @ q0


def solve(problem, G, g0, solver, stats):
    """v_{t+1} on the free DOFs from G_N^T A G_N y = G_N^T (b + A (v_t - g0)); returns dv = v_{t+1} - v_t."""
    A = problem.matrix()
    vf = problem.v.reshape(-1)[problem.system.free]
    Ar = (G.T @ A @ G).tocsr()
    br = G.T @ (problem.b + A @ (vf - g0))
    if Ar.shape[0]:
        solver.factorize(Ar)
        y = solver.solve(br)
    else:  # every body fully prescribed and no elastic DOF
        y = np.zeros(0)
    stats.update(dofs=Ar.shape[0], solver=solver.name, iterations=solver.last_iterations if Ar.shape[0] else 0)
    return G @ y + g0 - vf, Ar
