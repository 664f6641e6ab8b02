"""One compiled pass per element: F -> P, dP/dF projected to PSD, element block, element force.

The projection uses the analytic eigensystems of isotropic energies (Smith, de Goes & Kim
2019, "Analytic eigensystems for isotropic distortion energies"). With the rotation-variant
SVD F = U diag(s) V^T and Psi(s) the energy as a function of the signed singular values,
dP/dF is diagonal in the basis Q_k = U E_k V^T of :func:`_kernels._mode`:

* twist of the pair (i, j) (antisymmetric E_k): eigenvalue (Psi_i + Psi_j) / (s_i + s_j);
* flip of the pair (i, j) (symmetric, off-diagonal E_k): eigenvalue (Psi_i - Psi_j) / (s_i - s_j);
* the three scalings u_i v_i^T span an invariant subspace where dP/dF is d^2 Psi / ds^2 (3 x 3).

:func:`_spectrum` has the quotients of our three materials in closed form, written without
division by s_i - s_j (so repeated singular values are exact). The projection subtracts
lambda_k q_k q_k^T for the negative modes only, so a PSD element costs one SVD and no
9 x 9 work. Materials without a closed form (``code`` 0, any user :class:`Material`)
keep the Rayleigh-quotient projection of :func:`_kernels._project_modes`.
"""
import numpy as np
from numba import njit

from skfem_affine import _compile_notice  # noqa: F401 (one stderr line when the cached kernels compile)
from skfem_affine._kernels import _CHUNKS, _LANES, _mode, _symmetric_projected, _sym_eig3, element_block, svd3_lanes
from skfem_affine.threads import run_chunks

GENERIC, STVK, COROTATIONAL, NEOHOOKEAN = 0, 1, 2, 3


@njit(cache=True)
def _spectrum(code, mu, lam, s, twist, flip, Hs):
    """Twist and flip eigenvalues of pair k (the pair without index k) and the scaling Hessian Hs.

    ``lam`` is lam' = lam + mu for the stable Neo-Hookean (as :class:`NeoHookean` uses it).
    """
    if code == STVK:  # Psi_i = s_i (mu (s_i^2 - 1) + lam trE)
        trE = 0.5 * (s[0] * s[0] + s[1] * s[1] + s[2] * s[2] - 3.0)
        for k in range(3):
            i, j = (k + 1) % 3, (k + 2) % 3
            a = mu * (s[i] * s[i] + s[j] * s[j] - 1.0) + lam * trE
            twist[k] = a - mu * s[i] * s[j]
            flip[k] = a + mu * s[i] * s[j]
        for i in range(3):
            for j in range(3):
                Hs[i, j] = lam * s[i] * s[j]
            Hs[i, i] += mu * (3.0 * s[i] * s[i] - 1.0) + lam * trE
    elif code == COROTATIONAL:  # Psi_i = 2 mu (s_i - 1) + lam (tr S - 3)
        trs = s[0] + s[1] + s[2] - 3.0
        for k in range(3):
            den = s[(k + 1) % 3] + s[(k + 2) % 3]
            if abs(den) < 1e-12:
                den = 1e-12 if den >= 0 else -1e-12
            twist[k] = 2.0 * mu + (2.0 * lam * trs - 4.0 * mu) / den
            flip[k] = 2.0 * mu
        for i in range(3):
            for j in range(3):
                Hs[i, j] = lam
            Hs[i, i] += 2.0 * mu
    else:  # stable Neo-Hookean: Psi_i = mu s_i + sJ s_j s_k, sJ = lam' (J - 1) - mu
        c0, c1, c2 = s[1] * s[2], s[0] * s[2], s[0] * s[1]  # dJ/ds_i
        sJ = lam * (s[0] * c0 - 1.0) - mu
        for k in range(3):
            twist[k] = mu + sJ * s[k]
            flip[k] = mu - sJ * s[k]
        Hs[0, 0] = mu + lam * c0 * c0
        Hs[1, 1] = mu + lam * c1 * c1
        Hs[2, 2] = mu + lam * c2 * c2
        Hs[0, 1] = Hs[1, 0] = lam * c0 * c1 + sJ * s[2]
        Hs[0, 2] = Hs[2, 0] = lam * c0 * c2 + sJ * s[1]
        Hs[1, 2] = Hs[2, 1] = lam * c1 * c2 + sJ * s[0]


@njit(cache=True)
def _positive_definite3(A):
    """Sylvester's criterion for a symmetric 3 x 3."""
    m2 = A[0, 0] * A[1, 1] - A[0, 1] * A[0, 1]
    det = (A[0, 0] * (A[1, 1] * A[2, 2] - A[1, 2] * A[1, 2]) - A[0, 1] * (A[0, 1] * A[2, 2] - A[1, 2] * A[0, 2])
           + A[0, 2] * (A[0, 1] * A[1, 2] - A[1, 1] * A[0, 2]))
    return A[0, 0] > 0.0 and m2 > 0.0 and det > 0.0


@njit(cache=True)
def _subtract(Ce, lam, q):
    """Upper triangle of Ce -= lam q q^T (:func:`_mirror` completes it)."""
    for a in range(9):
        w = lam * q[a]
        for b in range(a, 9):
            Ce[a, b] -= w * q[b]


@njit(cache=True)
def _mirror(Ce):
    """Lower triangle of Ce <- its upper triangle."""
    for a in range(1, 9):
        for b in range(a):
            Ce[a, b] = Ce[b, a]


@njit(cache=True)
def _clamp_modes(Ce, U, V, twist, flip, Hs, W, Q, q):
    """Remove the negative modes of Ce (analytic spectrum, modes from U, V) in place."""
    changed = False
    for k in range(3):
        if twist[k] < 0.0:
            _mode(3 + k, U, V, q)
            _subtract(Ce, twist[k], q)
            changed = True
        if flip[k] < 0.0:
            _mode(6 + k, U, V, q)
            _subtract(Ce, flip[k], q)
            changed = True
    if not _positive_definite3(Hs):
        _sym_eig3(Hs, W)
        built = False
        for k in range(3):
            lam = Hs[k, k]
            if lam < 0.0:
                if not built:
                    for a in range(3):
                        _mode(a, U, V, Q[a])
                    built = True
                for a in range(9):
                    q[a] = W[0, k] * Q[0, a] + W[1, k] * Q[1, a] + W[2, k] * Q[2, a]
                _subtract(Ce, lam, q)
                changed = True
    if changed:
        _mirror(Ce)


@njit(cache=True)
def _cofactor(f, g):
    """g = vec(cof f) = d det f / d f, row-major."""
    g[0] = f[1, 1] * f[2, 2] - f[1, 2] * f[2, 1]
    g[1] = f[1, 2] * f[2, 0] - f[1, 0] * f[2, 2]
    g[2] = f[1, 0] * f[2, 1] - f[1, 1] * f[2, 0]
    g[3] = f[0, 2] * f[2, 1] - f[0, 1] * f[2, 2]
    g[4] = f[0, 0] * f[2, 2] - f[0, 2] * f[2, 0]
    g[5] = f[0, 1] * f[2, 0] - f[0, 0] * f[2, 1]
    g[6] = f[0, 1] * f[1, 2] - f[0, 2] * f[1, 1]
    g[7] = f[0, 2] * f[1, 0] - f[0, 0] * f[1, 2]
    g[8] = f[0, 0] * f[1, 1] - f[0, 1] * f[1, 0]


@njit(cache=True)
def _neohookean(f, mu, lam, want_C, Pe, Ce, g):
    """P = mu F + (lam' (J - 1) - mu) cof F and dP/dF = lam' g g^T + (lam' (J - 1) - mu) d^2J/dF^2 + mu I.

    d^2 J / dF_ij dF_kl = eps_ikp eps_jlq F_pq (one signed entry of F or 0).
    """
    _cofactor(f, g)
    J = f[0, 0] * g[0] + f[0, 1] * g[1] + f[0, 2] * g[2]
    sJ = lam * (J - 1.0) - mu
    for a in range(3):
        for b in range(3):
            Pe[a, b] = mu * f[a, b] + sJ * g[3 * a + b]
    if not want_C:
        return
    for r in range(9):
        for c in range(9):
            Ce[r, c] = lam * g[r] * g[c]
        Ce[r, r] += mu
    for i in range(3):
        for k in range(3):
            if i == k:
                continue
            p = 3 - i - k
            sik = 1.0 if (k - i) % 3 == 1 else -1.0  # eps_ikp
            for j in range(3):
                for l in range(3):
                    if j == l:
                        continue
                    q = 3 - j - l
                    sjl = 1.0 if (l - j) % 3 == 1 else -1.0
                    Ce[3 * i + j, 3 * k + l] += sJ * sik * sjl * f[p, q]


@njit(cache=True)
def _stvk(f, mu, lam, want_C, Pe, Ce, Cg, B):
    """P = F S, S = 2 mu E + lam tr(E) I; dP_ijkl = d_ik S_lj + mu (F_il F_kj + (F F^T)_ik d_jl) + lam F_ij F_kl."""
    for a in range(3):
        for b in range(3):
            Cg[a, b] = f[0, a] * f[0, b] + f[1, a] * f[1, b] + f[2, a] * f[2, b]
            B[a, b] = f[a, 0] * f[b, 0] + f[a, 1] * f[b, 1] + f[a, 2] * f[b, 2]
    tr = 0.5 * (Cg[0, 0] + Cg[1, 1] + Cg[2, 2] - 3.0)
    for a in range(3):  # Cg <- S
        for b in range(3):
            Cg[a, b] = mu * (Cg[a, b] - (1.0 if a == b else 0.0)) + (lam * tr if a == b else 0.0)
    for a in range(3):
        for b in range(3):
            Pe[a, b] = f[a, 0] * Cg[0, b] + f[a, 1] * Cg[1, b] + f[a, 2] * Cg[2, b]
    if not want_C:
        return
    for i in range(3):
        for j in range(3):
            for k in range(3):
                for l in range(3):
                    v = mu * f[i, l] * f[k, j] + lam * f[i, j] * f[k, l]
                    if i == k:
                        v += Cg[l, j]
                    if j == l:
                        v += mu * B[i, k]
                    Ce[3 * i + j, 3 * k + l] = v


@njit(cache=True)
def _corotational(f, mu, lam, want_C, project, U, s, V, twist, Pe, Ce, q):
    """P = 2 mu (F - R) + lam (tr S - 3) R, R = U V^T, and from the modes
    dP/dF = 2 mu I + lam r r^T + sum_twists (twist_k - 2 mu) q_k q_k^T, r = vec R
    (the scaling block is 2 mu I + lam 1 1^T and every flip is 2 mu); projected twists clamped at 0.
    """
    trs = s[0] + s[1] + s[2] - 3.0
    for a in range(3):
        for b in range(3):
            r = U[a, 0] * V[b, 0] + U[a, 1] * V[b, 1] + U[a, 2] * V[b, 2]
            Pe[a, b] = 2.0 * mu * (f[a, b] - r) + lam * trs * r
            q[3 * a + b] = r
    if not want_C:
        return
    for a in range(9):
        for b in range(9):
            Ce[a, b] = lam * q[a] * q[b]
        Ce[a, a] += 2.0 * mu
    for k in range(3):
        if project and twist[k] < 0.0:
            twist[k] = 0.0
        _mode(3 + k, U, V, q)
        _subtract(Ce, 2.0 * mu - twist[k], q)
    _mirror(Ce)


@njit(cache=True)
def _element_force(Pe, vg, e, out):
    """out (4, 3) = -V_e P_e grad phi_k: the element's internal force at its vertices."""
    for k in range(4):
        for a in range(3):
            out[k, a] = -(Pe[a, 0] * vg[e, k, 0] + Pe[a, 1] * vg[e, k, 1] + Pe[a, 2] * vg[e, k, 2])


def evaluate_elements(F, code, mu, lam, project, P, C, vg, g, He, fe):
    """Per element e: P[e], C[e] = dP/dF (9 x 9, PSD-projected if ``project``), He[e], fe[e].

    F (m, 3, 3); code (m,) one of GENERIC, STVK, COROTATIONAL, NEOHOOKEAN; mu, lam (m,)
    (lam' = lam + mu for Neo-Hookean). An output with a zero-length first axis is skipped:
    P (m, 3, 3), C (m, 9, 9), He (m, 12, 12) = V_e G^T C G (needs C), fe (m, 4, 3) =
    -V_e P grad phi (the element's internal force, needs P); vg = V_e grad phi and
    g = grad phi (m, 4, 3) are needed for He and fe. For GENERIC elements the caller fills
    P[e] and C[e] (unprojected) first; C[e] is symmetrised and projected by Rayleigh quotients.
    """
    run_chunks(_evaluate_chunks, _CHUNKS, F, code, mu, lam, project, P, C, vg, g, He, fe)


@njit(cache=True, nogil=True, fastmath={"contract"})
def _evaluate_chunks(c0, c1, F, code, mu, lam, project, P, C, vg, g, He, fe):
    """The elements of work units c0 .. c1 - 1 (of ``_CHUNKS``) of :func:`evaluate_elements`."""
    m = F.shape[0]
    want_P, want_C = P.shape[0] > 0, C.shape[0] > 0
    want_He, want_f = He.shape[0] > 0, fe.shape[0] > 0
    for c in range(c0, c1):
        A, W, B, Hs = np.empty((3, 3)), np.empty((3, 3)), np.empty((3, 3)), np.empty((3, 3))
        Us, Vs, ss = np.empty((_LANES, 3, 3)), np.empty((_LANES, 3, 3)), np.empty((_LANES, 3))
        a, v = np.empty((6, _LANES)), np.empty((9, _LANES))
        twist, flip = np.empty(3), np.empty(3)
        Q, CQ, Ce = np.empty((9, 9)), np.empty((9, 9)), np.empty((9, 9))
        Pe = np.empty((3, 3))
        q = np.empty(9)
        X = np.empty((9, 12))
        start, stop = c * m // _CHUNKS, (c + 1) * m // _CHUNKS
        for e0 in range(start, stop, _LANES):
            need_svd = False
            for e in range(e0, min(e0 + _LANES, stop)):
                if code[e] == COROTATIONAL or (want_C and project and code[e] != GENERIC):
                    need_svd = True
            if need_svd:
                svd3_lanes(F, e0, stop, Us, ss, Vs, a, v, A, W)
            for e in range(e0, min(e0 + _LANES, stop)):
                U, V, s = Us[e - e0], Vs[e - e0], ss[e - e0]
                ce = code[e]
                if ce == GENERIC:
                    if want_C:
                        _symmetric_projected(C, e, F, project, U, V, s, A, W, Q, CQ, Ce)
                    if want_P:
                        for i in range(3):
                            for j in range(3):
                                Pe[i, j] = P[e, i, j]
                else:
                    if ce == COROTATIONAL or (want_C and project):
                        _spectrum(ce, mu[e], lam[e], s, twist, flip, Hs)
                    if ce == NEOHOOKEAN:
                        _neohookean(F[e], mu[e], lam[e], want_C, Pe, Ce, q)
                    elif ce == STVK:
                        _stvk(F[e], mu[e], lam[e], want_C, Pe, Ce, A, B)
                    else:
                        _corotational(F[e], mu[e], lam[e], want_C, project, U, s, V, twist, Pe, Ce, q)
                    if want_C:
                        if project:
                            _clamp_modes(Ce, U, V, twist, flip, Hs, W, Q, q)
                        C[e] = Ce
                    if want_P:
                        P[e] = Pe
                if want_He:
                    element_block(Ce, vg, g, e, He, X)
                if want_f:
                    _element_force(Pe, vg, e, fe[e])


@njit(cache=True)
def internal_force(P, vg, t, n):
    """f (3n,) = -sum_e V_e P_e grad phi from the stresses P (m, 3, 3)."""
    fe = np.empty((P.shape[0], 4, 3))
    for e in range(P.shape[0]):
        _element_force(P[e], vg, e, fe[e])
    return scatter_forces(t, fe, n)


@njit(cache=True)
def scatter_forces(t, fe, n):
    """f (3n,) = sum of the element forces fe (m, 4, 3) at their vertices t (4, m)."""
    f = np.zeros(3 * n)
    for e in range(fe.shape[0]):
        for k in range(4):
            v = 3 * t[k, e]
            for a in range(3):
                f[v + a] += fe[e, k, a]
    return f
