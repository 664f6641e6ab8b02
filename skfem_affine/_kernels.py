"""Compiled per-element kernels (numba) for the few hot spots numpy batches poorly.

numpy's batched 3 x 3 SVD and eigh pay a LAPACK call per element (40 ms for
24k tets); these kernels do the same work in registers, in parallel.
"""
import numpy as np
from numba import njit, prange


@njit(cache=True, inline="always")
def _sym_eig3(A, V):
    """Cyclic Jacobi on a symmetric 3x3 A (overwritten: diagonal -> eigenvalues); V <- eigenvectors."""
    for i in range(3):
        for j in range(3):
            V[i, j] = 1.0 if i == j else 0.0
    for sweep in range(12):
        off = A[0, 1] ** 2 + A[0, 2] ** 2 + A[1, 2] ** 2
        if off <= 1e-30 * (A[0, 0] ** 2 + A[1, 1] ** 2 + A[2, 2] ** 2) or off == 0.0:
            break
        for p in range(2):
            for q in range(p + 1, 3):
                apq = A[p, q]
                if apq == 0.0:
                    continue
                theta = (A[q, q] - A[p, p]) / (2.0 * apq)
                t = (1.0 if theta >= 0 else -1.0) / (abs(theta) + np.sqrt(theta * theta + 1.0))
                c = 1.0 / np.sqrt(t * t + 1.0)
                s = t * c
                for k in range(3):  # A <- J^T A J
                    akp, akq = A[k, p], A[k, q]
                    A[k, p] = c * akp - s * akq
                    A[k, q] = s * akp + c * akq
                for k in range(3):
                    apk, aqk = A[p, k], A[q, k]
                    A[p, k] = c * apk - s * aqk
                    A[q, k] = s * apk + c * aqk
                for k in range(3):
                    vkp, vkq = V[k, p], V[k, q]
                    V[k, p] = c * vkp - s * vkq
                    V[k, q] = s * vkp + c * vkq


@njit(cache=True, inline="always")
def _cross(a, b, out):
    out[0] = a[1] * b[2] - a[2] * b[1]
    out[1] = a[2] * b[0] - a[0] * b[2]
    out[2] = a[0] * b[1] - a[1] * b[0]


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


@njit(cache=True)
def _project_one(Ce, Fe, modes, U, V, s, A, Q, T, D, W):
    svd3(Fe, U, s, V, A)
    for k in range(9):  # Q[:, k] = vec(U E_k V^T)
        for a in range(3):
            for b in range(3):
                acc = 0.0
                for i in range(3):
                    for j in range(3):
                        acc += U[a, i] * modes[k, 3 * i + j] * V[b, j]
                Q[3 * a + b, k] = acc
    for i in range(9):  # T = C Q (C symmetrised on the fly)
        for k in range(9):
            acc = 0.0
            for j in range(9):
                acc += 0.5 * (Ce[i, j] + Ce[j, i]) * Q[j, k]
            T[i, k] = acc
    for i in range(9):  # D = Q^T T
        for k in range(9):
            acc = 0.0
            for j in range(9):
                acc += Q[j, i] * T[j, k]
            D[i, k] = acc
    for i in range(3):
        for j in range(3):
            A[i, j] = D[i, j]
    _sym_eig3(A, W)
    psd = min(A[0, 0], A[1, 1], A[2, 2]) >= 0.0
    for k in range(3, 9):
        psd = psd and D[k, k] >= 0.0
    if psd:
        return
    for i in range(9):
        for j in range(9):
            D[i, j] = 0.0 if (i >= 3 or j >= 3) and i != j else D[i, j]
    for i in range(3):
        for j in range(3):
            acc = 0.0
            for k in range(3):
                acc += W[i, k] * max(A[k, k], 0.0) * W[j, k]
            D[i, j] = acc
    for k in range(3, 9):
        D[k, k] = max(D[k, k], 0.0)
    for i in range(9):  # C = Q D Q^T
        for k in range(9):
            acc = 0.0
            for j in range(9):
                acc += Q[i, j] * D[j, k]
            T[i, k] = acc
    for i in range(9):
        for k in range(9):
            acc = 0.0
            for j in range(9):
                acc += T[i, j] * Q[k, j]
            Ce[i, k] = acc


@njit(cache=True, parallel=True)
def project_isotropic(C, F, modes):
    """In place: clamp the eigenvalues of each isotropic dP/dF (m, 9, 9) to >= 0.

    ``modes`` (9, 9): row k is vec(E_k), the scaling/twist/flip basis. See
    :func:`skfem_affine.materials.project_psd`. PSD elements are left as they are.
    """
    m = C.shape[0]
    chunks = 64
    for c in prange(chunks):
        U, V, A, W = np.empty((3, 3)), np.empty((3, 3)), np.empty((3, 3)), np.empty((3, 3))
        s = np.empty(3)
        Q, T, D = np.empty((9, 9)), np.empty((9, 9)), np.empty((9, 9))
        for e in range(c * m // chunks, (c + 1) * m // chunks):
            _project_one(C[e], F[e], modes, U, V, s, A, Q, T, D, W)
