"""Several bodies: the frame's factorisation with every body's touched unknowns last, or body by body with
each body's touched unknowns last, against the plain factorisation with each body's Schur complement on
its own block (or the bodies' unit columns).

B copies of an elastic-like cube (a vector Laplacian with a mass term, 3630 unknowns each), its bottom
face touched (363 unknowns per body), A block diagonal. One process, one MKL thread, the routes in turn (the
order rotating), the median of ``--reps``; ms. Pardiso's complement of the whole system treats all the touched unknowns as one
dense block, while A (and so S) does not couple the bodies. Usage::

    python benchmarks/frame_schur_bodies.py --bodies 1 2 4 8
"""
import argparse
import os
import sys
import time

os.environ.setdefault("MKL_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")
sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

import numpy as np  # noqa: E402
import scipy.sparse as sp  # noqa: E402
import skfem  # noqa: E402
from skfem.models.poisson import laplace, mass  # noqa: E402

from skfem_affine.contact import delassus  # noqa: E402
from skfem_affine.contact.schur import SchurInverse  # noqa: E402
from skfem_affine.integrators.problem import Operator  # noqa: E402
from skfem_affine.solvers import Pardiso  # noqa: E402


def body():
    m = skfem.MeshTet.init_tensor(np.linspace(0, 1, 11), np.linspace(0, 1, 11), np.linspace(0, 1, 10))
    basis = skfem.Basis(m, skfem.ElementTetP1())
    K = sp.kron(laplace.assemble(basis) + 100 * mass.assemble(basis), sp.eye(3)).tocsr()
    bottom = np.flatnonzero(m.p[2] < 1e-9)
    return K, np.sort((3 * bottom[:, None] + np.arange(3)).ravel())


def interleaved(fs, reps):
    """The median ms of each of ``fs`` over ``reps`` rounds, the order rotating round to round."""
    out = [[] for _ in fs]
    for r in range(reps):
        for i in [(r + j) % len(fs) for j in range(len(fs))]:
            t0 = time.perf_counter()
            fs[i]()
            out[i].append(time.perf_counter() - t0)
    return [1e3 * float(np.median(t)) for t in out]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--bodies", type=int, nargs="+", default=[1, 2, 4, 8])
    ap.add_argument("--reps", type=int, default=5)
    args = ap.parse_args(argv)
    K, Tb = body()
    nb = K.shape[0]
    print("| bodies | unknowns / touched | plain factorisation | frame's own, Schur set of every body "
          "| body by body, each body's set | plain + each body's own complement | plain + unit columns side by side |")
    print("|---|---|---|---|---|---|---|")
    for B in args.bodies:
        A = sp.block_diag([K * (1 + 0.01 * i) for i in range(B)], format="csr")
        T = np.concatenate([Tb + i * nb for i in range(B)])
        J = sp.csr_matrix((np.ones(T.size), (np.arange(T.size), T)), shape=(T.size, A.shape[0]))
        bodies = np.repeat(np.arange(B), nb)
        plain, frame, own, blocks = Pardiso(), SchurInverse(min_size=1), SchurInverse(min_size=1), SchurInverse(min_size=1)
        plain.factorize(A)

        def framed():
            solver, keep, S = frame.factorize_on(A, T)
            delassus.Resolvent(Operator(solver, A, schur=(keep, S)), bodies=bodies).delassus(J)

        def by_body():
            solver, keep, S = blocks.factorize_blocks(A, T, bodies) if B > 1 else blocks.factorize_on(A, T)
            delassus.Resolvent(Operator(solver, A, schur=(keep, S)), bodies=bodies).delassus(J)

        def separate(schur):
            plain.factorize(A)
            delassus.Resolvent(Operator(plain, A), schur=schur, bodies=bodies).delassus(J)

        framed(), by_body(), separate(own)  # the analyses
        f, *times = interleaved([lambda: plain.factorize(A), framed, by_body, lambda: separate(own),
                                 lambda: separate(None)], args.reps)
        print(f"| {B} | {A.shape[0]} / {T.size} | {f:.0f} | " + " | ".join(f"{t:.0f} ({t / f:.1f}x)" for t in times) + " |",
              flush=True)


if __name__ == "__main__":
    main()
