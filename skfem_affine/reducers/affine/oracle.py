r"""The prediction oracle: one preconditioned CG iteration on the full system (paper sec. 3.4).

Before clustering, the velocities of previously affine elements are predicted by
one PCG iteration from a zero initial guess on A dv = b (eq. 1-2), gravity split
out of the solve (eq. 13),

.. math:: \Delta\dot x \approx \alpha z + h g, \qquad z = A_p^{-1} b, \qquad
          \alpha = \frac{b \cdot z}{z \cdot A z},

with A z = c_M M z + c_K H z (:func:`system_operator`), A itself never formed: the
reducers apply the frame's assembled stiffness H, which the reduced system needs anyway and
whose CSR product is much cheaper than the matrix-free one (:func:`stiffness_operator`;
measurements in docs/affinification.md). A_p is a Laplacian-like approximation of A built
once at rest (eq. 14, :class:`Preconditioner`),

.. math:: A_p = (1 + h\alpha) M + (h^2 + h\beta) B^T W B, \qquad W = \mathrm{diag}(w_e I_9).

Because W is a multiple of I_9 per element, B^T W B never couples the three
displacement components: in the node-major DOF order, ``A_p = S (x) I_3`` with S
the scalar (vertex) matrix ``(1 + h alpha) M_s + (h^2 + h beta) sum_e w_e g_e^T g_e``.
Only S (a ninth of the nonzeros of A_p) is factorised, and each application
solves it for the three components.

With warm-started contact support (and explicit thresholds), the reducers start the
iteration from the bodies' mean response to it, :func:`coarse_guess` (a two-level CG's
first step): a body resting on its support is then predicted at rest, where a single
step from zero keeps most of gravity's step.
"""
import time

import numpy as np
import scipy.sparse as sp
from numba import njit
from scipy.sparse.csgraph import reverse_cuthill_mckee

from skfem_affine.integrators.problem import Rayleigh, system_coefficients
from skfem_affine.kinematics import deformation_gradient, deformation_operator
from skfem_affine.reducers.affine.ichol import SHIFTS, incomplete_cholesky
from skfem_affine.solvers import seeded_global_random

KINDS = ("ichol", "amg")

# Incomplete Cholesky of S (Lin & More's threshold variant, :mod:`.ichol`): extra entries per
# column and relative drop tolerance (docs/affinification.md has the measurements behind them).
ICHOL_FILL = 10
ICHOL_DROP = 1e-3
# Diagonal shifts S + s diag(S) tried in turn if the incomplete factorisation breaks down.
ICHOL_SHIFTS = SHIFTS


def element_moduli(system):
    """Lame parameters (mu, lam) of every element, ``(m,)`` each, from ``system.groups``."""
    mu, lam = np.empty(system.m), np.empty(system.m)
    for mat, idx in system.groups:
        mu[idx] = np.broadcast_to(mat.mu, idx.shape)
        lam[idx] = np.broadcast_to(mat.lam, idx.shape)
    return mu, lam


def laplacian_weights(system):
    """Weights w_e = V_e mu_e of A_p (eq. 14); see :class:`Preconditioner` for the choice."""
    mu, _ = element_moduli(system)
    return system.volumes * mu


def _damping(damping):
    """(alpha, beta) from a Rayleigh object, a pair, or None (undamped)."""
    if damping is None:
        return 0.0, 0.0
    if hasattr(damping, "alpha"):
        return float(damping.alpha), float(damping.beta)
    alpha, beta = damping
    return float(alpha), float(beta)


def stiffness_operator(system, C):
    """Matrix-free p -> H p on the free DOFs, H = sum_e V_e G_e^T C_e G_e (H = -K, eq. 1).

    Parameters
    ----------
    system : ElasticSystem
    C : (m, 3, 3, 3, 3) or (m, 9, 9) array
        dP/dF per element, ``C[e, 3i+j, 3k+l] = dP_ij / dF_kl``.

    Returns
    -------
    callable
        ``Hp(p)`` for a free-DOF vector p, ``(n_free,)`` -> ``(n_free,)``: p scattered
        to all DOFs (fixed ones zero), F_dot_e = G_e p (eq. 4), the stress rate
        V_e C_e : F_dot_e, and G_e^T back to the vertices by ``np.bincount``.
    """
    VC = system.volumes[:, None, None] * np.asarray(C, dtype=float).reshape(-1, 9, 9)
    t, grads, free, n = system.t, system.grads, system.free, system.n
    edofs = system.edofs.ravel()

    def apply(p):
        x = np.zeros(3 * n)
        x[free] = p
        Fd = deformation_gradient(x.reshape(n, 3), t, grads).reshape(-1, 9, 1)
        S = np.matmul(VC, Fd).reshape(-1, 3, 3)                 # V_e C_e : F_dot_e
        fe = np.einsum("eij,ekj->eki", S, grads, optimize=True)  # G_e^T, (m, 4, 3)
        return np.bincount(edofs, weights=fe.ravel(), minlength=3 * n)[free]

    return apply


def deformed_gradients(system, x):
    """Shape gradients and volumes of the elements in the configuration x (n, 3).

    grad_x phi = F^{-T} grad_X phi, i.e. rows ``grads @ F^{-1}``, and volumes ``V |det F|``;
    an element whose F is singular keeps its rest gradients and volume.
    """
    F = system.deformation_gradients(x)
    J = np.linalg.det(F)
    ok = np.isfinite(J) & (np.abs(J) > 1e-12)
    Finv = np.broadcast_to(np.eye(3), F.shape).copy()
    Finv[ok] = np.linalg.inv(F[ok])
    grads = np.einsum("ekJ,eJj->ekj", system.grads, Finv)
    volumes = system.volumes * np.where(ok, np.abs(J), 1.0)
    return grads, volumes


def scalar_matrix(system, dt, damping=None, weights=None, x=None):
    """The scalar factor S of A_p = S (x) I_3 (eq. 14), CSR over the free vertices.

    ``S = (1 + h alpha) M_s + (h^2 + h beta) B_s^T diag(w_e I_3) B_s`` where M_s and
    B_s are the first-component blocks of M and B (row ``9e + j`` of B, free DOF
    ``3v``): the x-, y- and z-blocks of both are identical and uncoupled.

    With positions ``x`` (n, 3), B_s and the volumes in w_e = V_e mu_e are those of the
    deformed configuration (:func:`deformed_gradients`): the Laplacian at the pose, which a
    refreshed oracle factorises (:class:`~skfem_affine.reducers.affine.clustered.ClusteringReducer`,
    ``refresh``). The rest S when x is None.
    """
    alpha, beta = _damping(damping)
    free = system.free
    nf = free.size // 3
    if free.size % 3 or np.any(free.reshape(nf, 3) != free[::3, None] + np.arange(3)):
        raise ValueError("free DOFs must be whole vertices (all three components)")
    w = laplacian_weights(system) if weights is None else np.broadcast_to(np.asarray(weights, float), (system.m,))
    rows = (9 * np.arange(system.m)[:, None] + np.arange(3)).ravel()  # F_0j of every element
    if x is None:
        B = system.deformation_operator()
    else:
        grads, volumes = deformed_gradients(system, x)
        w = w * volumes / system.volumes
        B = deformation_operator(system.t, grads, system.n)
    Bs = B[rows][:, free[::3]]
    L = (Bs.T @ sp.diags(np.repeat(w, 3)) @ Bs).tocsr()
    cm, ck = system_coefficients(dt, Rayleigh(alpha, beta))
    S = cm * system.Mff[::3][:, ::3] + ck * L
    S = sp.csr_matrix(S)
    S.sum_duplicates()
    S.sort_indices()
    return S


def ichol_factor(S):
    """Incomplete Cholesky of an SPD CSR matrix S after reverse Cuthill-McKee ordering.

    The threshold variant of :func:`.ichol.incomplete_cholesky` (:data:`ICHOL_FILL` extra
    entries per column, relative drop tolerance :data:`ICHOL_DROP`); on breakdown (a pivot
    that is not positive) S is shifted to S + s diag(S) for the next s in :data:`ICHOL_SHIFTS`,
    and :class:`.ichol.IncompleteCholeskyBreakdown` (a ValueError) is raised if none works.
    RCM because, for a threshold IC whose dropping depends on the elimination order, the
    bandwidth reduction is what matters, and scipy has it.

    Returns
    -------
    perm : (n,) int
        The ordering: the factor is of ``S[perm][:, perm]``.
    factor : ichol.IncompleteCholesky
        ``factor.solve(X)`` is (L L^T)^{-1} X for X of shape (n,) or (n, k).
    shift : float
        The diagonal shift used (0 when none was needed).
    """
    S = sp.csr_matrix(S)
    perm = reverse_cuthill_mckee(S, symmetric_mode=True)
    factor = incomplete_cholesky(S[perm][:, perm], fill=ICHOL_FILL, drop=ICHOL_DROP, shifts=ICHOL_SHIFTS)
    return perm, factor, factor.shift


class Preconditioner:
    r"""z ~ A_p^{-1} r for the oracle's PCG iteration, A_p = (1 + h a) M + (h^2 + h b) B^T W B (eq. 14).

    Built once at rest; ``A_p = S (x) I_3`` (module docstring), so only the scalar
    vertex matrix S is factorised and each application solves it for the three
    displacement components.

    Parameters
    ----------
    system : ElasticSystem
    dt : float
        Time step h.
    damping : Rayleigh, (alpha, beta) or None
        Rayleigh damping of the integrator (eq. 1), so that A_p matches A at rest.
    kind : {"ichol", "amg"}
        ``"ichol"``: incomplete Cholesky with threshold dropping (Lin & More 1999,
        :func:`.ichol.incomplete_cholesky`: :data:`ICHOL_FILL` extra entries per
        column, relative drop tolerance :data:`ICHOL_DROP`) of S after a reverse
        Cuthill-McKee ordering (:func:`ichol_factor`). ``"amg"``: pyamg smoothed aggregation on
        S, one V-cycle (symmetric Gauss-Seidel smoothing, so the application is SPD).
    weights : (m,) array, optional
        w_e; default :func:`laplacian_weights`, V_e mu_e.
    x : (n, 3) array, optional
        Build at this pose (the Laplacian of the deformed configuration, :func:`scalar_matrix`)
        instead of at rest.

    Notes
    -----
    **Weights.** w_e = V_e mu_e, the shear part mu grad u : grad v of the linearised tangent
    (the Laplacian-based approximation of Mercier-Aubin & Kry 2023): of the candidates
    mu / 2, mu, 2 mu, mu + lam and 2 mu + lam it gives the smallest prediction residual,
    undamped and damped, and mu / 2 to mu stay best in the energy norm for stiff bodies.

    **ichol.** Threshold IC after RCM rather than IC(0): on the bent cantilever it
    predicts about as well as an exact A_p solve, where IC(0) is clearly worse and
    collapses on a badly numbered mesh; RCM makes the result independent of the
    input vertex order, and for a threshold IC whose dropping depends on the elimination
    order the bandwidth reduction is what matters. A factor that breaks down is retried on
    S + s diag(S) (:data:`ICHOL_SHIFTS`); S, a mass-augmented P1 Laplacian, has not needed it.

    **amg.** As good a prediction as an exact A_p solve but costlier per application
    than ichol (three V-cycles, one per component), so ichol is the default; Jacobi
    smoothing would halve the cost for a worse prediction.

    Measurements behind these choices: the user guide's Affinification page, "The oracle's
    preconditioner".
    """

    def __init__(self, system, dt, damping=None, kind="ichol", weights=None, x=None):
        if kind not in KINDS:
            raise ValueError(f"preconditioner kind must be one of {KINDS}, got {kind!r}")
        self.kind = kind
        t0 = time.perf_counter()
        self.scalar = scalar_matrix(system, dt, damping, weights, x=x)
        if kind == "ichol":
            self._setup_ichol()
        else:
            self._setup_amg()
        self.setup_time = time.perf_counter() - t0

    @property
    def shape(self):
        n = 3 * self.scalar.shape[0]
        return (n, n)

    @property
    def matrix(self):
        """A_p (eq. 14) over the free DOFs as CSR, S (x) I_3 (for checks; never factorised)."""
        return sp.kron(self.scalar, sp.eye(3), format="csr")

    def _setup_ichol(self):
        self.perm, self._ic, self.shift = ichol_factor(self.scalar)

    def _setup_amg(self):
        import pyamg

        with seeded_global_random():  # pyamg's spectral radius estimate starts from np.random
            self._ml = pyamg.smoothed_aggregation_solver(self.scalar)
            self._vcycle = self._ml.aspreconditioner(cycle="V")

    def apply(self, r):
        """z ~ A_p^{-1} r for a free-DOF vector r, ``(n_free,)`` -> ``(n_free,)``."""
        R = np.asarray(r, dtype=float).reshape(-1, 3)
        if self.kind == "amg":
            return np.ascontiguousarray(self._vcycle @ R).ravel()
        Z = np.empty_like(R)
        Z[self.perm] = self._ic.solve(R[self.perm])  # the three components in one pass
        return Z.ravel()

    __call__ = apply


class TangentPreconditioner:
    r"""z ~ A^{-1} r from an incomplete Cholesky of the frame's whole A = c_M M + c_K H (3n x 3n).

    The pose-following alternative to the scalar A_p (``refresh="tangent"`` of the clustering
    reducers): it sees the stiffness of the current pose with its anisotropy, which the
    Laplacian S (x) I_3 cannot, at about nine times the nonzeros per application. Same threshold
    IC and ordering as :func:`ichol_factor`.
    """

    kind = "tangent"

    def __init__(self, A):
        t0 = time.perf_counter()
        self.perm, self._ic, self.shift = ichol_factor(A)
        self.setup_time = time.perf_counter() - t0

    def apply(self, r):
        r = np.asarray(r, dtype=float)
        z = np.empty_like(r)
        z[self.perm] = self._ic.solve(r[self.perm])
        return z

    __call__ = apply


def system_operator(mdiag, H, coefficients):
    """p -> A p = c_M M p + c_K H p from the lumped mass diagonal and the assembled H; A is never formed.

    ``coefficients`` are (c_M, c_K) of :func:`~skfem_affine.integrators.problem.system_coefficients`.
    """
    cm, ck = coefficients
    return lambda p: cm * mdiag * p + ck * (H @ p)


def body_translations(system):
    """(n_free, k) sparse basis of the bodies' translations on the free DOFs: per body and axis a
    column of ones on its free DOFs along that axis (columns without a free DOF are left out)."""
    col = 3 * np.repeat(system.body_of_vertex, 3) + np.tile(np.arange(3), system.n)  # per DOF of the 3n
    col = col[system.free]
    used, col = np.unique(col, return_inverse=True)
    return sp.csr_matrix((np.ones(col.size), (np.arange(col.size), col)), shape=(col.size, used.size))


def explicit_impulse(problem):
    r"""The contact impulses the oracle takes as explicit forces (sec. 3.4), on the free DOFs.

    The contact solver offers J^T lambda_pred (``problem.contact_impulse``): the warm-started
    support, plus for every contact that carried no impulse last frame a bilateral estimate that
    stops its vertex's approach, gravity's step included. For a new contact that is an impact
    (``problem.contacts.impact``: it closes its gap faster than one step of gravity) the estimate is
    the push the oracle must see (the paper's: a dropped ball elastifies the region it hits). On a
    body at rest it is not: a vertex that touches without carrying an impulse (its neighbours carry
    the body's weight) has only gravity's step to stop, which the warm-started support already
    balances, so the estimate is a spurious local push of the vertex's weight, which the oracle predicts
    as a deformation rate above the paper's thresholds on the paper's resting pills (measured in
    docs/contact.md, the pills at rest). The body then turns elastic, is measured on its actual
    velocities (at rest: far below the thresholds), turns affine again, and its clusters change
    every frame.

    So a body touched by an impact takes the contact solver's impulses (support and estimates), and
    every other body its warm-started support alone. Without impact flags, the contact solver's
    impulses as given.

    Returns
    -------
    (n_free,) array or 0.0
    """
    offered, support, cs = problem.contact_impulse, problem.support_impulse, problem.contacts
    if cs is None or cs.impact is None or not np.ndim(offered):
        return offered
    support = np.zeros_like(offered) if not np.ndim(support) else support
    if not np.any(cs.impact):
        return support
    sysm = problem.system
    # the bodies of the vertices an impact's normal row moves
    rows = cs.J[0::3][np.flatnonzero(cs.impact)]
    dofs = np.unique(sp.csr_matrix(rows).indices)
    dof_body = sysm.body_of_vertex[sysm.free // 3]
    hit = np.zeros(len(sysm.bodies), dtype=bool)
    hit[dof_body[dofs]] = True
    return np.where(hit[dof_body], offered, support)


def coarse_guess(T, mdiag, H, coefficients, b):
    r"""The Galerkin guess in the span of ``T``: :math:`T (T^T A T)^{-1} T^T b`, A = c_M M + c_K H.

    With T the bodies' translations (:func:`body_translations`) this is the guess of a two-level
    (deflated) CG: each body's mean velocity change under the net force on it. A body resting
    on its support is then predicted at rest, its support impulses and elastic forces balancing
    its weight, which a single PCG step from zero does not see (the part of z along a body's
    translation is scaled by the same alpha as its stiff, local parts).
    """
    cm, ck = coefficients
    T = sp.csr_matrix(T)
    if T.nnz == T.shape[0] and np.array_equal(T.indptr, np.arange(T.shape[0] + 1)) and np.all(T.data == 1.0):
        # one unit entry per row (body_translations): T^T A T by group sums over A's entries, in the
        # order of scipy's products below (the same sums)
        TAT = _grouped_system(T.indices.astype(np.int64), T.shape[1], np.asarray(mdiag, dtype=float), H.indptr,
                              H.indices, np.asarray(H.data, dtype=float), float(cm), float(ck))
    else:
        TAT = (cm * (T.T @ sp.diags(mdiag) @ T) + ck * (T.T @ (H @ T))).toarray()
    return T @ np.linalg.solve(TAT, T.T @ b)


@njit(cache=True)
def _grouped_system(group, k, mdiag, indptr, indices, data, cm, ck):
    """T^T (c_M M + c_K H) T (k x k, dense) for T with one unit entry per row (row i in column
    ``group[i]``): per row i of H its entries summed by their columns' groups in stored order, those
    row sums added over the rows of each group in increasing order (as scipy's T^T (H T)); the mass
    likewise on the diagonal."""
    Ht = np.zeros((k, k))
    Mt = np.zeros(k)
    row = np.zeros(k)
    seen = np.zeros(k, dtype=np.bool_)
    for i in range(indptr.size - 1):
        g = group[i]
        for p in range(indptr[i], indptr[i + 1]):
            c = group[indices[p]]
            row[c] += data[p]
            seen[c] = True
        for c in range(k):
            if seen[c]:
                Ht[g, c] += row[c]
                row[c] = 0.0
                seen[c] = False
        Mt[g] += mdiag[i]
    out = ck * Ht
    for g in range(k):
        out[g, g] = cm * Mt[g] + ck * Ht[g, g]
    return out


def predict(apply_A, b, precond, gravity_dv=None, stats=None, x0=None):
    r"""One PCG iteration from zero (or from ``x0``) on A dv = b, plus the split-out gravity (eq. 13).

    Parameters
    ----------
    apply_A : callable or sparse matrix
        p -> A p on the free DOFs (e.g. mass plus :func:`stiffness_operator`).
    b : (n_free,) array
        Right-hand side of eq. 2 without gravity (contact impulses enter here).
    precond : Preconditioner or callable
        r -> z ~ A_p^{-1} r (eq. 14).
    gravity_dv : (n_free,) array, optional
        h g on the free DOFs, added to the result.
    x0 : (n_free,) array, optional
        Initial guess (e.g. :func:`coarse_guess`): the iteration then runs on b - A x0 and the
        result is ``x0 + alpha z + gravity_dv``; the residual stays relative to ||b||.
    stats : dict, optional
        Receives ``oracle_residual``, the relative residual ||b - A (x0 + alpha z)|| / ||b|| of the
        iteration (how well the preconditioner predicts; computed from b.b, b.Az and Az.Az,
        no extra product with A), when b is not zero.

    Returns
    -------
    dv : (n_free,) array
        ``x0 + alpha z + gravity_dv`` with ``r = b - A x0``, ``z = P^{-1} r``, ``alpha = (r.z) / (z.A z)``;
        ``alpha = 0`` when b = 0, r = 0 or z.A z <= 0.
    """
    b = np.asarray(b, dtype=float)
    dv = np.zeros_like(b) if gravity_dv is None else np.array(gravity_dv, dtype=float)
    if not np.any(b):
        return dv
    bb = float(b @ b)
    if x0 is not None:
        dv += x0
        b = b - (apply_A(x0) if callable(apply_A) else apply_A @ x0)
        if not np.any(b):
            return dv
    z = getattr(precond, "apply", precond)(b)
    Az = apply_A(z) if callable(apply_A) else apply_A @ z
    zAz = float(z @ Az)
    if not (np.isfinite(zAz) and zAz > 0):
        return dv
    alpha = float(b @ z) / zAz
    if stats is not None:
        rr = float(b @ b) - 2.0 * alpha * float(b @ Az) + alpha * alpha * float(Az @ Az)
        stats["oracle_residual"] = float(np.sqrt(max(rr, 0.0) / bb))
    return dv + alpha * z
