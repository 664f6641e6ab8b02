"""Sparse symmetric positive-definite solvers behind one small interface.

``solver.factorize(A)`` then ``solver.solve(b)``; ``solver.name`` and
``solver.last_iterations`` go into the frame statistics. Choose by name with
:func:`make_solver`: ``"pardiso"`` (MKL Pardiso, optional extra ``fast``),
``"superlu"`` (scipy, always available), ``"amg"`` (pyamg smoothed
aggregation preconditioned CG, hierarchy reused across frames), or ``"auto"``.

Pardiso's Cholesky is much faster than SuperLU from a few thousand unknowns on; AMG-CG with
a reused hierarchy beats both on soft materials but needs many iterations on stiff or nearly
incompressible ones. ``auto`` therefore uses a direct solver (Pardiso if installed, else
SuperLU) below :data:`AMG_MIN_DOFS` unknowns, and above it times both on the first systems and
keeps the faster (:class:`AutoSolver`); a hierarchy that needs more than
:data:`AMG_MAX_ITERATIONS` CG iterations is given up at once. Reduced systems always use a
direct solver (their affine blocks do not suit AMG). Measurements: ``docs/solvers.md``.
"""
import contextlib
import time

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from scipy.linalg import lapack

from skfem_affine import threads
from skfem_affine._extras import require
from skfem_affine.checks import choice, flag, integer, positive, real_array

AMG_MIN_DOFS = 5000
AMG_MIN_DOFS_PARDISO = 30000
PARDISO_THREADED_MIN = 10000
PARDISO_METIS_MIN = 5000
AMG_MAX_ITERATIONS = 30


def schur_set_fits(indptr, indices, k):
    """Whether a Schur set of ``k`` unknowns is safe for MKL Pardiso on a symmetric pattern (CSR indptr
    and indices, whole or its upper triangle): at most half of the unknowns, and at most half of those
    that couple to another. A set holding every coupled unknown, the others isolated (a diagonal entry
    alone, as a reduced frame's idle unknowns), corrupts memory as a set of all the unknowns does
    (reproduced with an affine body's 12 columns in a block of its idle unknowns: docs/contact.md)."""
    n = indptr.size - 1
    if 2 * k > n:
        return False
    if 2 * k <= n - int(np.count_nonzero(np.diff(indptr) == 1)):  # rows with more than their diagonal couple
        return True
    return 2 * k <= int(np.count_nonzero(coupled_unknowns(indptr, indices)))


def coupled_unknowns(indptr, indices):
    """Mask of the unknowns of a symmetric pattern (CSR indptr and indices, whole or its upper
    triangle) that couple to another: an entry off the diagonal in their row or column."""
    n = indptr.size - 1
    rows = np.repeat(np.arange(n), np.diff(indptr))
    off = indices != rows
    coupled = np.zeros(n, dtype=bool)
    coupled[rows[off]] = True
    coupled[indices[off]] = True
    return coupled


def positive_definite(n, L, info):
    """A LAPACK Cholesky factor or inverse L of a Schur complement on n unknowns, or its SolverError when
    LAPACK's ``info`` says the complement is not positive definite."""
    if info != 0:
        raise SolverError(f"the Schur complement on {n} unknowns is not positive definite "
                          f"(LAPACK info {info}); is A positive definite?")
    return L


#: What needs pypardiso, for the error that names its extra.
PARDISO_FEATURE = "the Pardiso solver (solver='pardiso')"


def has_pardiso():
    """Whether pypardiso (the ``fast`` extra) imports and finds MKL."""
    try:
        import pypardiso  # noqa: F401
        return True
    except Exception:  # ImportError, or MKL failing to load
        return False


class SolverError(RuntimeError):
    """The linear solve failed (singular or indefinite system, no convergence)."""


class SuperLU:
    """scipy SuperLU in symmetric mode with MMD(A^T + A) ordering (faster than its default here)."""

    name = "superlu"
    iterative = False

    def __init__(self):
        self.last_iterations = 1

    def factorize(self, A):
        try:
            self._lu = spla.splu(sp.csc_matrix(A), permc_spec="MMD_AT_PLUS_A",
                                 options=dict(SymmetricMode=True))
        except RuntimeError as err:
            raise SolverError(f"SuperLU factorization failed: {err}") from err

    def solve(self, b):
        return self._lu.solve(b)


class Pardiso:
    """MKL Pardiso sparse Cholesky (mtype 2) on the upper triangle.

    The symbolic analysis (ordering) is redone only when the pattern changes
    (compared with ``np.array_equal``, not hashed). The ordering is METIS nested
    dissection for a first analysis (a pattern that is then reused, so a cheaper
    numeric factorisation pays) and minimum degree below :data:`PARDISO_METIS_MIN`
    unknowns once the pattern has changed on consecutive calls (a reduced system whose
    clusters change every frame): there the analysis is paid every frame, and minimum
    degree's is the cheaper one. The positions of the upper triangle in a full
    symmetric CSR input are cached with its pattern, so a full-space frame costs one
    gather instead of ``triu`` and a sort. ``factorize`` also accepts an upper triangle
    directly (``upper=True``), as :func:`skfem_affine.reducers.affine.mapping.reduced_matrix` builds.

    Systems below :data:`PARDISO_THREADED_MIN` unknowns are factorised and solved on one
    MKL thread (on such systems MKL's threads cost more than they save), larger ones on MKL's default
    count, through :func:`skfem_affine.threads.mkl_threads` around each call (restored
    afterwards). All calls into pypardiso's private parts go through one adapter,
    :class:`_PardisoLibrary`. Measurements: ``docs/solvers.md``.
    """

    name = "pardiso"
    iterative = False
    accepts_upper = True

    def __init__(self):
        self._lib = _PardisoLibrary()
        self._threads = 1         # MKL threads for the current pattern's factorisation and solves
        self._pattern = None      # (indptr, indices) of the last analysed upper triangle
        self._source = None       # (indptr, indices, upper positions) of the last full input
        self._analysed = False    # whether a pattern was analysed before (later analyses use "md")
        self._ordering = None     # "metis", "md" or "given": how the current pattern was ordered
        self._resume = None       # a checkpoint's (indptr, indices, ordering, perm), for the next analysis
        self.last_iterations = 1

    def state_dict(self):
        """The ordering history later factorisations depend on: whether a pattern was analysed
        before, and the current pattern with its ordering (another ordering rounds differently)."""
        out = {"analysed": bool(self._analysed), "pattern": self._pattern is not None}
        if self._pattern is not None:
            out.update(indptr=self._pattern[0].copy(), indices=self._pattern[1].copy(), ordering=self._ordering,
                       perm=np.array(self._lib.perm(), dtype=np.int32))
        return out

    def load_state_dict(self, state):
        self._analysed = flag(state["analysed"], "analysed")
        self._resume = None
        if flag(state["pattern"], "pattern"):
            ordering = state["ordering"]
            if ordering not in ("metis", "md", "given"):
                raise ValueError(f"ordering must be 'metis', 'md' or 'given', got {ordering!r}")
            self._resume = (np.asarray(state["indptr"], np.int32), np.asarray(state["indices"], np.int32),
                            ordering, np.asarray(state["perm"], np.int32))

    def _upper(self, A, upper):
        """Upper triangle of A as sorted CSR (int32), reusing the positions of the last pattern."""
        if upper:
            U = sp.csr_matrix(A)
            if not U.has_sorted_indices:
                U.sort_indices()
            return U.indptr.astype(np.int32), U.indices.astype(np.int32), U.data
        A = sp.csr_matrix(A)
        src = self._source
        if src is not None and _same(src[0], A.indptr) and _same(src[1], A.indices):
            return src[2], src[3], A.data[src[4]]
        pos = np.arange(A.nnz)
        P = sp.csr_matrix((pos.astype(float), A.indices, A.indptr), shape=A.shape)
        U = sp.triu(P, format="csr")
        U.sort_indices()
        take = U.data.astype(np.int64)
        ip, ix = U.indptr.astype(np.int32), U.indices.astype(np.int32)
        self._source = (A.indptr.copy(), A.indices.copy(), ip, ix, take)
        return ip, ix, A.data[take]

    def factorize(self, A, upper=False, order=None):
        """Cholesky of A (full symmetric CSR, or its upper triangle with ``upper=True``).

        ``order``: the unknowns in elimination order (a fill-reducing permutation the caller
        already knows, e.g. :meth:`~skfem_affine.reducers.affine.mapping.Mapping.elimination_order`); Pardiso then skips
        its own ordering. Used for a new pattern, ignored when the pattern is the last one.
        """
        indptr, indices, data = self._upper(A, upper or getattr(A, "_upper", False))
        n = indptr.size - 1
        pat = self._pattern
        phase = 22 if pat is not None and _same(pat[0], indptr) and _same(pat[1], indices) else 12
        if phase == 12:
            churn = self._analysed  # a second analysis: the pattern changes
            if self._pattern is not None:  # release the previous factors first (MKL crashed on a re-analysis
                self._lib.release()        # with a new order)
            resume, self._resume = self._resume, None
            if resume is not None and _same(resume[0], indptr) and _same(resume[1], indices):
                # the pattern a checkpoint was factorised with: order it as the saved run did
                if resume[2] == "given":
                    self._lib.use_order(resume[3])
                else:
                    self._lib.use_ordering(resume[2])
                self._ordering = resume[2]
            elif order is not None:
                order = np.ascontiguousarray(order, dtype=np.int32)
                if order.shape != (n,) or (n and (order.min() < 0 or order.max() >= n)) or \
                        not np.all(np.bincount(order, minlength=n) == 1):
                    raise ValueError(f"order must list each of the {n} unknowns exactly once "
                                     f"(got {order.size} entries)")
                self._lib.use_order(order)
                self._ordering = "given"
            else:
                self._ordering = "md" if churn and n < PARDISO_METIS_MIN else "metis"
                self._lib.use_ordering(self._ordering)
            self._pattern = (indptr, indices)
            self._analysed = True
        self._threads = 1 if n < PARDISO_THREADED_MIN else self._lib.max_threads
        self._arrays = (np.ascontiguousarray(data, dtype=float), indptr, indices, n)
        try:
            with threads.mkl_threads(self._threads):
                self._lib.call(phase, self._arrays, np.zeros((n, 1)))
        except Exception as err:
            self._pattern = None
            raise SolverError(f"Pardiso factorization failed ({err}); is the system positive definite?") from err

    @property
    def factor_nonzeros(self):
        """The nonzeros of the current pattern's Cholesky factor (its fill: how good its ordering is),
        or None before a factorisation."""
        return None if self._pattern is None else self._lib.factor_nonzeros()

    def analysed_for(self, A, upper=False):
        """Whether A's pattern is the one analysed last (or the one a loaded checkpoint will analyse
        next): :meth:`factorize` would then skip the analysis."""
        pat = self._pattern if self._pattern is not None else self._resume
        if pat is None:
            return False
        indptr, indices, _ = self._upper(A, upper or getattr(A, "_upper", False))
        return _same(pat[0], indptr) and _same(pat[1], indices)

    def __del__(self):
        try:
            if self._pattern is not None:
                self._lib.release()
        except Exception:
            pass

    def solve(self, b):
        b = np.asarray(b, dtype=float)
        with threads.mkl_threads(self._threads):
            x = self._lib.call(33, self._arrays, np.asfortranarray(b.reshape(b.shape[0], -1)))
        return np.ascontiguousarray(x).reshape(b.shape)


class PardisoSchur(Pardiso):
    """The dense Schur complement ``S = A_TT - A_TR A_RR^-1 A_RT`` of a symmetric positive-definite
    matrix on chosen unknowns T (MKL Pardiso, ``iparm(36)``), on a handle of its own: then
    ``(A^-1)_TT = S^-1``.

    The analysis (ordering with T eliminated last) is redone when the pattern or T changes, the
    numeric factorisation every call. Two conditions under which MKL Pardiso corrupts memory are
    kept out: T is at most half the unknowns (with T all of them, Pardiso wrote past its Schur
    buffer), and an analysis' factorisations and release run on the MKL thread count it ran on
    (an analysis on two threads and a factorisation on one segfaulted). Both were reproduced by
    ``benchmarks/schur_stress.py``, which also checks that this class survives varied calls. A third
    (:func:`schur_set_fits`): T at most half of the unknowns that couple to another (T holding every
    coupled unknown, the others isolated, corrupted memory as T all of them does).

    Parameters
    ----------
    solves : bool
        Also factorise S (LAPACK's Cholesky, :attr:`factor`), so that the factorisation solves the
        whole system (:meth:`solve`): then it can be a frame's own factorisation. Pardiso forms S without
        factorising it (``iparm(36) = 1``) either way; its mode that factorises S too (``iparm(36) = 2``)
        costs more than LAPACK's Cholesky of S (measured in ``docs/contact.md``).
    """

    name = "pardiso-schur"

    def __init__(self, solves=False):
        super().__init__()
        self.solves = flag(solves, "solves")
        self._marks = None  # the Schur set's marks of the current analysis (Pardiso's perm argument)
        self.factor = None  # with ``solves``: the lower Cholesky factor of the last complement S
        self._complemented = None  # that S

    def complement(self, A, keep, upper=False):
        """S (``|keep| x |keep|``, dense) of A (full symmetric CSR, or its upper triangle with
        ``upper=True``) on the sorted, distinct unknowns ``keep`` (at most half of A's)."""
        indptr, indices, data = self._upper(A, upper)
        n, keep = indptr.size - 1, np.asarray(keep, dtype=np.int64)
        k = keep.size
        if k == 0 or (k > 1 and np.any(np.diff(keep) <= 0)) or keep[0] < 0 or keep[-1] >= n \
                or not schur_set_fits(indptr, indices, k):
            raise ValueError(f"keep must be sorted distinct unknowns, at most half of the {n} and of those "
                             f"coupled to another (got {k})")
        pat = self._pattern
        same = (pat is not None and _same(pat[0], indptr) and _same(pat[1], indices) and _same(pat[2], keep))
        if not same:
            self._release()
            self._threads = 1 if n < PARDISO_THREADED_MIN else self._lib.max_threads
        marks = np.zeros(n, dtype=np.int32)
        marks[keep] = 1
        self._marks = marks
        self._arrays = (np.ascontiguousarray(data, dtype=float), indptr, indices, n)
        self.factor = self._complemented = None
        try:
            with threads.mkl_threads(self._threads):  # marks given afresh: Pardiso writes its ordering into perm
                x = self._lib.schur(12 if not same else 22, self._arrays, marks.copy(), k)
        except Exception as err:
            self._release()
            raise SolverError(f"Pardiso Schur complement failed ({err}); is the system positive definite?") from err
        self._pattern = (indptr, indices, keep.copy())
        S = x.reshape(k, k)
        if self.solves:
            with threads.serial_blas():
                self.factor = positive_definite(k, *lapack.dpotrf(S, lower=1, clean=1))
            self._complemented = S
        return S

    def factor_of(self, S):
        """The lower Cholesky factor of S when S is the last complement this handle returned (with
        ``solves``), else None: the Delassus operator then needs no second factorisation of it."""
        return self.factor if S is self._complemented and self.factor is not None else None

    def analysed(self, A, upper=False):
        """The unknowns T of the current analysis when it is of A's pattern, else None (a complement
        on them costs a numeric factorisation only)."""
        pat = self._pattern
        if pat is None:
            return None
        indptr, indices, _ = self._upper(A, upper)
        return pat[2] if _same(pat[0], indptr) and _same(pat[1], indices) else None

    def _release(self):
        """Free the analysis and factors with the arrays and thread count they were made with."""
        if self._pattern is not None:
            self._pattern = None
            with threads.mkl_threads(self._threads):
                self._lib.release(self._arrays)

    def __del__(self):
        try:
            self._release()
        except Exception:
            pass

    def factorize(self, A, upper=False, order=None):
        raise TypeError("PardisoSchur factorises in complement, with the unknowns it eliminates last")

    def solve(self, b):
        """x = A^-1 b with the last :meth:`complement`'s factorisation (only with ``solves=True``)."""
        if not self.solves:
            raise TypeError("PardisoSchur(solves=False) computes Schur complements, it does not solve")
        if self._pattern is None:
            raise TypeError("PardisoSchur.solve needs a factorisation first (complement)")
        b = np.asarray(b, dtype=float)
        keep = self._pattern[2]
        with threads.mkl_threads(self._threads):  # the analysis' thread count
            # forward substitution leaves the complement's right-hand side on keep; S's own factor solves it
            rhs = np.asfortranarray(b.reshape(b.shape[0], -1))
            y = self._lib.call(331, self._arrays, rhs, perm=self._marks.copy())
            with threads.serial_blas():
                y[keep] = lapack.dpotrs(self.factor, y[keep], lower=1)[0]
            x = self._lib.call(333, self._arrays, np.asfortranarray(y), perm=self._marks.copy())
        return np.ascontiguousarray(x).reshape(b.shape)


class _PardisoLibrary:
    """The one adapter to MKL Pardiso through pypardiso's private parts (ctypes, ``_mkl_pardiso``, iparm).

    pypardiso solves full systems with its own checks and copies; the solver above needs the
    raw phases (analysis 12, numeric factorisation 22, solve 33) on an upper triangle with
    zero-based indices, its own ordering and one factor kept across calls, so it talks to
    ``pardiso`` directly. Everything that depends on pypardiso's internals is here. Thread
    counts are set by the caller (:func:`skfem_affine.threads.mkl_threads`).
    """

    MTYPE = 2  # real symmetric positive definite

    def __init__(self):
        import os

        pypardiso = require("pypardiso", PARDISO_FEATURE, "fast")
        self._ps = pypardiso.PyPardisoSolver(mtype=self.MTYPE)
        # pypardiso searches site-packages for MKL on every instance unless PYPARDISO_MKL_RT (its
        # documented override) names the library: set it once MKL is found, so later solvers skip it
        os.environ.setdefault("PYPARDISO_MKL_RT", self._ps.libmkl._name)
        self._ps.set_iparm(1, 1)   # user-set iparm
        self._ps.set_iparm(35, 1)  # zero-based indices: no shifted copies of the pattern per call
        self.max_threads = threads.mkl_max_threads() or 1  # MKL's count before any limit: every core

    def use_order(self, order):
        """Eliminate in the given order (int32 permutation) at the next analysis."""
        self._ps.set_iparm(5, 1)
        self._ps.perm = order

    def use_ordering(self, kind):
        """Pardiso's own ordering at the next analysis: ``"metis"`` (nested dissection) or ``"md"``."""
        self._ps.set_iparm(5, 0)
        self._ps.set_iparm(2, {"md": 0, "metis": 2}[kind])

    def factor_nonzeros(self):
        """The nonzeros of the Cholesky factor of the last analysis (``iparm(18)``)."""
        return int(self._ps.iparm[17])

    def perm(self):
        """The permutation array handed to Pardiso (the given order, when one was)."""
        return self._ps.perm

    def release(self, arrays=None):
        """Free the factors and the analysis (``arrays``: those of the last call, required after a
        Schur complement: pypardiso's own release passes an empty matrix, which that mode must not see)."""
        if arrays is None:
            self._ps.free_memory(everything=True)
            return
        n = arrays[3]
        self.call(-1, arrays, np.zeros((n, 1)), perm=np.zeros(n, dtype=np.int32))
        self._ps.pt[:] = 0  # a fresh handle for the next analysis

    def schur(self, phase, arrays, marks, k, mode=1):
        """Factorise (``phase`` 12 or 22, METIS ordering) with the unknowns marked 1 in ``marks``
        (int32, n) eliminated last; returns their dense Schur complement (k * k, row-major).
        ``mode`` (``iparm(36)``): 1 the complement only, 2 the whole system factorised too (it solves)."""
        self._ps.set_iparm(2, 2)
        self._ps.set_iparm(5, 0)
        self._ps.set_iparm(36, mode)
        n = arrays[3]
        return self.call(phase, arrays, np.zeros((max(n, k * k), 1)), perm=marks)[:k * k, 0]

    def call(self, phase, arrays, b, perm=None):
        """One ``pardiso`` call on the upper triangle ``arrays = (data, indptr, indices, n)``; returns x
        (``perm``: the permutation array of this call, default the one set by the orderings above)."""
        import ctypes
        ps = self._ps
        perm = ps.perm if perm is None else perm
        if phase in (11, 12, 13):
            ps.set_iparm(18, -1)  # report the factor's nonzeros (iparm(18) holds the last count, which disables it)
        data, indptr, indices, n = arrays
        x = np.zeros_like(b)
        error = ctypes.c_int32(0)
        i32, f64 = ctypes.POINTER(ctypes.c_int32), ctypes.POINTER(ctypes.c_double)
        ps._mkl_pardiso(ps.pt.ctypes.data_as(ctypes.POINTER(ps._pt_type[0])), ctypes.byref(ctypes.c_int32(1)),
                        ctypes.byref(ctypes.c_int32(1)), ctypes.byref(ctypes.c_int32(self.MTYPE)),
                        ctypes.byref(ctypes.c_int32(phase)), ctypes.byref(ctypes.c_int32(n)),
                        data.ctypes.data_as(f64), indptr.ctypes.data_as(i32), indices.ctypes.data_as(i32),
                        perm.ctypes.data_as(i32), ctypes.byref(ctypes.c_int32(b.shape[1])),
                        ps.iparm.ctypes.data_as(i32), ctypes.byref(ctypes.c_int32(0)),
                        b.ctypes.data_as(f64), x.ctypes.data_as(f64), ctypes.byref(error))
        threads.no_spin_wait()  # after a call, MKL has loaded its OpenMP runtime if it uses one
        if error.value != 0:
            raise SolverError(f"Pardiso error {error.value}")
        return x


@contextlib.contextmanager
def seeded_global_random(seed=0):
    """Run a block with NumPy's global random state seeded, restoring the caller's state after.

    pyamg estimates spectral radii (for its prolongation smoother) by Arnoldi/Lanczos from a
    ``np.random.rand`` start vector, so two hierarchies built from one matrix differ in the last
    bits unless the global state is fixed. Seeding it here makes every hierarchy, and hence every
    AMG-CG solve and AMG oracle prediction, reproducible run to run, without disturbing the
    random numbers of the user's own code.
    """
    saved = np.random.get_state()
    np.random.seed(seed)
    try:
        yield
    finally:
        np.random.set_state(saved)


def _same(a, b):
    return a.shape == b.shape and np.array_equal(a, b)


class AMGCG:
    """Conjugate gradients preconditioned by one pyamg smoothed-aggregation V-cycle.

    The hierarchy is built on the first system and reused for later ones until
    CG needs more than ``max(rebuild_iterations, 2 * fresh_iterations)``
    iterations, ``fresh_iterations`` being the count right after a rebuild.
    """

    name = "amg"
    iterative = True

    def __init__(self, tol=1e-8, maxiter=500, rebuild_iterations=15):
        self.tol = positive(tol, "tol")
        self.maxiter = integer(maxiter, "maxiter", low=1)
        self.rebuild_iterations = integer(rebuild_iterations, "rebuild_iterations", low=1)
        self._ml = None
        self._stale = False
        self.last_iterations = 0
        self.fresh_iterations = None
        self.rebuilds = 0

    def factorize(self, A):
        self._A = sp.csr_matrix(A)
        if self._ml is None or self._ml.levels[0].A.shape != A.shape or self._stale:
            self._build(self._A)
            self._stale = False
            self.fresh_iterations = None
            self.rebuilds += 1

    def _build(self, A):
        """The hierarchy of A (reproducible: :func:`seeded_global_random`)."""
        import pyamg
        B = np.kron(np.ones((A.shape[0] // 3, 1)), np.eye(3)) if A.shape[0] % 3 == 0 else None
        with seeded_global_random():
            self._ml = pyamg.smoothed_aggregation_solver(A, B=B, strength="symmetric", max_coarse=500)
            self._M = self._ml.aspreconditioner(cycle="V")
        self._built_from = A.copy()

    def state_dict(self):
        """What later solves depend on: the matrix the current hierarchy was built from, and the
        rebuild bookkeeping (the hierarchy itself is rebuilt from the matrix, bit-identically)."""
        A = getattr(self, "_built_from", None) if self._ml is not None else None
        out = {"stale": bool(self._stale), "fresh_iterations": self.fresh_iterations, "rebuilds": int(self.rebuilds)}
        if A is not None:
            out.update(A_data=A.data.copy(), A_indices=A.indices.copy(), A_indptr=A.indptr.copy(),
                       A_shape=np.array(A.shape))
        return out

    def load_state_dict(self, state):
        self._ml = None
        if "A_data" in state:
            A = sp.csr_matrix((state["A_data"], state["A_indices"], state["A_indptr"]), shape=tuple(state["A_shape"]))
            self._build(A)
        self._stale = flag(state["stale"], "stale")
        self.fresh_iterations = state["fresh_iterations"]
        self.rebuilds = int(state["rebuilds"])

    def solve(self, b, time_limit=None):
        """CG on the last system; ``time_limit`` (seconds, optional) raises ``_TooSlow`` once passed."""
        count = [0]
        t0 = time.perf_counter()

        def cb(_):
            count[0] += 1
            if time_limit is not None and time.perf_counter() - t0 > time_limit:
                self.last_iterations = count[0]
                raise _TooSlow()

        x, info = spla.cg(self._A, b, rtol=self.tol, atol=0.0, maxiter=self.maxiter, M=self._M, callback=cb)
        self.last_iterations = count[0]
        if info != 0:
            # one rebuild and retry before giving up
            self._stale = True
            self.factorize(self._A)
            count[0] = 0
            x, info = spla.cg(self._A, b, rtol=self.tol, atol=0.0, maxiter=self.maxiter, M=self._M, callback=cb)
            self.last_iterations = count[0]
            if info != 0:
                raise SolverError(f"AMG-CG did not converge to {self.tol:g} in {self.maxiter} iterations")
        if self.fresh_iterations is None:
            self.fresh_iterations = count[0]
        if count[0] > max(self.rebuild_iterations, 2 * self.fresh_iterations):
            self._stale = True
        return x


def direct_solver():
    """The fastest available direct solver: Pardiso if installed, else SuperLU."""
    return Pardiso() if has_pardiso() else SuperLU()


class _TooSlow(Exception):
    """AMG-CG on trial took longer than the direct solver would have."""


class AutoSolver:
    """The direct solver or AMG-CG, whichever measures faster on this simulation's systems.

    Systems below ``amg_min_dofs`` unknowns always go to the direct solver (Pardiso if
    installed, else SuperLU). By default that is :data:`AMG_MIN_DOFS_PARDISO` unknowns with
    Pardiso (below it, a hierarchy alone costs more than ten Pardiso solves, and AMG-CG needed
    28-38 iterations on the cantilever at 1.5k and 15k tets) and :data:`AMG_MIN_DOFS` with
    SuperLU. On larger systems the first ones are a trial, in order:

    1. two systems with the direct solver: the second's factorisation and solve time is its
       cost per system (a Pardiso analysis is paid once, in the first);
    2. two with AMG-CG: the first builds the hierarchy, the second reuses it and gives its
       cost per system. A CG run that takes longer than the direct solver's cost, or a fresh
       hierarchy that needs more than ``amg_max_iterations`` iterations, ends the trial at
       once: that system is solved directly.

    From then on the faster of the two solves every system (AMG-CG for good only while a
    rebuilt hierarchy converges within ``amg_max_iterations``; the direct solver after). So on
    the first frames ``auto`` pays one hierarchy and at most a few systems of the slower
    solver, and is never the slowest choice for long. The choice, once made, is saved in a
    checkpoint (:meth:`state_dict`) so that a resumed run continues with it. Measurements:
    ``docs/solvers.md``.
    """

    def __init__(self, amg_min_dofs=None, amg_max_iterations=None):
        self.amg_max_iterations = (AMG_MAX_ITERATIONS if amg_max_iterations is None
                                   else integer(amg_max_iterations, "amg_max_iterations", low=1))
        if amg_min_dofs is None:
            amg_min_dofs = AMG_MIN_DOFS_PARDISO if has_pardiso() else AMG_MIN_DOFS
        self.amg_min_dofs = integer(amg_min_dofs, "amg_min_dofs", low=0)
        self._direct = self._amg = None
        self._current = None
        self.amg_abandoned = False
        self.choice = None        # "direct" or "amg" once the trial is over
        self.trial = []           # seconds per system on trial: (solver, seconds) in order
        self._A = None
        self._t0 = 0.0
        self._timing = False      # whether the next solve is a system on trial

    @property
    def name(self):
        return self._current.name if self._current else "auto"

    @property
    def last_iterations(self):
        return self._current.last_iterations if self._current else 0

    @property
    def iterative(self):
        """Whether the solver that factorised the last system is iterative (AMG-CG)."""
        return bool(self._current.iterative) if self._current else False

    def _on_trial(self):
        """The solver the next large system goes to while the trial lasts (None: the trial is over)."""
        if self.choice is not None:
            return None
        return ("direct", "direct", "amg", "amg")[len(self.trial)] if len(self.trial) < 4 else None

    def _choose(self):
        """End the trial: the faster solver per system, direct unless AMG-CG measured faster."""
        cost = {"direct": self.trial[1][1] if len(self.trial) > 1 else None,
                "amg": self.trial[3][1] if len(self.trial) > 3 else None}
        amg_ok = cost["amg"] is not None and not self.amg_abandoned
        self.choice = "amg" if amg_ok and cost["amg"] < cost["direct"] else "direct"
        if self.choice == "direct":
            self.amg_abandoned = True

    def factorize(self, A):
        self._t0 = time.perf_counter()
        self._A = A
        amg = self._amg
        if amg is not None and amg.fresh_iterations is not None and amg.fresh_iterations > self.amg_max_iterations:
            self.amg_abandoned = True
            if self.choice is None:
                self._choose()
        large = A.shape[0] >= self.amg_min_dofs
        use = (self._on_trial() or self.choice) if large else "direct"
        self._timing = large and self.choice is None
        if use == "amg" and not self.amg_abandoned:
            self._amg = self._amg or AMGCG()
            self._current = self._amg
        else:
            self._direct = self._direct or direct_solver()
            self._current = self._direct
        self._current.factorize(A)

    def solve(self, b):
        timing, self._timing = self._timing, False  # a system's first solve is timed, later ones not
        if not timing:
            return self._current.solve(b)
        if self._current is not self._amg:
            x = self._current.solve(b)
            self._record("direct")
            return x
        # AMG-CG on trial: stopped once CG alone has cost more than a direct factorisation and solve
        direct = self.trial[1][1] if len(self.trial) > 1 else None
        try:
            x = self._amg.solve(b, time_limit=direct)
        except _TooSlow:
            self.amg_abandoned = True
            self._choose()
            self._direct = self._direct or direct_solver()
            self._current = self._direct
            self._direct.factorize(self._A)
            return self._direct.solve(b)
        self._record("amg")
        if self._amg.fresh_iterations is not None and self._amg.fresh_iterations > self.amg_max_iterations:
            self.amg_abandoned = True
            self._choose()
        return x

    def _record(self, solver):
        self.trial.append((solver, time.perf_counter() - self._t0))
        if len(self.trial) >= 4 and self.choice is None:
            self._choose()

    def state_dict(self):
        """The AMG/direct choice, the trial so far and each solver's state (:meth:`AMGCG.state_dict`)."""
        out = {"amg_abandoned": bool(self.amg_abandoned),
               "current": None if self._current is None else ("amg" if self._current is self._amg else "direct"),
               "choice": self.choice, "trial_solvers": ",".join(s for s, _ in self.trial),
               "trial_seconds": np.array([w for _, w in self.trial], dtype=float)}
        if self._amg is not None:
            out.update({f"amg.{k}": v for k, v in self._amg.state_dict().items()})
        if self._direct is not None and hasattr(self._direct, "state_dict"):
            out.update({f"direct.{k}": v for k, v in self._direct.state_dict().items()})
        out["has_direct"] = self._direct is not None
        return out

    def load_state_dict(self, state):
        self.amg_abandoned = flag(state["amg_abandoned"], "amg_abandoned")
        chosen = state.get("choice")
        if isinstance(chosen, np.ndarray) and chosen.ndim == 0:
            chosen = chosen.item()
        self.choice = None if chosen is None else choice(chosen, "choice", ("direct", "amg"))
        names = [s for s in str(state.get("trial_solvers", "")).split(",") if s]
        for name in names:
            choice(name, "trial_solvers", ("direct", "amg"))
        seconds = real_array(state.get("trial_seconds", np.zeros(0)), "trial_seconds", low=0.0)
        if seconds.shape != (len(names),) or len(names) > 4:
            raise ValueError(f"trial_seconds must hold one time per solver on trial ({len(names)}, at most 4), "
                             f"got shape {seconds.shape}")
        self.trial = list(zip(names, seconds.tolist()))
        amg = {k[4:]: v for k, v in state.items() if k.startswith("amg.")}
        self._amg = None
        if amg:
            self._amg = AMGCG()
            self._amg.load_state_dict(amg)
        if state["has_direct"]:
            self._direct = self._direct or direct_solver()
            direct = {k[7:]: v for k, v in state.items() if k.startswith("direct.")}
            if direct and hasattr(self._direct, "load_state_dict"):
                self._direct.load_state_dict(direct)
        current = state["current"]
        if current not in ("amg", "direct", None) or isinstance(current, bool):
            raise ValueError(f"current must be 'amg', 'direct' or None, got {current!r:.40}")
        self._current = {"amg": self._amg, "direct": self._direct, None: None}[current]


SOLVERS = {"superlu": SuperLU, "pardiso": Pardiso, "amg": AMGCG, "auto": AutoSolver, "direct": direct_solver}


def make_solver(solver):
    """A solver instance from a name in :data:`SOLVERS` or an object with factorize/solve."""
    if solver is None:
        solver = "auto"
    if isinstance(solver, str):
        if solver not in SOLVERS:
            raise ValueError(f"unknown solver {solver!r}; choose one of {sorted(SOLVERS)}")
        if solver == "pardiso":
            require("pypardiso", PARDISO_FEATURE, "fast")
        return SOLVERS[solver]()
    if isinstance(solver, type):
        raise TypeError(f"solver must be a name or a solver instance, got the class {solver.__name__}: "
                        f"write {solver.__name__}()")
    if not (hasattr(solver, "factorize") and hasattr(solver, "solve")):
        raise TypeError(f"solver must be a name or an object with factorize(A) and solve(b), "
                        f"got {type(solver).__name__}")
    return solver


def factorize_and_solve(solver, A, b, stats):
    """Factorise A, solve A x = b; record the timings, DOFs, solver and iterations in ``stats``."""
    t0 = time.perf_counter()
    solver.factorize(A)
    t1 = time.perf_counter()
    x = solver.solve(b)
    t2 = time.perf_counter()
    stats["factorization"] = stats.get("factorization", 0.0) + t1 - t0
    stats["solve"] = stats.get("solve", 0.0) + t2 - t1
    stats["dofs"] = A.shape[0]
    stats["solver"] = solver.name
    stats["iterations"] = stats.get("iterations", 0) + solver.last_iterations
    return x
