r"""Adaptive subspace reducer: modal subspace plus nodal enrichment (Trusty et al., sec. 3.2-3.11).

Each time step minimises the incremental potential E (:mod:`skfem_affine.newton`) by Newton
iterations in an adaptive space, keeping the full positions x as the state (sec. 3.2). One
iteration at x (Algorithm 1):

1. ``assembly``: forces and projected dP/dF at x; element blocks only in subdomains that need
   exact evaluation (those with an element touching an enriched node, sec. 3.9);
2. ``reduced_assembly`` (subspace Hessian, sec. 3.9): per subdomain l of a fixed METIS
   decomposition (``subdomains``), the elastic part U_a^T H_l U_a is a BFGS approximation
   (eq. 20), exact where enrichment touches; inertia and damping are exact;
3. ``prediction`` (the oracle, sec. 3.7): the unmasked subspace direction d_q = -H_a^-1 U_a^T grad E
   (eq. 18) scaled by a line search, then nodal and modal errors and progress
   (:mod:`skfem_affine.subspace_oracle`, eq. 5-17); a node activates its whole subdomain and a
   block of modes activates when error > eps and progress < eps_progress;
4. the non-overlapping decomposition (sec. 3.6): B_a = U_a with the enriched rows masked, S_a
   selects the enriched DOFs, and the coupled system (eq. 19)
   [[H_q, C], [C^T, H_x]] [d_q; d_x] = -[g_q; g_x] is solved by the Schur complement (eq. 21-22):
   ``factorization`` = dense Cholesky of H_q, ``solve`` = PCG with 3 x 3 block-Jacobi on
   H_x - C^T H_q^-1 C applied matrix-free (sec. 3.10; relative tolerance ``pcg_tol`` = 1e-5);
5. ``line_search`` on E(x + alpha (B_a d_q + S_a d_x)); stop when ||d||_inf / h <= newton_tol * size.

After the step, modes and nodes whose contribution was small are downdated (sec. 3.11); the
starting blocks of the basis (a body's affine/rigid motion) are never downdated.

Choices where the paper is silent, stated here: subdomains are element sets (an element belongs
to the METIS part of its first vertex), so the subdomain energies sum exactly to Psi and no
interface averaging is needed in eq. 20; the BFGS update is skipped when y^T s <= 0 (keeping
every H_l positive semi-definite) and reduces to y y^T / y^T s when s^T H_l s = 0; the characteristic
length l of sec. 3.11 is the scene's bounding-box diagonal.
"""
import time

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp

from skfem_affine.integrators import newton

from skfem_affine.reducers.subspace import oracle as so
from skfem_affine.integrators.newton import vdot
from skfem_affine._kernels import scatter_add
from skfem_affine.assembly import Pattern
from skfem_affine.reducers.subspace.bases import SkinningEigenmodes, _Basis
from skfem_affine.checks import positive
from skfem_affine.solvers import SolverError
from skfem_affine import threads


def _threshold(value, name):
    value = float(value)
    if not (value >= 0):
        raise ValueError(f"threshold {name} must be >= 0, got {value}")
    return value


def metis_parts(system, nparts):
    """Vertex partition into ``nparts`` subdomains of the mesh graph (METIS via pymetis)."""
    n = system.n
    nparts = int(min(max(nparts, 1), n))
    if nparts == 1:
        return np.zeros(n, dtype=np.int64)
    import pymetis
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


def forces(system, x):
    """F, P and the internal force f at positions x (n, 3): no tangent."""
    F = system.deformation_gradients(x)
    P, _ = system.stresses(F, tangent=False)
    return F, P, system._internal_force(P)


class _BlockDiagonal:
    """CSR pattern of a block-diagonal matrix stacked from per-block :class:`Pattern` s."""

    def __init__(self, patterns):
        nnz = np.cumsum([0] + [p.nnz for p in patterns])
        size = np.cumsum([0] + [p.shape[0] for p in patterns])
        self.slot = np.concatenate([np.where(p.slot >= 0, p.slot + o, -1) for p, o in zip(patterns, nnz[:-1])])
        self.indices = np.concatenate([p.indices + s for p, s in zip(patterns, size[:-1])]).astype(np.int32)
        self.indptr = np.concatenate([[0]] + [p.indptr[1:] + o for p, o in zip(patterns, nnz[:-1])]).astype(np.int32)
        self.nnz, self.shape = int(nnz[-1]), (int(size[-1]), int(size[-1]))

    def scatter(self, blocks):
        return scatter_add(self.slot, blocks.reshape(-1), self.nnz)

    def matrix(self, data):
        return sp.csr_matrix((data, self.indices, self.indptr), shape=self.shape)


class _Subdomains:
    """Element subdomains of a fixed vertex partition with the data for exact U^T H_l U (sec. 3.9)."""

    def __init__(self, system, parts):
        self.parts = parts
        self.L = int(parts.max()) + 1
        self.of_element = parts[system.t[0]]
        dof_map = np.full(3 * system.n, -1, dtype=np.int64)
        dof_map[system.free] = np.arange(system.free.size)
        self.elems, self.dofs, self.patterns = [], [], []
        self.local = np.full((system.m, 12), -1, dtype=np.int64)  # DOF's index within its element's subdomain
        order = np.argsort(self.of_element, kind="stable")
        bounds = np.searchsorted(self.of_element[order], np.arange(self.L + 1))
        for l in range(self.L):  # once, at set-up: per-subdomain element and DOF lists
            el = order[bounds[l]:bounds[l + 1]]
            ed = dof_map[system.edofs[el]]  # (k, 12)
            dofs = np.unique(ed[ed >= 0])
            self.local[el] = np.where(ed >= 0, np.searchsorted(dofs, np.where(ed >= 0, ed, 0)), -1)
            self.elems.append(el)
            self.dofs.append(dofs)
            loc = self.local[el]
            self.patterns.append(Pattern(np.where(loc >= 0, loc, dofs.size),
                                         np.concatenate([np.arange(dofs.size), [-1]])))
        rows = dof_map[system.edofs].ravel()
        ok = rows >= 0
        self.grad_rows, self.grad_cols, self.grad_keep = rows[ok], np.repeat(self.of_element, 12)[ok], ok
        self.nfree = system.free.size
        self._stacks = {}

    def exact(self, He, which, U):
        """U_l^T H_l U_l (len(which), a, a) from element blocks He (m, 12, 12).

        The subdomains' elastic Hessians are scattered at once into one block-diagonal sparse
        matrix over their stacked local DOFs; then one sparse product H U and a small dense
        product per subdomain.
        """
        which = np.asarray(list(which), dtype=np.int64)
        a = U.shape[1]
        out = np.zeros((which.size, a, a))
        if not which.size:
            return out
        pattern, elems, off, dofs = self._stacked(which)
        HU = pattern.matrix(pattern.scatter(He[elems])) @ U[dofs]
        Us = U[dofs]
        for k in range(len(which)):  # small dense products, one per subdomain
            seg = slice(off[k], off[k + 1])
            out[k] = Us[seg].T @ HU[seg]
        return out

    def exact_sum(self, He, which, U, masked=None):
        """sum_l B_l^T H_l B_l over subdomains ``which`` (a, a), B = U with the rows in the boolean
        mask ``masked`` (free DOFs) zeroed; only the unmasked rows are multiplied."""
        which = np.asarray(list(which), dtype=np.int64)
        a = U.shape[1]
        if not which.size:
            return np.zeros((a, a))
        pattern, elems, off, dofs = self._stacked(which)
        H = pattern.matrix(pattern.scatter(He[elems]))
        if masked is None:
            Us = U[dofs]
            return Us.T @ (H @ Us)
        keep = np.flatnonzero(~masked[dofs])
        Bs = U[dofs[keep]]
        return Bs.T @ (H[keep][:, keep] @ Bs)

    def _stacked(self, which):
        """Block-diagonal pattern of subdomains ``which`` over their stacked local DOFs, stacked
        from the per-subdomain patterns (no sorting), with the elements, DOF offsets and DOFs."""
        key = which.tobytes()
        if key not in self._stacks:
            if len(self._stacks) >= 8:
                self._stacks.pop(next(iter(self._stacks)))
            off = np.concatenate([[0], np.cumsum([self.dofs[l].size for l in which])])
            self._stacks[key] = (_BlockDiagonal([self.patterns[l] for l in which]),
                                 np.concatenate([self.elems[l] for l in which]), off,
                                 np.concatenate([self.dofs[l] for l in which]))
        return self._stacks[key]

    def projected_gradients(self, ge, U):
        """U^T grad Psi_l per subdomain, (L, a), from element gradients ge (m, 4, 3)."""
        G = sp.csr_matrix((ge.reshape(-1)[self.grad_keep], (self.grad_rows, self.grad_cols)),
                          shape=(self.nfree, self.L))
        return np.asarray((G.T @ U))


class AdaptiveSubspace:
    """Adaptive subspace time integration (Trusty et al.): modes + nodal enrichment with an oracle.

    Parameters
    ----------
    basis : a basis spec from :mod:`skfem_affine.bases` (default ``SkinningEigenmodes(n=16)``)
    eps_nodal, eps_modal : float
        Error thresholds (dimensionless, eq. 10 and 14); lower enriches more. 0 with
        ``eps_progress=inf`` enriches every node with an error: the full-space solve.
    eps_progress : float
        Progress threshold (eq. 11, 15): a candidate activates only if the current subspace
        makes less progress than this there. ``inf`` switches the progress test off.
    eps_down : float
        Downdating threshold (sec. 3.11), relative to (scene size x h).
    subdomains : int
        Number of METIS subdomains for nodal enrichment and BFGS (sec. 3.6, 3.9).
    newton_tol : float
        ||d||_inf / h <= newton_tol * scene size ends a step.
    max_newton, pcg_tol, pcg_maxiter : iteration caps and the PCG tolerance (paper 1e-5).
    hessian_init : {"rest", "exact"}
        What the per-subdomain BFGS Hessians start from at each step and after a basis change:
        the rest-state subspace Hessians (precomputed once; default) or the exact ones at the
        current iterate (all element Hessians, a full evaluation per step).
    blas_threads : int or None
        BLAS threads inside the step (default 1, see :meth:`minimize`); None leaves them alone.
    record_residual : bool
        Also record the full-space Newton decrement of each step's result (a full solve; for
        measuring accuracy only).

    Runs with ``Simulation(..., integrator="implicit_euler" | "bdf2")``.
    """

    name = "adaptive_subspace"

    def __init__(self, basis=None, eps_nodal=0.5, eps_modal=0.5, eps_progress=1e-4, eps_down=0.1,
                 subdomains=200, newton_tol=1e-3, max_newton=50, pcg_tol=1e-5, pcg_maxiter=10000,
                 record_residual=False, hessian_init="rest", blas_threads=1):
        basis = SkinningEigenmodes(n=16) if basis is None else basis
        if not isinstance(basis, _Basis):
            raise TypeError(f"basis must be a basis such as sa.SkinningEigenmodes(n=16), got {type(basis).__name__}")
        self.basis_spec = basis
        self.eps_nodal = _threshold(eps_nodal, "eps_nodal")
        self.eps_modal = _threshold(eps_modal, "eps_modal")
        self.eps_progress = _threshold(eps_progress, "eps_progress")
        self.eps_down = _threshold(eps_down, "eps_down")
        if int(subdomains) < 1:
            raise ValueError(f"subdomains must be >= 1, got {subdomains}")
        self.n_subdomains = int(subdomains)
        self.newton_tol = positive(newton_tol, "newton_tol")
        self.max_newton = int(max_newton)
        self.pcg_tol = positive(pcg_tol, "pcg_tol")
        self.pcg_maxiter = int(pcg_maxiter)
        self.record_residual = bool(record_residual)
        if hessian_init not in ("rest", "exact"):
            raise ValueError(f"hessian_init must be 'rest' or 'exact', got {hessian_init!r}")
        self.hessian_init = hessian_init
        self.blas_threads = None if blas_threads is None else int(blas_threads)

    def __repr__(self):
        return (f"AdaptiveSubspace(basis={self.basis_spec!r}, eps_nodal={self.eps_nodal}, eps_modal={self.eps_modal}, "
                f"eps_progress={self.eps_progress}, eps_down={self.eps_down}, subdomains={self.n_subdomains})")

    # ------------------------------------------------------------------ set-up
    def attach(self, sim):
        if sim.stepper is None:
            raise ValueError("AdaptiveSubspace needs Simulation(..., integrator='implicit_euler' or 'bdf2')")
        t0 = time.perf_counter()
        sysm = sim.system
        self.sim, self.system = sim, sysm
        self.basis = self.basis_spec.build(sysm)
        self.U = self.basis.U[sysm.free]  # (nfree, r)
        self.queries = so.ModalQueries(self.basis.U, self.basis.blocks)
        self.area_scale, self.volume_scale = so.node_scaling(sysm)
        self.ring = so.OneRing(sysm)
        self.sub = _Subdomains(sysm, metis_parts(sysm, self.n_subdomains))
        self.active = sorted(set(self.basis.initial))
        self.permanent = set(self.basis.initial)
        self.enriched = np.zeros(sysm.n, dtype=bool)
        self.free_vertex = np.zeros(sysm.n, dtype=bool)
        self.free_vertex[sysm.free // 3] = True
        self.dof_map = np.full(3 * sysm.n, -1, dtype=np.int64)
        self.dof_map[sysm.free] = np.arange(sysm.free.size)
        if self.hessian_init == "rest":
            rest = sysm.evaluate(sysm.p0, project=sim.project_hessian)
            self.rest_hessians = self.sub.exact(rest.He, range(self.sub.L), self.U)
        self.setup_time = time.perf_counter() - t0
        self.last_system = self.last_hessians = None
        self._inertia_cache = {}

    def solve(self, sim, rec):
        raise ValueError("AdaptiveSubspace runs with integrator='implicit_euler' or 'bdf2'")

    def columns(self):
        return np.concatenate([self.basis.blocks[j] for j in self.active])

    def _enriched_dofs(self):
        v = np.flatnonzero(self.enriched)
        return self.dof_map[(3 * v[:, None] + np.arange(3)).ravel()]

    # ------------------------------------------------------------------ one step
    def minimize(self, ip, rec):
        """Algorithm 1: the adaptive Newton solve of one step; returns x_{t+1} (flat).

        Runs with ``blas_threads`` BLAS threads (default 1): the dense products here are small
        (a few hundred modes), and OpenBLAS's thread hand-off cost more than it saved
        (measured 2.3x slower per frame on the 24k-tet beam with 2 threads).
        """
        with threads.blas_threads(self.blas_threads):
            return self._minimize(ip, rec)

    def _minimize(self, ip, rec):
        sim, sysm, sub = self.sim, self.system, self.sub
        w, free = ip.weight, ip.free
        x = ip.x_t.copy()
        Meff = sysm.pattern.matrix(ip.hessian_data(np.zeros(sysm.pattern.nnz))).copy()  # M + w D (exact)
        Meff.eliminate_zeros()  # diagonal for lumped mass without beta damping (the copy keeps the pattern intact)
        UMU = self._inertia(ip, Meff)  # U^T (M + w D) U over all candidate columns
        n_scale = np.maximum(w * self.area_scale, 1e-300)
        m_scale = np.maximum(w * self.volume_scale, 1e-300)
        q = np.zeros(self.basis.size)
        Hl = None
        Y_prev = s_prev = None
        pcg_total, e = 0, ip.energy(x)
        He = np.empty((sysm.m, 12, 12))
        he_valid = np.zeros(sysm.m, dtype=bool)
        data = None
        if ip.has_start:  # already evaluated (Rayleigh beta needs H_t): reuse it
            data, He[:], he_valid[:] = (ip.start.F, ip.start.P, ip.start.f), ip.start.He, True
        converged = False
        for it in range(self.max_newton):
            t0 = time.perf_counter()
            if data is None:
                data = forces(sysm, x.reshape(-1, 3))
            F, P, f = data
            g = ip.gradient(x, f)
            ge = so.element_gradients(sysm, P)
            t1 = time.perf_counter()
            rec["assembly"] = rec.get("assembly", 0.0) + t1 - t0
            # ---- subspace Hessian (sec. 3.9): BFGS where valid, exact where enrichment touches
            cols = self.columns()
            Ua = self.U[:, cols]
            invalid = self._invalid_subdomains()
            if Hl is None or Hl.shape[1] != cols.size:
                Hl = self._initial_hessians(F, He, he_valid, cols, Ua)
            else:
                Y = sub.projected_gradients(ge, Ua)
                valid = np.ones(sub.L, dtype=bool)
                valid[invalid] = False
                bfgs_update(Hl, s_prev, Y - Y_prev, valid)
            Y_prev = sub.projected_gradients(ge, Ua)
            Mk = Meff if ip.contact is None else Meff + sysm.pattern.matrix(ip.contact_data(x))  # exact contact
            Hu = self._sandwich(UMU, cols, Mk - Meff, Ua) + w * self._elastic(Hl, invalid, F, He, he_valid, Ua)
            t2 = time.perf_counter()
            rec["reduced_assembly"] = rec.get("reduced_assembly", 0.0) + t2 - t1
            # ---- oracle (sec. 3.7): tentative subspace step (eq. 18), then error and progress
            changed = self._update(ip, x, g, ge, Ua, Hu, e, n_scale, m_scale, rec)
            t3 = time.perf_counter()
            rec["prediction"] = rec.get("prediction", 0.0) + t3 - t2
            if changed == "modes":
                cols = self.columns()
                Ua = self.U[:, cols]
                Hl = self._initial_hessians(F, He, he_valid, cols, Ua)
                Y_prev = sub.projected_gradients(ge, Ua)
            # ---- coupled system (eq. 19) on the non-overlapping decomposition (sec. 3.6)
            invalid = self._invalid_subdomains()
            S = self._enriched_dofs()
            Ba = Ua.copy()
            Ba[S] = 0.0
            masked = np.zeros(free.size, dtype=bool)
            masked[S] = True
            Hq = self._sandwich(UMU, cols, Mk - Meff, Ua, Mk, S) + w * self._elastic(Hl, invalid, F, He, he_valid,
                                                                                   Ua, masked)
            # relative 1e-10 shift: fully masked or mutually dependent columns stay solvable
            Hq += (1e-10 * max(np.trace(Hu) / max(cols.size, 1), 1e-300)) * np.eye(cols.size)
            if S.size:
                elems = self._elements_of(invalid)
                Hpart = self._partial_data(He, elems)
                Acols = sysm.pattern.matrix(ip.hessian_data(Hpart, x)).tocsc()[:, S]
                Hx = Acols[S, :].tocsr()
                C = np.asarray((Acols.T @ Ba).T)
            else:
                Hx, C = sp.csr_matrix((0, 0)), np.zeros((cols.size, 0))
            gq, gx = Ba.T @ g, g[S]
            t4 = time.perf_counter()
            rec["reduced_assembly"] = rec.get("reduced_assembly", 0.0) + t4 - t3
            dq, dx, iters, tf = schur_solve(Hq, C, Hx, gq, gx, self.pcg_tol, self.pcg_maxiter)
            pcg_total += iters
            self.last_system = (Hq, C, Hx, gq, gx)
            t5 = time.perf_counter()
            rec["factorization"] = rec.get("factorization", 0.0) + tf
            rec["solve"] = rec.get("solve", 0.0) + t5 - t4 - tf
            # ---- line search and update (Algorithm 1)
            d = Ba @ dq
            d[S] += dx
            alpha, e = newton.line_search(ip, x, d, g, e)
            x = ip.with_step(x, alpha * d)
            q[cols] += alpha * dq
            s_prev = alpha * dq
            data = None
            he_valid[:] = False
            rec["line_search"] = rec.get("line_search", 0.0) + time.perf_counter() - t5
            if newton.converged(ip, d, self.newton_tol) or alpha == 0.0:
                converged = newton.converged(ip, d, self.newton_tol)
                break
        self.last_hessians = Hl
        rec["newton_iters"] = it + 1
        rec["newton_converged"] = converged
        rec["pcg_iters"] = pcg_total
        rec["active_modes"] = int(self.columns().size)
        rec["enriched_ratio"] = float(self.enriched.sum() / max(self.free_vertex.sum(), 1))
        rec["dofs"] = int(self.columns().size + 3 * self.enriched.sum())
        rec["solver"] = "schur-pcg"
        if self.record_residual:
            rec["full_residual"] = newton.full_space_residual(ip, x)
        self._downdate(ip, x, q, rec)
        return x

    # ------------------------------------------------------------------ pieces
    def _inertia(self, ip, Meff):
        """U^T (M + w D) U for all candidate modes: once per step, or once per run without beta damping."""
        key = (ip.weight, ip.c)
        if self.sim.damping.beta == 0 and key in self._inertia_cache:
            return self._inertia_cache[key]
        UMU = self.U.T @ (Meff @ self.U)
        if self.sim.damping.beta == 0:
            self._inertia_cache[key] = UMU
        return UMU

    def _sandwich(self, UMU, cols, extra, Ua, Mk=None, S=None):
        """B^T (M + w D + extra) B with B = U_a, or U_a masked on the DOFs S (then Mk = M + w D + extra).

        Uses the cached U^T (M + w D) U; the sparse ``extra`` (contact) and the masking are
        corrections over the few rows they touch: B^T A B = U^T A U - U^T A E U - U^T E A U + U^T E A E U.
        """
        out = UMU[np.ix_(cols, cols)].copy()
        rows = np.flatnonzero(np.diff(extra.tocsr().indptr)) if extra.nnz else np.zeros(0, np.int64)
        if rows.size:
            Ur = Ua[rows]
            out += Ur.T @ (extra[rows][:, rows] @ Ur)
        if S is not None and S.size:
            X = Mk[:, S]  # columns of the enriched DOFs
            XU = np.asarray((X.T @ Ua))  # (s, a) = E A U restricted to S rows
            US = Ua[S]
            cross = US.T @ XU
            out += -cross - cross.T + US.T @ (Mk[S][:, S] @ US)
        return out

    def _invalid_subdomains(self):
        """Subdomains with an element touching an enriched node: exact evaluation (sec. 3.9)."""
        touch = np.any(self.enriched[self.system.t], axis=0)
        return np.unique(self.sub.of_element[touch])

    def _elements_of(self, subs):
        return np.concatenate([self.sub.elems[l] for l in subs]) if len(subs) else np.zeros(0, np.int64)

    def _elastic(self, Hl, invalid, F, He, he_valid, Ua, masked=None):
        """Elastic subspace Hessian (sec. 3.9): BFGS H_l in valid subdomains plus the exact
        U^T H_l U (masked: B^T H_l B) summed over the subdomains that enrichment touches."""
        valid = np.ones(Hl.shape[0])
        valid[invalid] = 0.0
        total = np.einsum("l,lab->ab", valid, Hl)  # sum over valid subdomains without copying them
        if invalid.size:
            self._blocks(F, He, he_valid, self._elements_of(invalid))
            total += self.sub.exact_sum(He, invalid, Ua, masked)
        return total

    def _initial_hessians(self, F, He, he_valid, cols, Ua):
        """Per-subdomain elastic subspace Hessians that BFGS starts from (sec. 3.9).

        ``hessian_init="exact"``: U_a^T H_l(x) U_a at the current iterate (all element blocks);
        ``"rest"``: the rest-state U_a^T H_l(X) U_a, precomputed once for all candidate modes.
        Subdomains needing exact evaluation are overwritten by the caller either way.
        """
        if self.hessian_init == "rest":
            return np.ascontiguousarray(self.rest_hessians[:, cols][:, :, cols])
        self._blocks(F, He, he_valid, np.arange(self.system.m))
        return self.sub.exact(He, range(self.sub.L), Ua)

    def _blocks(self, F, He, he_valid, elems):
        """Fill element blocks He of ``elems`` at the current iterate (computed once per iterate)."""
        need = elems[~he_valid[elems]]
        if need.size:
            He[need] = self.system.element_blocks(F, need, self.sim.project_hessian)
            he_valid[need] = True

    def _partial_data(self, He, elems):
        """Stiffness of ``elems`` only, as data on the free-DOF pattern."""
        slot = self.system.pattern.slot.reshape(self.system.m, 144)[elems].ravel()
        ok = slot >= 0
        return np.bincount(slot[ok], weights=He[elems].reshape(-1)[ok], minlength=self.system.pattern.nnz)

    def _update(self, ip, x, g, ge, Ua, Hu, e0, n_scale, m_scale, rec):
        """Oracle (sec. 3.7): activate nodes (by subdomain) and blocks of modes; returns what changed."""
        sysm = self.system
        shift = 1e-10 * max(np.trace(Hu) / max(Hu.shape[0], 1), 1e-300)  # candidate columns may be dependent
        dq = -sla.solve(Hu + shift * np.eye(Hu.shape[0]), Ua.T @ g, assume_a="pos")  # eq. 18
        du = Ua @ dq
        alpha, _ = newton.line_search(ip, x, du, g, e0)
        du *= alpha
        W0 = so.element_energies(sysm, x.reshape(-1, 3))
        x1 = ip.with_step(x, du)
        W1 = so.element_energies(sysm, x1.reshape(-1, 3))
        dE = so.nodal_shares(ip, x, W0) - so.nodal_shares(ip, x1, W1)  # eq. 7
        point = so.point_gradients(ip, x)
        gnorm = self.ring.gradient_norms(ip.weight * ge, point)
        G_nodal = gnorm / n_scale  # eq. 10
        E_nodal = dE / m_scale  # eq. 11
        cand = self.free_vertex & ~self.enriched & (G_nodal > self.eps_nodal) & (E_nodal < self.eps_progress)
        changed = None
        if np.any(cand):
            parts = np.unique(self.sub.parts[cand])
            self.enriched |= np.isin(self.sub.parts, parts) & self.free_vertex
            changed = "nodes"
        inactive = [j for j in range(len(self.basis.blocks)) if j not in self.active]
        grad_full = np.zeros(3 * sysm.n)
        grad_full[ip.free] = g
        G_modal, E_modal = self.queries.measure(inactive, grad_full, dE, n_scale, m_scale)
        new = [j for j, ge_, pe in zip(inactive, G_modal, E_modal) if ge_ > self.eps_modal and pe < self.eps_progress]
        if new:
            self.active = sorted(set(self.active) | set(new))
            changed = "modes"
        rec["max_nodal_error"] = max(rec.get("max_nodal_error", 0.0), float(G_nodal[self.free_vertex].max(initial=0.0)))
        return changed

    def _downdate(self, ip, x, q, rec):
        """Sec. 3.11: drop modes that moved little and enriched nodes the subspace already captures."""
        h, length = ip.h, self.sim.size
        limit = self.eps_down * length * h
        keep = []
        for j in self.active:
            blk = self.basis.blocks[j]
            if j in self.permanent or np.abs(self.U[:, blk] @ q[blk]).max(initial=0.0) >= limit:
                keep.append(j)
        self.active = keep
        if np.any(self.enriched):
            cols = np.flatnonzero(q)
            da = (self.basis.U[:, cols] @ q[cols]).reshape(-1, 3)
            dx = (x - ip.x_t).reshape(-1, 3)
            small = np.linalg.norm(dx - da, axis=1) < limit
            self.enriched &= ~small
        rec["enriched_after_downdate"] = float(self.enriched.sum() / max(self.free_vertex.sum(), 1))
