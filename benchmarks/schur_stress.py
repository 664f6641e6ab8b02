"""Stress test of the Schur complement path (MKL Pardiso ``iparm(36)``): many varied calls in one
process, each checked against the dense inverse, so that memory corruption shows as a crash or a
wrong Z here and not later in a test session.

Calls vary the matrix (new patterns from time to time, new values every call), the touched set T
(its size, a subset of the last one, more than half the unknowns: declined), the MKL thread count
of the caller, the instance (several alive at once, some dropped and collected) and the mode: Z
from the complement alone (``SchurInverse.inverse_on``) or from the frame's own factorisation
(``SchurInverse.factorize_on``, which then also solves a right-hand side, checked too)::

    python benchmarks/schur_stress.py --calls 2000

``--frame-solves`` instead stresses the Schur factorisation in mode ``iparm(36) = 2`` serving also as
a frame's own factorisation (phase 33 solves of the whole system, as
``benchmarks/delassus_routes.py`` times it) in raw calls: new patterns, sets and
values call to call, two handles alive, each on the MKL thread count of its analysis; S and the
solves are checked against dense ones.

``--repro threads`` instead makes the raw Pardiso calls that crash, without the guards of
:class:`~skfem_affine.solvers.PardisoSchur`: an analysis on two MKL threads, then numeric
factorisations of it on one (a segmentation fault within 150 calls on a 2-core machine; run it
in a subprocess). The other guarded condition, T equal to all the unknowns, shows under
valgrind (``PYTHONMALLOC=malloc valgrind python benchmarks/schur_stress.py --repro all``: an
invalid write of 4 bytes just after a buffer Pardiso allocated for the Schur complement).
"""
import argparse
import faulthandler
import gc
import os
import sys

import numpy as np
import scipy.sparse as sp

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def spd(rng, vertices):
    """A random SPD matrix with 3 unknowns per vertex on a random sparse graph (elasticity-like)."""
    i, j = rng.integers(0, vertices, 4 * vertices), rng.integers(0, vertices, 4 * vertices)
    graph = sp.coo_matrix((np.ones(i.size), (i, j)), shape=(vertices, vertices)).tocsr()
    B = sp.kron((graph + graph.T) > 0, np.ones((3, 3))).tocsr()
    B.data = 0.1 * rng.normal(size=B.nnz)
    B = B + B.T
    return sp.csr_matrix(B + sp.diags(np.abs(B).sum(axis=1).A1 + 1.0))


def stress(calls, check_every, seed, vertices=400):
    from threadpoolctl import ThreadpoolController
    from skfem_affine.contact.schur import SchurInverse, inverse_on_positions
    control = ThreadpoolController()
    rng = np.random.default_rng(seed)
    providers = [SchurInverse(min_size=1) for _ in range(3)]
    mats = [spd(rng, int(v)) for v in rng.integers(10, vertices, size=5)]
    last = [None] * len(providers)
    worst, declined = 0.0, 0
    for c in range(calls):
        if rng.random() < 0.05:  # a new pattern
            m = int(rng.integers(len(mats)))
            mats[m] = spd(rng, int(rng.integers(10, vertices)))
            last = [None if kept is not None and kept[0] == m else kept for kept in last]
        if rng.random() < 0.03:  # an instance dropped and collected, a new one in its place
            h = int(rng.integers(len(providers)))
            providers[h], last[h] = SchurInverse(min_size=1), None
            gc.collect()
        h = int(rng.integers(len(providers)))
        m = int(rng.integers(len(mats)))
        A = mats[m].copy()
        A.data *= 1.0 + 0.01 * rng.random()
        n = A.shape[0]
        if last[h] is not None and last[h][0] == m and rng.random() < 0.5:  # a subset of the last set
            T = np.sort(rng.choice(last[h][1], max(1, int(0.7 * last[h][1].size)), replace=False))
        else:
            T = np.sort(rng.choice(n, int(rng.integers(1, int(0.6 * n) + 2)), replace=False))
        frame, x = rng.random() < 0.4, None  # the frame's own factorisation, which also solves
        b = rng.normal(size=n)
        with control.limit(limits=int(rng.integers(1, 3)), user_api="blas"):
            if frame:
                out = providers[h].factorize_on(A, T)
                Z = None if out is None else inverse_on_positions(out[2], np.searchsorted(out[1], T))
                x = None if out is None else out[0].solve(b)
            else:
                Z = providers[h].inverse_on(A, T)
        if Z is None:
            declined += 1
            if 2 * T.size <= n:
                raise AssertionError(f"call {c}: a set of {T.size} of {n} unknowns declined")
            continue
        last[h] = (m, T)
        if c % check_every == 0:
            ref = np.linalg.inv(A.toarray())[np.ix_(T, T)]
            err = np.abs(Z - ref).max() / np.abs(ref).max()
            if x is not None:
                err = max(err, np.abs(A @ x - b).max() / np.abs(b).max())
            worst = max(worst, err)
            if err > 1e-8:
                raise AssertionError(f"call {c}: Z off by {err:.2e} (n {n}, |T| {T.size})")
    print(f"survived {calls} calls ({declined} declined: more than half the unknowns), "
          f"worst relative error of Z and the solves {worst:.1e}")


def frame_solves(calls, seed, vertices=200):
    """Schur mode 2 with the frame's solves on the same factorisation (raw calls, guarded as
    :class:`~skfem_affine.solvers.PardisoSchur` is: one thread count per analysis, T at most half)."""
    from threadpoolctl import ThreadpoolController
    from skfem_affine.solvers import _PardisoLibrary
    control = ThreadpoolController()
    rng = np.random.default_rng(seed)
    handles, worst = [None, None], 0.0
    for c in range(calls):
        h = int(rng.integers(2))
        if handles[h] is not None:  # the handle's next system: release the last on its thread count
            lib, arrays, threads = handles[h]
            with control.limit(limits=threads, user_api="blas"):
                lib.release(arrays)
        A = spd(rng, int(rng.integers(10, vertices)))
        U = sp.triu(A, format="csr")
        U.sort_indices()
        n = A.shape[0]
        k = int(rng.integers(1, n // 2 + 1))
        T = np.sort(rng.choice(n, k, replace=False))
        marks = np.zeros(n, dtype=np.int32)
        marks[T] = 1
        lib, threads = _PardisoLibrary(), int(rng.integers(1, 3))
        lib._ps.set_iparm(2, 2)
        lib._ps.set_iparm(5, 0)
        lib._ps.set_iparm(36, 2)
        for rep in range(int(rng.integers(1, 4))):  # a new analysis, then numeric factorisations only
            scale = 1.0 + 0.01 * rep
            arrays = (U.data * scale, U.indptr.astype(np.int32), U.indices.astype(np.int32), n)
            b = rng.normal(size=(n, 2))
            with control.limit(limits=threads, user_api="blas"):
                S = lib.call(12 if rep == 0 else 22, arrays, np.zeros((max(n, k * k), 1)), perm=marks.copy())
                x = lib.call(33, arrays, np.asfortranarray(b), perm=marks.copy())
            dense = scale * A.toarray()
            ref = np.linalg.inv(dense)[np.ix_(T, T)]
            err = max(np.abs(np.linalg.inv(S[:k * k, 0].reshape(k, k)) - ref).max() / np.abs(ref).max(),
                      np.abs(dense @ x - b).max() / np.abs(b).max())
            worst = max(worst, err)
            if err > 1e-8:
                raise AssertionError(f"call {c}: S^-1 or the solve off by {err:.2e} (n {n}, |T| {k})")
        handles[h] = (lib, arrays, threads)
    for kept in handles:
        if kept is not None:
            with control.limit(limits=kept[2], user_api="blas"):
                kept[0].release(kept[1])
    print(f"survived {calls} calls (mode 2 with the frame's solves), worst relative error {worst:.1e}")


def repro(kind, calls, seed):
    """The raw calls that corrupt memory (no guards)."""
    from threadpoolctl import ThreadpoolController
    from skfem_affine.solvers import _PardisoLibrary
    control = ThreadpoolController()
    rng = np.random.default_rng(seed)
    lib = _PardisoLibrary()
    for c in range(calls):
        A = spd(rng, 5 if kind == "all" else 339)
        U = sp.triu(A, format="csr")
        U.sort_indices()
        n = A.shape[0]
        arrays = (U.data.copy(), U.indptr.astype(np.int32), U.indices.astype(np.int32), n)
        k = n if kind == "all" else int(rng.integers(200, 300))
        marks = np.zeros(n, dtype=np.int32)
        marks[np.sort(rng.choice(n, k, replace=False))] = 1
        with control.limit(limits=2, user_api="blas"):
            lib.schur(12, arrays, marks, k)  # a new analysis on the live handle, as the old path made them
        with control.limit(limits=1 if kind == "threads" else 2, user_api="blas"):
            lib.schur(22, arrays, marks, k)
        print("call", c, "n", n, "k", k, flush=True)
    print("no crash")


def main():
    faulthandler.enable()
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--calls", type=int, default=2000)
    ap.add_argument("--check-every", type=int, default=10, help="compare Z with the dense inverse every so many calls")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--vertices", type=int, default=400, help="largest matrix: 3 unknowns per vertex")
    ap.add_argument("--repro", choices=("threads", "all"), help="the unguarded calls that crash")
    ap.add_argument("--frame-solves", action="store_true",
                    help="Schur mode 2 also solving the whole system (raw calls, not a path of the package)")
    args = ap.parse_args()
    if args.frame_solves:
        frame_solves(args.calls, args.seed, args.vertices)
    elif args.repro:
        repro(args.repro, min(args.calls, 150 if args.repro == "threads" else 3), args.seed)
    else:
        stress(args.calls, args.check_every, args.seed, args.vertices)


if __name__ == "__main__":
    main()
