"""Linear-algebra toolkit of the adaptive subspace solve: PCG, block Jacobi, the Schur-complement
solve of the coupled system (eq. 19, 21-22), the BFGS update (eq. 20) and METIS partitions.

Generic: these functions know nothing about the reducer and take plain arrays and matrices.
"""
import time

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp

from skfem_affine._extras import require
from skfem_affine.integrators.potential import vdot
from skfem_affine.solvers import SolverError


def metis_parts(system, nparts):
    """Vertex partition into ``nparts`` subdomains of the mesh graph (METIS via pymetis)."""
    n = system.n
    nparts = int(min(max(nparts, 1), n))
    if nparts == 1:
        return np.zeros(n, dtype=np.int64)
    pymetis = require("pymetis", "sa.AdaptiveSubspace's subdomains (METIS partitions; subdomains=1 needs none)",
                      "subspace")
    t = system.t
    pairs = np.concatenate([t[[a, b]] for a in range(4) for b in range(4) if a != b], axis=1)
    G = sp.csr_matrix((np.ones(pairs.shape[1]), (pairs[0], pairs[1])), shape=(n, n))
    G.sum_duplicates()
    _, parts = pymetis.part_graph(nparts, adjacency=pymetis.CSRAdjacency(G.indptr, G.indices))
    return np.asarray(parts, dtype=np.int64)


def bfgs_update(H, s, Y, valid):
    """BFGS secant update (eq. 20) of the per-subdomain Hessians H (L, a, a), in place.

    ``s`` (a,) is the step in modal coordinates, ``Y`` (L, a) the change of each subdomain's
    projected elastic gradient; only subdomains in the mask ``valid`` are updated. Updates with
    y^T s <= 0 are skipped, so positive semi-definite H stay so.
    """
    ys = Y @ s
    scale = np.linalg.norm(Y, axis=1) * np.linalg.norm(s)
    ok = valid & (ys > 1e-12 * np.maximum(scale, 1e-300))
    if not np.any(ok):
        return
    idx = np.flatnonzero(ok)
    Hs = np.einsum("lab,b->la", H[idx], s)
    sHs = Hs @ s
    big = sHs > 1e-14 * np.abs(ys[idx])
    V = np.stack([Y[idx], Hs], axis=2)  # (l, a, 2): the two rank-one terms, one symmetric product
    coef = np.column_stack([1.0 / ys[idx], np.where(big, -1.0 / np.where(big, sHs, 1.0), 0.0)])
    H[idx] += np.einsum("lak,lk,lbk->lab", V, coef, V, optimize=True)


def pcg(apply, b, precond, tol, maxiter):
    """Preconditioned CG to relative residual ``tol``; returns (x, iterations)."""
    x = np.zeros_like(b)
    nb = np.sqrt(vdot(b, b))
    if nb == 0.0:
        return x, 0
    r = b.copy()
    z = precond(r)
    p, rz = z.copy(), vdot(r, z)
    for it in range(1, maxiter + 1):
        Ap = apply(p)
        alpha = rz / vdot(p, Ap)
        x += alpha * p
        r -= alpha * Ap
        if np.sqrt(vdot(r, r)) <= tol * nb:
            return x, it
        z = precond(r)
        rz, rz_old = vdot(r, z), rz
        p = z + (rz / rz_old) * p
    return x, maxiter


def block_jacobi(Hx):
    """Inverse 3 x 3 diagonal blocks of Hx (node-major DOFs) as a preconditioner function."""
    k = Hx.shape[0] // 3
    base = 3 * np.arange(k)
    r = (base[:, None, None] + np.arange(3)[None, :, None]) + 0 * np.arange(3)[None, None, :]
    c = (base[:, None, None] + np.arange(3)[None, None, :]) + 0 * np.arange(3)[None, :, None]
    blocks = np.asarray(Hx.tocsr()[r.ravel(), c.ravel()]).reshape(k, 3, 3)
    inv = np.linalg.inv(blocks)
    return lambda v: np.einsum("kab,kb->ka", inv, v.reshape(k, 3)).ravel()


def schur_solve(Hq, C, Hx, gq, gx, tol=1e-5, maxiter=10000):
    """Solve [[Hq, C], [C^T, Hx]] [dq; dx] = -[gq; gx] by the Schur complement (eq. 21-22).

    Hq (a, a) dense SPD is Cholesky-factorised; (Hx - C^T Hq^-1 C) dx = C^T Hq^-1 gq - gx is
    solved by block-Jacobi PCG with matrix-free products; dq = -Hq^-1 (C dx + gq).
    Returns (dq, dx, pcg iterations, factorization seconds).
    """
    t0 = time.perf_counter()
    try:
        fac = sla.cho_factor(Hq, lower=True)
    except np.linalg.LinAlgError as err:
        raise SolverError(f"modal block H_q is not positive definite ({err})") from err
    tf = time.perf_counter() - t0
    if Hx.shape[0] == 0:
        return -sla.cho_solve(fac, gq), np.zeros(0), 0, tf
    rhs = C.T @ sla.cho_solve(fac, gq) - gx

    def apply(p):
        return Hx @ p - C.T @ sla.cho_solve(fac, C @ p)

    dx, iters = pcg(apply, rhs, block_jacobi(Hx), tol, maxiter)
    dq = -sla.cho_solve(fac, C @ dx + gq)
    return dq, dx, iters, tf


def masked_sandwich(UAU, cols, extra, Ua, Ak=None, S=None):
    """B^T (A + extra) B with B = U_a (columns ``cols`` of U), or U_a with the rows S zeroed
    (then ``Ak`` = A + extra).

    Uses the cached U^T A U over all columns; the sparse ``extra`` and the masking are corrections
    over the few rows they touch: B^T A B = U^T A U - U^T A E U - U^T E A U + U^T E A E U.
    """
    out = UAU[np.ix_(cols, cols)].copy()
    rows = np.flatnonzero(np.diff(extra.tocsr().indptr)) if extra.nnz else np.zeros(0, np.int64)
    if rows.size:
        Ur = Ua[rows]
        out += Ur.T @ (extra[rows][:, rows] @ Ur)
    if S is not None and S.size:
        X = Ak[:, S]  # columns of the masked DOFs
        XU = np.asarray((X.T @ Ua))  # (s, a) = E A U restricted to S rows
        US = Ua[S]
        cross = US.T @ XU
        out += -cross - cross.T + US.T @ (Ak[S][:, S] @ US)
    return out
