"""Compiled per-element kernels (numba) for the few hot spots numpy batches poorly.

numpy's batched 3 x 3 SVD and eigh pay a LAPACK call per element; these kernels do the
same work in registers (timings: the user guide's Materials page). The element loops are
``nogil`` kernels over work units, run in parallel by :func:`skfem_affine.threads.run_chunks`
(no numba parallel regions: see :mod:`skfem_affine.threads`).
"""
import numpy as np
from numba import njit

from skfem_affine import _compile_notice  # noqa: F401 (one stderr line when the cached kernels compile)
from skfem_affine.threads import run_chunks


@njit(cache=True, inline="always")
def _givens(app, aqq, apq):
    """Jacobi rotation (c, s, t = s / c) that zeroes apq of a symmetric 2 x 2.

    t = sgn(d) 2 apq / (|d| + sqrt(d^2 + 4 apq^2)), d = aqq - app: the smaller root of
    t^2 + 2 t theta - 1 = 0, theta = d / (2 apq), with one division (Numerical Recipes' form).
    """
    d = aqq - app
    den = abs(d) + np.sqrt(d * d + 4.0 * apq * apq)
    if den == 0.0:
        return 1.0, 0.0, 0.0
    t = 2.0 * apq / den
    if d < 0.0:
        t = -t
    c = 1.0 / np.sqrt(t * t + 1.0)
    return c, t * c, t


@njit(cache=True, inline="always")
def _turn(c, s, x, y):
    """(x, y) rotated by the Givens rotation (c, s): (c x - s y, s x + c y)."""
    return c * x - s * y, s * x + c * y


@njit(cache=True, inline="always")
def _jacobi_pair(app, aqq, apq, arp, arq, v0p, v0q, v1p, v1q, v2p, v2q):
    """One Jacobi rotation zeroing apq (r the third index, rows 0-2 of V's columns p, q).

    Skipped when the pair is already below rounding (apq^2 <= 1e-32 |app aqq|).
    """
    if apq * apq <= 1e-32 * abs(app * aqq):
        return app, aqq, apq, arp, arq, v0p, v0q, v1p, v1q, v2p, v2q
    c, s, t = _givens(app, aqq, apq)
    arp, arq = _turn(c, s, arp, arq)
    v0p, v0q = _turn(c, s, v0p, v0q)
    v1p, v1q = _turn(c, s, v1p, v1q)
    v2p, v2q = _turn(c, s, v2p, v2q)
    return app - t * apq, aqq + t * apq, 0.0, arp, arq, v0p, v0q, v1p, v1q, v2p, v2q


@njit(cache=True, inline="always")
def _sym_eig3(A, V):
    """Cyclic Jacobi on a symmetric 3x3 A (overwritten: diagonal -> eigenvalues); V <- eigenvectors.

    The six distinct entries and V live in scalars (registers), see :func:`_jacobi_pair`.
    """
    a00, a11, a22, a01, a02, a12 = A[0, 0], A[1, 1], A[2, 2], A[0, 1], A[0, 2], A[1, 2]
    v00, v01, v02, v10, v11, v12, v20, v21, v22 = 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0
    for sweep in range(12):
        off = a01 * a01 + a02 * a02 + a12 * a12
        if off <= 1e-30 * (a00 * a00 + a11 * a11 + a22 * a22) or off == 0.0:
            break
        a00, a11, a01, a02, a12, v00, v01, v10, v11, v20, v21 = _jacobi_pair(  # pair (0, 1), third 2
            a00, a11, a01, a02, a12, v00, v01, v10, v11, v20, v21)
        a00, a22, a02, a01, a12, v00, v02, v10, v12, v20, v22 = _jacobi_pair(  # pair (0, 2), third 1
            a00, a22, a02, a01, a12, v00, v02, v10, v12, v20, v22)
        a11, a22, a12, a01, a02, v01, v02, v11, v12, v21, v22 = _jacobi_pair(  # pair (1, 2), third 0
            a11, a22, a12, a01, a02, v01, v02, v11, v12, v21, v22)
    A[0, 0], A[1, 1], A[2, 2] = a00, a11, a22
    A[0, 1] = A[1, 0] = a01
    A[0, 2] = A[2, 0] = a02
    A[1, 2] = A[2, 1] = a12
    V[0, 0], V[0, 1], V[0, 2] = v00, v01, v02
    V[1, 0], V[1, 1], V[1, 2] = v10, v11, v12
    V[2, 0], V[2, 1], V[2, 2] = v20, v21, v22


@njit(cache=True, inline="always")
def svd3(F, U, s, V, A):
    """Rotation-variant SVD of a 3x3 F: det U = det V = 1, s descending, s[2] may be < 0.

    ``A`` is 3x3 scratch. Eigenvectors of F^T F by Jacobi give V; U from a
    Gram-Schmidt QR of F V, with u2 = u0 x u1 so that s[2] carries the sign of det F.
    """
    for i in range(3):
        for j in range(3):
            A[i, j] = F[0, i] * F[0, j] + F[1, i] * F[1, j] + F[2, i] * F[2, j]
    _sym_eig3(A, V)
    _svd_from_eig(F, A, V, U, s)


_LANES = 8  # elements whose Jacobi rotations are interleaved by svd3_lanes


@njit(cache=True, inline="always")
def _rotate_lanes(a, v, P, Q, PQ, RP, RQ, p, q):
    """One Jacobi rotation of the pair (p, q) in every lane, branch-free (see :func:`_givens`).

    ``a`` (6, lanes) holds a00, a11, a22, a01, a02, a12; P, Q, PQ index app, aqq, apq and
    RP, RQ the entries (r, p), (r, q) of the third index r; ``v`` (9, lanes) row-major V.
    """
    for b in range(_LANES):
        app, aqq, apq = a[P, b], a[Q, b], a[PQ, b]
        d = aqq - app
        t = 2.0 * apq / (abs(d) + np.sqrt(d * d + 4.0 * apq * apq) + 1e-300)
        t = t if d >= 0.0 else -t
        c = 1.0 / np.sqrt(t * t + 1.0)
        sn = t * c
        arp, arq = a[RP, b], a[RQ, b]
        a[P, b] = app - t * apq
        a[Q, b] = aqq + t * apq
        a[PQ, b] = 0.0
        a[RP, b], a[RQ, b] = _turn(c, sn, arp, arq)
        v[p, b], v[q, b] = _turn(c, sn, v[p, b], v[q, b])
        v[3 + p, b], v[3 + q, b] = _turn(c, sn, v[3 + p, b], v[3 + q, b])
        v[6 + p, b], v[6 + q, b] = _turn(c, sn, v[6 + p, b], v[6 + q, b])


@njit(cache=True, inline="always")
def svd3_lanes(F, e0, stop, U, s, V, a, v, A, W, sweeps=4):
    """:func:`svd3` of F[e0 : min(e0 + _LANES, stop)] into U[b], s[b], V[b], b = e - e0.

    ``sweeps`` (4) Jacobi sweeps run on all lanes at once, so the rotations of different
    elements overlap (the scalar sweep is latency-bound); a lane not yet converged after
    ``sweeps`` (enough for the random, near-singular and inverted F of the tests) finishes with
    :func:`_sym_eig3` on V^T A V. ``a`` (6, lanes),
    ``v`` (9, lanes), ``A``, ``W`` (3, 3) are scratch. Unused lanes repeat the last element.
    """
    for b in range(_LANES):
        f = F[min(e0 + b, stop - 1)]
        a[0, b] = f[0, 0] * f[0, 0] + f[1, 0] * f[1, 0] + f[2, 0] * f[2, 0]
        a[1, b] = f[0, 1] * f[0, 1] + f[1, 1] * f[1, 1] + f[2, 1] * f[2, 1]
        a[2, b] = f[0, 2] * f[0, 2] + f[1, 2] * f[1, 2] + f[2, 2] * f[2, 2]
        a[3, b] = f[0, 0] * f[0, 1] + f[1, 0] * f[1, 1] + f[2, 0] * f[2, 1]
        a[4, b] = f[0, 0] * f[0, 2] + f[1, 0] * f[1, 2] + f[2, 0] * f[2, 2]
        a[5, b] = f[0, 1] * f[0, 2] + f[1, 1] * f[1, 2] + f[2, 1] * f[2, 2]
        for r in range(9):
            v[r, b] = 1.0 if r % 4 == 0 else 0.0
    for sweep in range(sweeps):
        _rotate_lanes(a, v, 0, 1, 3, 4, 5, 0, 1)  # pair (0, 1), third index 2
        _rotate_lanes(a, v, 0, 2, 4, 3, 5, 0, 2)  # pair (0, 2), third index 1
        _rotate_lanes(a, v, 1, 2, 5, 3, 4, 1, 2)  # pair (1, 2), third index 0
    for b in range(min(_LANES, stop - e0)):
        A[0, 0], A[1, 1], A[2, 2] = a[0, b], a[1, b], a[2, b]
        A[0, 1] = A[1, 0] = a[3, b]
        A[0, 2] = A[2, 0] = a[4, b]
        A[1, 2] = A[2, 1] = a[5, b]
        Vb = V[b]
        for r in range(3):
            for c in range(3):
                Vb[r, c] = v[3 * r + c, b]
        off = a[3, b] ** 2 + a[4, b] ** 2 + a[5, b] ** 2
        if off > 1e-30 * (a[0, b] ** 2 + a[1, b] ** 2 + a[2, b] ** 2):
            _sym_eig3(A, W)  # V <- V W
            for r in range(3):
                x0, x1, x2 = Vb[r, 0], Vb[r, 1], Vb[r, 2]
                for c in range(3):
                    Vb[r, c] = x0 * W[0, c] + x1 * W[1, c] + x2 * W[2, c]
        _svd_from_eig(F[e0 + b], A, Vb, U[b], s[b])


@njit(cache=True, inline="always")
def _svd_from_eig(F, A, V, U, s):
    """Finish :func:`svd3` from the eigenpairs of F^T F (diagonal of A, columns of V); A is scratch."""
    # sort eigenpairs descending (3 compare-swaps)
    for step in range(3):
        a = 0 if step != 1 else 1
        b = a + 1
        if A[a, a] < A[b, b]:
            A[a, a], A[b, b] = A[b, b], A[a, a]
            for k in range(3):
                V[k, a], V[k, b] = V[k, b], V[k, a]
    detv = (V[0, 0] * (V[1, 1] * V[2, 2] - V[1, 2] * V[2, 1]) - V[0, 1] * (V[1, 0] * V[2, 2] - V[1, 2] * V[2, 0])
            + V[0, 2] * (V[1, 0] * V[2, 1] - V[1, 1] * V[2, 0]))
    if detv < 0:
        for k in range(3):
            V[k, 2] = -V[k, 2]
    for i in range(3):  # B = F V stored in A
        for j in range(3):
            A[i, j] = F[i, 0] * V[0, j] + F[i, 1] * V[1, j] + F[i, 2] * V[2, j]
    n0 = np.sqrt(A[0, 0] ** 2 + A[1, 0] ** 2 + A[2, 0] ** 2)
    if n0 > 1e-300:
        for k in range(3):
            U[k, 0] = A[k, 0] / n0
    else:
        U[0, 0], U[1, 0], U[2, 0] = 1.0, 0.0, 0.0
    d = U[0, 0] * A[0, 1] + U[1, 0] * A[1, 1] + U[2, 0] * A[2, 1]
    for k in range(3):
        U[k, 1] = A[k, 1] - d * U[k, 0]
    n1 = np.sqrt(U[0, 1] ** 2 + U[1, 1] ** 2 + U[2, 1] ** 2)
    if n1 <= 1e-12 * max(n0, 1e-300):  # rank <= 1: any unit vector orthogonal to u0
        if abs(U[0, 0]) < 0.9:
            U[0, 1], U[1, 1], U[2, 1] = 1.0, 0.0, 0.0
        else:
            U[0, 1], U[1, 1], U[2, 1] = 0.0, 1.0, 0.0
        d = U[0, 0] * U[0, 1] + U[1, 0] * U[1, 1] + U[2, 0] * U[2, 1]
        for k in range(3):
            U[k, 1] -= d * U[k, 0]
        n1 = np.sqrt(U[0, 1] ** 2 + U[1, 1] ** 2 + U[2, 1] ** 2)
    for k in range(3):
        U[k, 1] /= n1
    U[0, 2] = U[1, 0] * U[2, 1] - U[2, 0] * U[1, 1]
    U[1, 2] = U[2, 0] * U[0, 1] - U[0, 0] * U[2, 1]
    U[2, 2] = U[0, 0] * U[1, 1] - U[1, 0] * U[0, 1]
    for j in range(3):
        s[j] = U[0, j] * A[0, j] + U[1, j] * A[1, j] + U[2, j] * A[2, j]


_PAIRS = np.array([[1, 2], [0, 2], [0, 1]])
_R2 = 1.0 / np.sqrt(2.0)


@njit(cache=True, inline="always")
def _mode(k, U, V, Q):
    """vec(Q_k), Q_k = U E_k V^T: k < 3 scaling u_k v_k^T, 3..5 twists, 6..8 flips."""
    if k < 3:
        for a in range(3):
            for b in range(3):
                Q[3 * a + b] = U[a, k] * V[b, k]
    else:
        i, j = _PAIRS[(k - 3) % 3, 0], _PAIRS[(k - 3) % 3, 1]
        sign = -1.0 if k < 6 else 1.0
        for a in range(3):
            for b in range(3):
                Q[3 * a + b] = _R2 * (U[a, i] * V[b, j] + sign * U[a, j] * V[b, i])


@njit(cache=True)
def _project_modes(Ce, Fe, U, V, s, A, W, Q, CQ):
    """Clamp the eigenvalues of one symmetric isotropic dP/dF (9x9, in place) to >= 0.

    For an isotropic energy the twists and flips Q_k = U E_k V^T are eigenvectors
    and the three scalings span an invariant subspace (Smith et al. 2019), so
    Rayleigh quotients give the spectrum; only negative modes are corrected.
    """
    svd3(Fe, U, s, V, A)
    for k in range(9):
        _mode(k, U, V, Q[k])
        for i in range(9):
            acc = 0.0
            for j in range(9):
                acc += Ce[i, j] * Q[k, j]
            CQ[k, i] = acc
    for i in range(3):  # scaling block
        for j in range(3):
            acc = 0.0
            for a in range(9):
                acc += Q[i, a] * CQ[j, a]
            A[i, j] = acc
    A[0, 1] = A[1, 0] = 0.5 * (A[0, 1] + A[1, 0])
    A[0, 2] = A[2, 0] = 0.5 * (A[0, 2] + A[2, 0])
    A[1, 2] = A[2, 1] = 0.5 * (A[1, 2] + A[2, 1])
    for k in range(3, 9):
        lam = 0.0
        for a in range(9):
            lam += Q[k, a] * CQ[k, a]
        if lam < 0.0:
            for a in range(9):
                for b in range(9):
                    Ce[a, b] -= lam * Q[k, a] * Q[k, b]
    _sym_eig3(A, W)
    for k in range(3):
        lam = A[k, k]
        if lam < 0.0:
            q = W[0, k] * Q[0] + W[1, k] * Q[1] + W[2, k] * Q[2]
            for a in range(9):
                for b in range(9):
                    Ce[a, b] -= lam * q[a] * q[b]


_CHUNKS = 64  # work units split across threads: each allocates its scratch once


@njit(cache=True, inline="always")
def _symmetric_projected(C, e, F, project, U, V, s, A, W, Q, CQ, Ce):
    """Ce <- sym(C[e]), projected to PSD if asked; written back to C[e]."""
    for i in range(9):
        for j in range(9):
            Ce[i, j] = 0.5 * (C[e, i, j] + C[e, j, i])
    if project:
        _project_modes(Ce, F[e], U, V, s, A, W, Q, CQ)
    C[e] = Ce


@njit(cache=True, inline="always")
def element_block(Ce, vg, g, e, He, X):
    """He[e] = V_e G_e^T Ce G_e for a symmetric Ce, node-major:
    He[3k+a, 3l+b] = sum_jq vg_kj Ce[3a+j, 3b+q] g_lq (upper triangle computed, mirrored)."""
    for r in range(9):  # X[3a+j, 3l+b] = sum_q Ce[3a+j, 3b+q] g[l, q]
        for l in range(4):
            for b in range(3):
                X[r, 3 * l + b] = (Ce[r, 3 * b] * g[e, l, 0] + Ce[r, 3 * b + 1] * g[e, l, 1]
                                   + Ce[r, 3 * b + 2] * g[e, l, 2])
    for k in range(4):
        for a in range(3):
            row = 3 * k + a
            for col in range(row, 12):
                v = vg[e, k, 0] * X[3 * a, col] + vg[e, k, 1] * X[3 * a + 1, col] + vg[e, k, 2] * X[3 * a + 2, col]
                He[e, row, col] = v
                He[e, col, row] = v


def element_hessians(C, F, vg, g, project, He, blocks=True):
    """He[e] = V_e G_e^T C_e G_e (12 x 12, node-major), C_e optionally projected to PSD.

    C (m, 9, 9) = dP/dF, F (m, 3, 3), vg = V_e grad phi (m, 4, 3), g = grad phi (m, 4, 3).
    H_e[3k+a, 3l+b] = V_e sum_jq grad_k,j C[3a+j, 3b+q] grad_l,q. C is overwritten with
    the symmetrised (and projected) tensor actually used; ``blocks=False`` only does that.
    """
    run_chunks(_element_hessians, _CHUNKS, C, F, vg, g, project, He, blocks)


@njit(cache=True, nogil=True)
def _element_hessians(c0, c1, C, F, vg, g, project, He, blocks):
    """The work units c0 .. c1 - 1 (of ``_CHUNKS``) of :func:`element_hessians`."""
    m = C.shape[0]
    for c in range(c0, c1):
        U, V, A, W = np.empty((3, 3)), np.empty((3, 3)), np.empty((3, 3)), np.empty((3, 3))
        s = np.empty(3)
        Q, CQ, Ce = np.empty((9, 9)), np.empty((9, 9)), np.empty((9, 9))
        X = np.empty((9, 12))
        for e in range(c * m // _CHUNKS, (c + 1) * m // _CHUNKS):
            _symmetric_projected(C, e, F, project, U, V, s, A, W, Q, CQ, Ce)
            if not blocks:
                continue
            element_block(Ce, vg, g, e, He, X)


@njit(cache=True)
def scatter_add(slot, values, nnz):
    """out[slot[i]] += values[i] for slot[i] >= 0 (element matrices into CSR data)."""
    out = np.zeros(nnz)
    for i in range(slot.size):
        k = slot[i]
        if k >= 0:
            out[k] += values[i]
    return out


def deformation_gradients(x, t, grads, out):
    """out[e] = sum_k x[t[k, e]] (x) grad phi_k (eq. 3; velocities give F_dot, eq. 4), (m, 3, 3).

    The compiled twin of :func:`kinematics.deformation_gradient`: numpy's einsum routes the
    batched product through multi-threaded BLAS, which is slow for many 3 x 3 products.
    """
    run_chunks(_deformation_gradients, _CHUNKS, x, t, grads, out)


@njit(cache=True, nogil=True)
def _deformation_gradients(c0, c1, x, t, grads, out):
    """The elements of work units c0 .. c1 - 1 (of ``_CHUNKS``) of :func:`deformation_gradients`."""
    m = t.shape[1]
    for e in range(c0 * m // _CHUNKS, c1 * m // _CHUNKS):
        for i in range(3):
            for j in range(3):
                acc = 0.0
                for k in range(4):
                    acc += x[t[k, e], i] * grads[e, k, j]
                out[e, i, j] = acc


def strain_rate_norms(x, v, t, grads, out):
    """out[e] = ||sym(F^T F_dot)||^2 with F from positions x and F_dot from velocities v (eq. 3-4).

    The rigidification metric (Mercier-Aubin et al. 2022) in one pass, F and F_dot kept in registers.
    """
    run_chunks(_strain_rate_norms, _CHUNKS, x, v, t, grads, out)


@njit(cache=True, nogil=True)
def _strain_rate_norms(c0, c1, x, v, t, grads, out):
    """The elements of work units c0 .. c1 - 1 (of ``_CHUNKS``) of :func:`strain_rate_norms`."""
    m = t.shape[1]
    for e in range(c0 * m // _CHUNKS, c1 * m // _CHUNKS):
        F = np.empty((3, 3))
        D = np.empty((3, 3))
        for i in range(3):
            for j in range(3):
                a = 0.0
                b = 0.0
                for k in range(4):
                    a += x[t[k, e], i] * grads[e, k, j]
                    b += v[t[k, e], i] * grads[e, k, j]
                F[i, j] = a
                D[i, j] = b
        acc = 0.0
        for i in range(3):
            for j in range(i, 3):
                s = 0.0
                for k in range(3):
                    s += F[k, i] * D[k, j] + F[k, j] * D[k, i]
                s *= 0.5
                acc += s * s if i == j else 2.0 * s * s
        out[e] = acc
