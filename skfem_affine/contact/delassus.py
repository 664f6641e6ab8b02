r"""The Delassus operator W = J A^-1 J^T of a frame's contacts (paper sec. 3.3).

The Jacobian J (3 rows n, t1, t2 per contact) maps free-DOF velocities to the relative
velocity of each contact vertex against its closest point. W is applied through the frame's
factorisation and, for a reduced frame, through G: ``A^-1 ~ G (G^T A G)^-1 G^T``, so
``W = (J G) A_r^-1 (J G)^T`` costs solves of the small reduced system, one per unknown
that the contacts touch (12 per affine body, 6 per rigid one) or per row of J, whichever is
fewer, the right-hand sides of several bodies solved side by side (:class:`Resolvent`). What it
needs of the frame comes in the reducer's :class:`~skfem_affine.integrators.problem.Operator`.
"""
import numpy as np
import scipy.sparse as sp
from numba import njit

from skfem_affine import _compile_notice  # noqa: F401 (one stderr line when the cached kernels compile)
from skfem_affine.contact.blocks import BlockSolver
from skfem_affine.contact.dense import DenseBlocks, used_unknowns
from skfem_affine.contact.schur import inverse_on_positions
from skfem_affine.solvers import SuperLU, direct_solver

# A body's block of more than SCHUR_BLOCK_MIN unknowns takes Z from its own Schur complement (when
# the SchurInverse accepts); smaller ones are solved with the others. Below BLOCK_DIRECT_MIN
# unknowns SuperLU factorises a system the Delassus operator factorises itself, else the direct
# solver (measurements in docs/contact.md).
SCHUR_BLOCK_MIN = 800
BLOCK_DIRECT_MIN = 2000


def jacobian(contacts, n_vertices, free):
    """J (3k x n_free, CSR, sorted indices): row 3i + r is frame row r of contact i on w_a v_a - sum_k w_k v_k
    (w_a the contact's ``own`` weight, 1 for a vertex; fixed DOFs and zero entries dropped)."""
    k = contacts.size
    verts = np.column_stack([contacts.vertex, contacts.others]).astype(np.int64)   # (k, 4)
    own = np.ones(k) if contacts.own is None else contacts.own
    coef = np.column_stack([own, -contacts.weights]).astype(float)                 # (k, 4)
    dof_map = np.full(3 * n_vertices, -1, dtype=np.int64)
    dof_map[free] = np.arange(free.size)
    indptr, indices, data = _jacobian_rows(np.ascontiguousarray(contacts.frames(), dtype=float), verts, coef, dof_map)
    J = sp.csr_matrix((data, indices, indptr), shape=(3 * k, free.size))
    J.has_sorted_indices = True
    return J


@njit(cache=True)
def _jacobian_rows(frames, verts, coef, dof_map):
    """The CSR arrays of :func:`jacobian`: entry (3i + r, DOF d of vertex verts[i, v]) is coef[i, v] frames[i, r, d],
    each row's columns increasing, a column met twice summed."""
    k, nv = verts.shape
    indptr = np.zeros(3 * k + 1, dtype=np.int64)
    indices = np.empty(9 * k * nv, dtype=np.int64)
    data = np.empty(9 * k * nv)
    cols, vals = np.empty(3 * nv, dtype=np.int64), np.empty(3 * nv)
    n = 0
    for i in range(k):
        for r in range(3):
            m = 0
            for v in range(nv):
                for d in range(3):
                    val = coef[i, v] * frames[i, r, d]
                    at = 3 * verts[i, v] + d
                    c = dof_map[at + dof_map.size if at < 0 else at]
                    if c < 0 or val == 0.0:
                        continue
                    q = m
                    while q > 0 and cols[q - 1] > c:
                        q -= 1
                    if q > 0 and cols[q - 1] == c:
                        vals[q - 1] += val
                        continue
                    for t in range(m, q, -1):
                        cols[t], vals[t] = cols[t - 1], vals[t - 1]
                    cols[q], vals[q] = c, val
                    m += 1
            indices[n:n + m], data[n:n + m] = cols[:m], vals[:m]
            n += m
            indptr[3 * i + r + 1] = n
    return indptr, indices[:n], data[:n]


def vertex_unknowns(vertices, n_vertices, free):
    """The sorted free unknowns (columns of J) of ``vertices``, or None when ``vertices`` is None."""
    if vertices is None:
        return None
    dof_map = np.full(3 * n_vertices, -1, dtype=np.int64)
    dof_map[free] = np.arange(free.size)
    c = dof_map[(3 * np.asarray(vertices, dtype=np.int64)[:, None] + np.arange(3)).ravel()]
    return np.unique(c[c >= 0])


def block_solver(size):
    """A direct solver for a system of ``size`` unknowns: SuperLU below :data:`BLOCK_DIRECT_MIN`,
    else the fastest direct solver."""
    return SuperLU() if size < BLOCK_DIRECT_MIN else direct_solver()


def unknown_bodies(bodies, G):
    """The body of each unknown of a frame's system, from ``bodies`` (n_free,), the body of each free
    DOF: in full space ``bodies`` itself; through the reducer's G (n_free x r) the body of each
    column's rows (-1 for a column without any). None when a column of G spans two bodies: the
    blocks are then unknown, and the system is taken whole."""
    if G is None:
        return bodies
    G = G if sp.issparse(G) and G.format == "csr" else sp.csr_matrix(G)
    out, mixed = _column_bodies(G.indptr, G.indices, np.asarray(bodies, dtype=np.int64), G.shape[1])
    return None if mixed else out


@njit(cache=True)
def _column_bodies(indptr, indices, bodies, ncols):
    """(the body of each column of G from its rows' ``bodies``, -1 for an empty column; whether a column
    spans two bodies)."""
    out = np.full(ncols, -1, dtype=np.int64)
    for i in range(indptr.size - 1):
        for p in range(indptr[i], indptr[i + 1]):
            c = indices[p]
            if out[c] < 0:
                out[c] = bodies[i]
            elif out[c] != bodies[i]:
                return out, True
    return out, False


def _checked_bodies(bodies, operator):
    """``bodies`` as an int array, one entry per free DOF (the rows of G, or of A in full space)."""
    n = operator.G.shape[0] if operator.G is not None else operator.shape[0]
    out = np.asarray(bodies)
    if out.shape != (n,) or not np.issubdtype(out.dtype, np.integer):
        raise ValueError(f"bodies must be an int array of the {n} free DOFs' bodies, got {out.dtype} {out.shape}")
    return out


@njit(cache=True)
def _add_symmetric(W, rows, Wb):
    """W[rows_i, rows_j] += (Wb_ij + Wb_ji) / 2: a body's part of W, made exactly symmetric."""
    m = rows.size
    for i in range(m):
        r = rows[i]
        for j in range(i):
            v = 0.5 * (Wb[i, j] + Wb[j, i])
            W[r, rows[j]] += v
            W[rows[j], r] += v
        W[r, r] += Wb[i, i]  # (Wb_ii + Wb_ii) / 2, exactly


def _solve(solver, R, iterative=False):
    if iterative:  # CG takes one right-hand side at a time
        return np.column_stack([solver.solve(np.ascontiguousarray(R[:, j])) for j in range(R.shape[1])])
    return np.asarray(solver.solve(R)).reshape(R.shape)


class Resolvent:
    """A^-1 applied to the columns of J^T with the frame's system, through G when reduced (sec. 3.3).

    ``operator`` (:class:`~skfem_affine.integrators.problem.Operator`) holds the frame's
    system matrix (full A, or A_r = G^T A G of a reducer), the solver that has factorised it,
    and the reducer's mapping G (n_free x r), or None in full space, so that
    ``W = Jr A^-1 Jr^T`` with ``Jr = J G`` (``J`` in full space).

    W needs A^-1 only on the unknowns T that the contacts touch (the columns of Jr with a
    nonzero): ``W = Jr_T Z Jr_T^T`` with ``Z = (A^-1)_TT``, from the solves of the unit columns
    e_T. That costs ``|T|`` solves instead of one per row of Jr (3 per contact), and is taken when
    ``|T|`` is the smaller: the contacts on an affine (rigid) body touch its 12 (6) reduced
    unknowns however many they are, and a vertex with several contacts is solved once; otherwise
    A^-1 Jr^T is solved row by row (always, with ``touched=False``: the reference path). With
    ``schur`` (:class:`~skfem_affine.contact.schur.SchurInverse`) Z comes from the Schur
    complement of A on T where it accepts, without a solve per unknown.

    Bodies are not coupled by A. Given ``bodies``, the body of each free DOF, the unknowns of
    each body form a block of A (:func:`unknown_bodies`), and the right-hand sides of all bodies
    are solved together with the frame's own factorisation: a body's j-th right-hand side shares
    the column of every other body's j-th (their supports, and those of their solutions, are
    disjoint), so a frame solves as many columns as its most demanding body needs, each body the
    fewer of its touched unknowns and its rows. A block of more than :data:`SCHUR_BLOCK_MIN`
    unknowns takes Z from its own Schur complement where ``schur`` accepts (keyed by its size and
    first unknown); bodies without contacts cost nothing. Without ``bodies`` (or when G mixes
    them) the system is one block. An iterative frame solver would solve the shared columns to
    one tolerance for all bodies: with several bodies A is then factorised once by a direct
    solver, kept in ``cache`` (a dict kept across frames) under (size, 0); after each frame the
    cache holds only what that frame used. With ``dense`` > 0 (and no Schur complement of the frame's
    own) the blocks of at most ``dense`` used unknowns (an affine or rigid body's reduced ones and its
    elastic vertices') add their part of W, and of :meth:`apply`, from their dense Cholesky factors
    (:class:`~skfem_affine.contact.dense.DenseBlocks`). ``columns_solved``: the right-hand sides
    solved by the last :meth:`delassus`; ``schur_unknowns``: the unknowns whose Z came from Schur
    complements; ``dense_unknowns``: those of the blocks whose part came from their dense factors.

    Its dense work (the blocks' Cholesky factors, triangular solves and products) is small: call
    :meth:`delassus` and :meth:`apply` under the contact solve's thread policy,
    :func:`~skfem_affine.threads.serial_blas` (:meth:`~skfem_affine.contact.pgs.Contact.resolve`
    enters it once per frame).
    """

    def __init__(self, operator, block=64, cache=None, touched=True, schur=None, bodies=None, dense=0):
        self.operator, self.solver, self.G = operator, operator.solver, operator.G
        self._Gcsr = None if self.G is None else self.G.tocsr()
        self.block, self.touched, self.schur = int(block), bool(touched), schur
        self.iterative = operator.iterative
        labels = None if bodies is None else unknown_bodies(_checked_bodies(bodies, operator), self._Gcsr)
        known = labels[labels >= 0] if labels is not None else np.zeros(0, dtype=np.int64)
        self.labels = labels if known.size and known.min() < known.max() else None
        self.parts = None if self.labels is None else int(self.labels.max()) + 1  # None: one block
        self.cache = {} if cache is None else cache
        used = set()
        if self.parts is not None and self.iterative:
            key = (operator.shape[0], 0)
            if key not in self.cache:
                self.cache[key] = block_solver(key[0])
            self.solver, self.iterative = self.cache[key], False
            self.solver.factorize(operator.matrix)
            used.add(key)
        for key in [key for key in self.cache if key not in used]:  # a frame's blocks are not the next one's
            del self.cache[key]
        self.columns_solved = 0  # right-hand sides solved by the last :meth:`delassus`
        self.schur_unknowns = 0  # unknowns whose Z came from the Schur complement instead
        self.dense_unknowns = 0  # unknowns of the blocks whose part of W came from their dense factors
        # a frame factorised with the touched unknowns last has their complement already: no dense blocks
        self.dense = None if not (dense and self.touched and operator.schur is None) else DenseBlocks(
            operator, self.labels, used_unknowns(self._Gcsr, operator.shape[0]), dense)
        self._J = self._Jr = None  # the last J and Jr = J G (:attr:`Jr`)
        self._dense_blocks, self._small = [], None  # the last W's blocks from dense factors; the small blocks' unknowns

    def _from_frame(self, label, T):
        """Z = (A^-1)_TT on the unknowns T (sorted) of one block from the Schur complement S the frame's
        own factorisation left (:attr:`Operator.schur`), inverting the block's part of S only (A does
        not couple bodies, so neither does S); None without it or when T is not within its unknowns.
        S may be a list of the blocks' complements, one after another in ``keep`` (a frame factorised
        body by body; each block's unknowns sorted, the blocks in any order)."""
        keep, S = self.operator.schur
        if isinstance(S, list):
            ends = np.cumsum([Sb.shape[0] for Sb in S])
            by = np.argsort(keep, kind="stable")
            at = np.minimum(np.searchsorted(keep[by], T), keep.size - 1)
            pos = by[at]
            if not pos.size or not np.array_equal(keep[pos], T):
                return None
            b = int(np.searchsorted(ends, pos[0], side="right"))
            start = ends[b] - S[b].shape[0]
            if pos.min() < start or pos.max() >= ends[b]:
                return None
            self.schur_unknowns += T.size
            return inverse_on_positions(S[b], pos - start, self._factor(S[b], T))
        part = np.arange(keep.size) if self.labels is None else np.flatnonzero(self.labels[keep] == label)
        pos = np.searchsorted(keep[part], T)
        if pos.size and (pos[-1] >= part.size or not np.array_equal(keep[part][pos], T)):
            return None
        self.schur_unknowns += T.size
        if part.size == keep.size:  # the whole complement: the frame's handle may hold its factor
            return inverse_on_positions(S, pos, self._factor(S, T))
        return inverse_on_positions(np.ascontiguousarray(S[np.ix_(part, part)]), pos)

    def _factor(self, S, T):
        """S's Cholesky factor made by the frame's factorisation (the handle of the block of T, the sorted
        unknowns of one body, when the frame was factorised body by body), or None."""
        solver = self.solver
        if isinstance(solver, BlockSolver):
            if not T.size:
                return None
            solver = solver.handles[int(np.searchsorted(solver.bounds, T[0], side="right")) - 1]
        factor_of = getattr(solver, "factor_of", None)
        return factor_of(S) if factor_of is not None else None

    def _from_schur(self, label, T):
        """Z = (A^-1)_TT on the unknowns T (sorted) of one block from a Schur complement, or None when
        ``schur`` is not given or declines, the solver is iterative or the block is small."""
        if not self.touched:
            return None
        if self.operator.schur is not None:  # on A's unknowns, or A_r's of a reduced frame
            Z = self._from_frame(label, T)
            if Z is not None or isinstance(self.operator.schur[1], list):
                return Z  # a body the frame factorised plainly: no second factorisation, its columns are solved
        if self.schur is None or self.iterative:
            return None
        A, key = None, None
        if self.labels is not None:
            idx = np.flatnonzero(self.labels == label)
            if idx.size <= SCHUR_BLOCK_MIN:
                return None
            A = self.operator.matrix
            A = A[idx[0]:idx[-1] + 1, idx[0]:idx[-1] + 1] if idx[-1] - idx[0] + 1 == idx.size else A[idx][:, idx]
            T, key = np.searchsorted(idx, T), (idx.size, int(idx[0]))
        Z = self.schur.inverse_on(self.operator.matrix if A is None else A, T, key=key)
        if Z is not None:
            self.schur_unknowns += T.size
        return Z

    def _blocks(self, Jr):
        """Per body whose unknowns the contacts touch: (the body, its touched unknowns T_b, the rows of Jr
        on them, those rows' entries Jt_b as a CSC matrix (rows x T_b)); and T, the T_b one after another."""
        Jc = Jr.tocsc()
        Jc.eliminate_zeros()
        count = np.diff(Jc.indptr)
        T = np.flatnonzero(count)
        if T.size == 0:
            return [], T
        if self.labels is None:
            bounds, labels = np.array([0, T.size]), np.zeros(1, dtype=np.int64)
        else:
            lab = self.labels[T]
            order = np.argsort(lab, kind="stable")
            T, lab = T[order], lab[order]
            cuts = np.flatnonzero(np.diff(lab)) + 1
            bounds, labels = np.concatenate([[0], cuts, [T.size]]), lab[np.concatenate([[0], cuts])]
        count = count[T]  # the columns T of Jc, gathered
        ptr = np.concatenate([[0], np.cumsum(count)])
        src = np.repeat(Jc.indptr[T] - ptr[:-1], count) + np.arange(ptr[-1])
        indices, data = Jc.indices[src], Jc.data[src]
        out, seen = [], np.zeros(Jr.shape[0], dtype=bool)
        for b, (s, e) in enumerate(zip(bounds[:-1], bounds[1:])):
            p, q = ptr[s], ptr[e]
            seen[:] = False
            seen[indices[p:q]] = True
            rows = np.flatnonzero(seen)
            local = (np.cumsum(seen) - 1)[indices[p:q]]  # the body's rows, numbered in order
            Jt = sp.csc_matrix((data[p:q], local, ptr[s:e + 1] - p), shape=(rows.size, e - s))
            out.append((labels[b], T[s:e], rows, Jt))
        return out, T

    def _packed(self, plans, T):
        """X_T: the touched rows (of T) of A^-1 R, R (r x c) the right-hand sides of every body side by side,
        ``block`` columns at a time. ``plans``: (s, e, rows, Jt, unit) per body, its unknowns T[s:e];
        ``unit``: its columns are e_T[s:e], else its rows of Jr (the entries of Jt)."""
        width = max(Jt.shape[1] if unit else Jt.shape[0] for _, _, _, Jt, unit in plans)
        r_idx, c_idx, vals = [], [], []
        for s, e, _, Jt, unit in plans:
            if unit:
                r_idx.append(T[s:e])
                c_idx.append(np.arange(e - s))
                vals.append(np.ones(e - s))
            else:  # column j: row j of Jt on the body's touched unknowns
                r_idx.append(T[s:e][np.repeat(np.arange(e - s), np.diff(Jt.indptr))])
                c_idx.append(Jt.indices)
                vals.append(Jt.data)
        r_idx, c_idx, vals = np.concatenate(r_idx), np.concatenate(c_idx), np.concatenate(vals)
        X = np.empty((T.size, width))
        for s in range(0, width, self.block):  # the bodies' supports are disjoint: no entry is set twice
            e = min(s + self.block, width)
            R = np.zeros((self.Jr.shape[1], e - s))
            part = (c_idx >= s) & (c_idx < e)
            R[r_idx[part], c_idx[part] - s] = vals[part]
            X[:, s:e] = _solve(self.solver, R, self.iterative)[T]
        self.columns_solved = width
        return X

    @property
    def Jr(self):
        """Jr = J G (CSR) of the last :meth:`delassus`, J in full space; made on first use (a frame whose
        contacts touch small blocks only never needs it)."""
        if self._Jr is None:
            J = self._J
            self._Jr = sp.csr_matrix(J @ self.G) if self.G is not None else sp.csr_matrix(J)
        return self._Jr

    def delassus(self, J):
        """W = J A^-1 J^T (dense, symmetric), A^-1 ~ G A_r^-1 G^T in a reduced frame."""
        J = J if sp.issparse(J) and J.format == "csr" else sp.csr_matrix(J)
        self._J, self._Jr, self.columns_solved, self.schur_unknowns, self.dense_unknowns = J, None, 0, 0, 0
        k = J.shape[0]
        W = np.zeros((k, k))
        self._dense_blocks, self._small = [], None
        parts, plans, s, rest = [], [], 0, True
        if self.dense is not None:  # the small blocks' parts from their dense factors, the others as below
            dense, labels = self.dense.parts(J, self._Gcsr)
            if labels.size:
                self._dense_blocks = labels
                self._small, self.dense_unknowns, rest = self.dense.in_small(), self.dense.touched, self.dense.rest
                parts += [(rows, C, C.T, False) for rows, C in dense]  # W_b = C C^T
        Jr = self.Jr if rest else None
        if rest and self._small is not None:
            Jr = Jr.copy()
            Jr.data[self._small[Jr.indices]] = 0.0
        blocks, T = self._blocks(Jr) if rest else ([], None)
        for label, Tb, rows, Jt in blocks:
            e = s + Tb.size
            Z = self._from_schur(label, Tb)
            if Z is not None:
                parts.append((rows, Jt, Z, True))
            else:
                plans.append((s, e, rows, Jt, self.touched and Tb.size < rows.size))
            s = e
        if plans:
            X = self._packed(plans, T)
            parts += [(rows, Jt, X[s:e, :Jt.shape[1] if unit else rows.size], unit)
                      for s, e, rows, Jt, unit in plans]
        if not parts:
            return W
        for rows, Jt, X, unit in parts:
            if sp.issparse(Jt) and 10 * Jt.nnz >= Jt.shape[0] * Jt.shape[1]:  # e.g. an affine body's 12 unknowns
                Jt = Jt.toarray()
            _add_symmetric(W, rows, np.ascontiguousarray(Jt @ (Jt @ X).T if unit else Jt @ X))
        return W

    def apply(self, lam):
        """dv = A^-1 J^T lambda on the free DOFs (through G when reduced): one solve, the small blocks'
        part from their dense factors (no solve when the contacts touch only those)."""
        if self._small is None:
            y = _solve(self.solver, (self.Jr.T @ lam)[:, None], self.iterative)[:, 0]
        else:
            y = np.zeros(self.operator.shape[0])
            if self.dense.rest:
                rest = self.Jr.T @ lam
                rest[self._small] = 0.0
                if np.any(rest):
                    y = _solve(self.solver, rest[:, None], self.iterative)[:, 0]
            self.dense.apply(lam, y)
        return self.G @ y if self.G is not None else y
