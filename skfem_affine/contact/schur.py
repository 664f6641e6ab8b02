r"""Z = (A^-1)_TT on the unknowns T that contacts touch, from a Schur complement (paper sec. 3.3).

With S the Schur complement of A on T (:class:`~skfem_affine.solvers.PardisoSchur`, one
factorisation of A with T eliminated last), ``(A^-1)_TT = S^-1``: no solve per unknown of T.
:class:`SchurInverse` decides, frame by frame, whether that pays: a new analysis (ordering) costs
up to a few numeric factorisations, so it keeps the last one while the contacts touch a subset of its
unknowns at most twice as many. Once a kept analysis has served a later frame (the contacts are
settling), new touched unknowns grow it under the same bound; while every frame needs a new one
(bodies landing: their contacts move further than a grown set reaches), it is made on the touched
unknowns alone, the cheaper set. Below ``min_size`` unknowns (or above half of A's, or of those that couple to another:
:func:`~skfem_affine.solvers.schur_set_fits`) it declines,
and the caller solves the unit columns.
Several systems (the bodies of a scene, each its own block) each keep their analysis, by key.

In full space the contacts are found before the frame's solve, so the frame's own factorisation can
be the one with T last (:meth:`SchurInverse.factorize_on`, a factorisation that also solves the whole
system, S's Cholesky factor with it): Z then costs S^-1 from that factor on top of the frame's
factorisation, not a second factorisation. That
handle is the whole system's (key None), under the same rules but one: when the matrix's pattern
differs from the previous frame's (a reduced frame whose bodies changed), the plain factorisation
would make a new analysis too, so one on fewer than ``min_size`` unknowns is not declined. A frame
whose contacts touch several bodies is factorised body by body, each body's block with its touched
unknowns last (:meth:`SchurInverse.factorize_blocks`, :mod:`~skfem_affine.contact.blocks`).
"""
import zlib
from collections import OrderedDict

import numpy as np
from scipy.linalg import lapack

from skfem_affine.checks import flag, integer, real
from skfem_affine.contact.blocks import UpperBlocks, body_bounds, factorize_blocks
from skfem_affine.solvers import Pardiso, PardisoSchur, has_pardiso, positive_definite, schur_set_fits
from skfem_affine.threads import serial_blas

# Below this many touched unknowns and without a kept analysis, solves of the unit columns with the
# frame's factorisation are cheaper than a new analysis with its factorisation (measured in
# docs/contact.md, "The Delassus operator from a Schur complement against unit-column solves").
SCHUR_MIN = 128
# A kept analysis serves while the touched unknowns are at least 1 / SPREAD of its set, and a predicted
# superset is analysed when at most SPREAD times the touched unknowns (measured in docs/contact.md).
SPREAD = 2.0


class SchurInverse:
    """(A^-1)_TT from the Schur complement of A on T or on a kept superset of T.

    Parameters
    ----------
    min_size : int
        Fewest touched unknowns for which a new analysis is made (:data:`SCHUR_MIN`).
    systems : int
        Most systems (keys) whose analyses are kept; the least recently used goes first.
    frame : bool
        Whether the full-space frame factorises with the touched unknowns last and solves with that
        factorisation (:meth:`factorize_on`, used by :class:`~skfem_affine.reducers.full.FullSpace`);
        False: the frame factorises plainly and Z takes a factorisation of its own.
    blocks : bool
        Whether a full-space frame whose contacts touch several bodies is factorised body by body, each
        body's block with its touched unknowns last (:meth:`factorize_blocks`); False: plainly, and
        each large body's Z from a complement on a handle of its own.
    spread : float
        A kept analysis serves while its set is at most ``spread`` times the touched unknowns, and a
        predicted superset of them (``near`` of :meth:`factorize_on`) is analysed when at most that many
        (:data:`SPREAD`, >= 1).

    ``available`` is False without MKL Pardiso; :meth:`inverse_on` then always returns None.
    Hold one instance per simulation, not per frame: it keeps the analyses.
    """

    def __init__(self, min_size=SCHUR_MIN, systems=16, frame=True, blocks=True, spread=SPREAD):
        self.min_size = integer(min_size, "min_size", low=1)
        self.spread = real(spread, "spread", low=1.0)
        self.systems = integer(systems, "systems", low=1)
        self.frame = flag(frame, "frame")
        self.blocks = flag(blocks, "blocks")
        self.available = has_pardiso()
        self._kept_by = OrderedDict()  # key -> PardisoSchur, each on its own Pardiso handle
        self._resume = {}  # key -> the unknowns a checkpointed run had analysed, for the key's next call
        self._served = {}  # key -> whether its kept analysis has served a later call (then it may grow)
        self.analyses = 0  # new analyses made (the rest were numeric factorisations only)
        self._seen = None  # the pattern of the last matrix given to :meth:`factorize_on` (pattern_key)
        self._plain_by = OrderedDict()  # key -> Pardiso: blocks of :meth:`factorize_blocks` factorised plainly
        self._split = UpperBlocks()

    def _handle(self, key, solves):
        if key not in self._kept_by or self._kept_by[key].solves != solves:
            self._kept_by[key] = PardisoSchur(solves=solves)
            while len(self._kept_by) > self.systems:
                self._served.pop(self._kept_by.popitem(last=False)[0], None)
        self._kept_by.move_to_end(key)
        return self._kept_by[key]

    def _kept(self, last, n, T, key, floor=True, near=None):
        """The unknowns to take the complement on (T or a superset) and whether they are the kept ones,
        or (None, False) to decline; ``last``: those of the current analysis when it is of this
        system's pattern (:meth:`PardisoSchur.analysed`); ``near``: a predicted superset of T, the set of
        a new analysis when at most ``spread`` times T's."""
        if last is None and key in self._resume:  # as the saved run: the same set rounds the same way
            last = self._resume.pop(key)
            last = last if last.size and last[-1] < n and 2 * last.size <= n else None
        if last is not None:
            if last.size <= self.spread * T.size and np.isin(T, last, assume_unique=True).all():
                return last, True
            grown = np.union1d(last, T)
            if self._served.get(key, False) and grown.size <= 2 * T.size and 2 * grown.size <= n:
                return grown, False
        if T.size == 0 or (floor and T.size < self.min_size) or 2 * T.size > n:
            return None, False
        if near is not None and near.size <= self.spread * T.size and 2 * near.size <= n:
            return near, False
        return T, False

    def _complement(self, A, T, upper, key, solves, floor=True, near=None):
        """(handle, keep, S): the factorisation of A with ``keep`` (T or a kept superset) last and its
        Schur complement S on them, or None when declining. A handle of the other mode is replaced
        only when the complement is taken."""
        if not self.available:
            return None
        T = np.asarray(T, dtype=np.int64)
        handle = self._kept_by.get(key)
        current = handle.analysed(A, upper) if handle is not None and handle.solves == solves else None
        keep, kept = self._kept(current, A.shape[0], T, key, floor, near)
        if keep is None or not schur_set_fits(A.indptr, A.indices, keep.size):
            return None
        if keep is not current:  # a new set (or pattern): a new analysis
            self.analyses += 1
        self._served[key] = kept
        schur = self._handle(key, solves)
        return schur, keep, schur.complement(A, keep, upper)

    def inverse_on(self, A, T, upper=False, key=None):
        """Z = (A^-1)_TT (dense, ``|T| x |T|``) for the SPD matrix A (CSR, whole or, with ``upper=True``,
        its upper triangle) and the sorted unknowns T; None when the Schur complement declines.
        ``key`` names the system (e.g. a body's block), whose analysis is kept for its next call."""
        out = self._complement(A, T, upper, key, solves=False)
        if out is None:
            return None
        _, keep, S = out
        return inverse_on_positions(S, np.searchsorted(keep, np.asarray(T, dtype=np.int64)))

    def factorize_on(self, A, T, upper=False, near=None):
        """The whole system's factorisation with T (or a kept superset ``keep``) last, which also solves
        A x = b: (solver, keep, S) with S the Schur complement on ``keep`` (``(A^-1)_keep,keep = S^-1``),
        or None when the rules above decline (the caller factorises plainly). A matrix whose pattern
        differs from the last one given here is taken at any size: its plain factorisation would
        analyse anew as well (on the wheel at rest a reduced frame's pattern changes every frame).
        ``near``: sorted unknowns predicted to be touched in the next frames, a superset of T: a new
        analysis takes it (when at most ``spread`` times T), so that it serves the frames after."""
        seen = pattern_key(A)
        if near is not None:
            near = np.asarray(near, dtype=np.int64)
            if near.size < T.size or not np.isin(T, near, assume_unique=True).all():
                raise ValueError("near must hold every touched unknown T")
        fresh = self._seen is not None and not np.array_equal(seen, self._seen)
        self._seen = seen
        return self._complement(A, T, upper, None, solves=True, floor=not fresh, near=near)

    def complement_block(self, A, T, key, floor=True):
        """One block's factorisation in the solving mode with T (or a kept superset) last: (handle, keep, S),
        or None when the rules above decline (A: the block's upper triangle, CSR). ``floor=False``: fewer
        than ``min_size`` touched unknowns are taken too (the block's plain factorisation would analyse a
        new pattern as well)."""
        return self._complement(A, np.asarray(T, dtype=np.int64), True, key, solves=True, floor=floor)

    def factorize_blocks(self, A, T, bodies):
        """The frame's factorisation body by body, each body's block (keyed by its size and first unknown)
        with its touched unknowns last where the rules above accept, plainly where they decline:
        (solver, keep, [S_b]), the complements in the order of ``keep``; None when the bodies' unknowns
        are not contiguous ranges, A couples them, or no block's complement is taken (the caller
        factorises A whole). ``bodies``: the body of each unknown of A."""
        if not self.available or not self.blocks:
            return None
        bounds = body_bounds(bodies)
        if bounds is None or bounds[-1] != A.shape[0]:
            return None
        return factorize_blocks(self, A, np.asarray(T, dtype=np.int64), bounds, self._split, self._plain)

    def _plain(self, key):
        """The plain Pardiso handle of a block (the least recently used of more than ``systems`` goes)."""
        if key not in self._plain_by:
            self._plain_by[key] = Pardiso()
            while len(self._plain_by) > self.systems:
                self._plain_by.popitem(last=False)
        self._plain_by.move_to_end(key)
        return self._plain_by[key]

    def state_dict(self):
        """The unknowns each kept analysis was made on, by system: a resumed run analyses the same
        sets (another superset would round Z differently)."""
        keys = [(-1, -1) if key is None else key for key in self._kept_by]
        out = {"schur_systems": np.array(keys, dtype=np.int64).reshape(-1, 2),
               "schur_served": np.array([self._served.get(key, False) for key in self._kept_by], dtype=bool)}
        out["schur_seen"] = np.zeros(0, np.int64) if self._seen is None else self._seen.copy()
        for i, schur in enumerate(self._kept_by.values()):
            kept = schur._pattern[2] if schur._pattern is not None else np.zeros(0, np.int64)
            out[f"schur{i}.keep"] = np.array(kept, dtype=np.int64)
        return out

    def load_state_dict(self, state):
        self._kept_by = OrderedDict()
        systems = np.asarray(state.get("schur_systems", np.zeros((0, 2))), dtype=np.int64).reshape(-1, 2)
        self._resume, self._served = {}, {}
        seen = np.asarray(state["schur_seen"], dtype=np.int64).reshape(-1)
        if seen.size not in (0, 4):
            raise ValueError(f"schur_seen must be empty or a pattern's 4 numbers, got {seen.size}")
        self._seen = seen.copy() if seen.size else None
        served = np.asarray(state["schur_served"], dtype=bool).reshape(-1)
        if served.size != len(systems):
            raise ValueError(f"schur_served must hold one flag per system ({len(systems)}), got {served.size}")
        for i, (size, first) in enumerate(systems):
            key = None if size < 0 else (int(size), int(first))
            keep = np.asarray(state[f"schur{i}.keep"], dtype=np.int64)
            if keep.ndim != 1 or (keep.size > 1 and np.any(np.diff(keep) <= 0)) or (keep.size and keep[0] < 0):
                raise ValueError(f"schur{i}.keep must be sorted distinct unknowns")
            self._resume[key] = keep
            self._served[key] = bool(served[i])


def pattern_key(A):
    """A sparse matrix's pattern in four numbers: its shape, its entries and a checksum of its indices."""
    indptr, indices = np.ascontiguousarray(A.indptr), np.ascontiguousarray(A.indices)
    return np.array([A.shape[0], indices.size, zlib.crc32(indptr), zlib.crc32(indices)], dtype=np.int64)


def inverse_on_positions(S, pos, factor=None):
    """(S^-1)[pos][:, pos] for the SPD matrix S (dense), from Cholesky factors (LAPACK).

    ``pos`` (increasing) all of S: S^-1 from its Cholesky factor (potrf, potri: half of a solve with I).
    Fewer (S on a kept superset of the touched unknowns): ``(S^-1)_PP`` is the inverse of S's own
    Schur complement on P, ``C = S_PP - S_PN S_NN^-1 S_NP``, so only S_NN is factorised (potrf, trtrs,
    syrk) and C inverted, not the whole of S. ``factor``: S's lower Cholesky factor when already made
    (:meth:`~skfem_affine.solvers.PardisoSchur.factor_of`; left unchanged): S^-1 then costs potri only,
    taken whenever its flops are fewer than the route on P's."""
    pos = np.asarray(pos, dtype=np.int64)
    k, p = S.shape[0], pos.size
    q = k - p
    with serial_blas():
        if factor is not None and 2 * k ** 3 <= q ** 3 + 3 * q * q * p + 6 * q * p * p + 3 * p ** 3:
            L = positive_definite(k, *lapack.dpotri(factor, lower=1, overwrite_c=0))
        else:
            if p < k:
                rest = np.setdiff1d(np.arange(k), pos, assume_unique=True)
                L = positive_definite(k, *lapack.dpotrf(np.asarray(S[np.ix_(rest, rest)], order="F"), lower=1, clean=1))
                X, _ = lapack.dtrtrs(L, np.asarray(S[np.ix_(rest, pos)], order="F"), lower=1)  # L nonsingular
                S, pos = np.asarray(S[np.ix_(pos, pos)], order="F") - X.T @ X, np.arange(p)
            L = positive_definite(p, *lapack.dpotrf(S, lower=1, clean=0))
            L = positive_definite(p, *lapack.dpotri(L, lower=1, overwrite_c=1))
    Z = np.tril(L[np.ix_(pos, pos)])  # potri fills the lower triangle only (pos is increasing)
    return Z + np.tril(Z, -1).T
