"""What a reduced frame's factorisation costs against the full frame's: Pardiso's analysis (phase 11)
and numeric factorisation (phase 22) timed apart, and the factor's fill (``iparm(18)``, its nonzeros).

One affinification run of a contact scene (``benchmarks/contact_phases.py``'s scenes) is stepped to
``--frame``; that frame's full matrix A and reduced matrix A_r (the upper triangle the reducer
factorises, in its numbering) are captured with the unknowns its contacts touch, and then factorised
``--repeat`` times each way in turn (medians), one MKL thread:

- ``full, metis``: A with Pardiso's nested dissection (the full-space frame's analysis);
- ``reduced, given``: A_r in the order inherited from the mesh (``Mapping.elimination_order``);
- ``reduced, metis`` and ``reduced, md``: A_r with Pardiso's own orderings;
- ``full, schur`` and ``reduced, schur``: the factorisation with the touched unknowns last that also
  leaves their Schur complement (the route a frame with contacts on one body takes), timed as a new
  analysis (``analysis`` = phase 12 minus phase 22) and as a reused one (phase 22).

The plain factorisations also time the solves of the touched unknowns' unit columns, (A^-1)_{:,T},
which the Delassus operator needs when no Schur complement is taken.

Usage::

    python benchmarks/reduced_factorisation.py MESH_DIR --scene wheel --frame 130
    python benchmarks/reduced_factorisation.py --scene pile --cells 4 --frame 60
"""
import argparse
import os
import sys
import time

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import numpy as np  # noqa: E402
import scipy.sparse as sp  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))
sys.path.insert(0, HERE)
import contact_phases  # noqa: E402
from skfem_affine.reducers.affine import clustered  # noqa: E402
from skfem_affine.reducers.full import touched_unknowns  # noqa: E402
from skfem_affine.solvers import PardisoSchur, _PardisoLibrary  # noqa: E402


def capture(mesh_dir, scene, frame, cells):
    """Step the scene's affinification run to ``frame``; return that frame's (A upper, A_r upper, order,
    touched unknowns of A, touched unknowns of A_r) from its factorisation call."""
    sim = contact_phases.builders(mesh_dir, scene, frame + 1, cells)[1]
    seen = {}
    original = clustered.contact_factorization

    def spy(schur, bodies, solver, contacts, A, G=None, upper=False):
        if sim.state.frame == frame and contacts is not None and contacts.J is not None and G is not None:
            seen.update(Ar=A.copy(), upper=upper, Tr=touched_unknowns(contacts.J @ G), T=touched_unknowns(contacts.J))
        return original(schur, bodies, solver, contacts, A, G, upper)

    full_matrix, order_of = {}, clustered.reduction.Mapping.elimination_order

    def order_spy(gmap, rank):
        out = order_of(gmap, rank)
        if sim.state.frame == frame:
            seen["order"] = out
        return out

    frame_of = clustered.ClusteringReducer._frame

    def frame_spy(self, problem):
        if sim.state.frame == frame:
            full_matrix["A"] = problem.matrix()
        return frame_of(self, problem)

    clustered.contact_factorization, clustered.ClusteringReducer._frame = spy, frame_spy
    clustered.reduction.Mapping.elimination_order = order_spy
    try:
        while sim.state.frame <= frame:
            sim.step()
            if sim.state.frame % 10 == 0:
                print(f"{scene} frame {sim.state.frame}/{frame}", file=sys.stderr, flush=True)
    finally:
        clustered.contact_factorization, clustered.ClusteringReducer._frame = original, frame_of
        clustered.reduction.Mapping.elimination_order = order_of
    if "Ar" not in seen:
        raise SystemExit(f"frame {frame} of {scene} had no reduced frame with contacts on one body")
    A = sp.triu(sp.csr_matrix(full_matrix["A"]), format="csr")
    Ar = sp.csr_matrix(seen["Ar"]) if seen["upper"] else sp.triu(sp.csr_matrix(seen["Ar"]), format="csr")
    order = seen.get("order")
    if order is not None and order.size != Ar.shape[0]:
        order = None  # the frame renumbered its unknowns (several bodies): no order of A_r's numbering
    return A, Ar, order, seen["T"], seen["Tr"]


def arrays(U):
    U = sp.csr_matrix(U)
    U.sort_indices()
    return np.ascontiguousarray(U.data, dtype=float), U.indptr.astype(np.int32), U.indices.astype(np.int32), U.shape[0]


def plain(U, ordering, order=None, T=None):
    """(analysis ms, numeric ms, factor nonzeros, ms of the solves of T's unit columns) of U's Cholesky,
    ``order`` given or Pardiso's ``ordering``."""
    a = arrays(U)
    lib = _PardisoLibrary()
    if order is not None:
        lib.use_order(np.ascontiguousarray(order, dtype=np.int32))
    else:
        lib.use_ordering(ordering)
    t0 = time.perf_counter()
    lib.call(11, a, np.zeros((a[3], 1)))
    t1 = time.perf_counter()
    lib.call(22, a, np.zeros((a[3], 1)))
    t2 = time.perf_counter()
    fill = lib.factor_nonzeros()
    E = np.zeros((a[3], T.size), order="F")
    E[T, np.arange(T.size)] = 1.0
    t3 = time.perf_counter()
    lib.call(33, a, E)  # (A^-1)_{:,T}: what the Delassus operator needs without a Schur complement
    t4 = time.perf_counter()
    lib.release()
    return 1e3 * (t1 - t0), 1e3 * (t2 - t1), fill, 1e3 * (t4 - t3)


def schur(U, T):
    """(analysis ms, numeric ms, factor nonzeros) of the factorisation with T last (its Schur complement
    too): a new analysis (phase 12) less a reused one (phase 22), and the reused one."""
    h = PardisoSchur(solves=True)
    t0 = time.perf_counter()
    h.complement(U, T, upper=True)
    t1 = time.perf_counter()
    h.complement(U, T, upper=True)
    t2 = time.perf_counter()
    fill = h.factor_nonzeros
    h._release()
    return 1e3 * (t1 - t0 - (t2 - t1)), 1e3 * (t2 - t1), fill, 0.0


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("mesh_dir", nargs="?", default=os.environ.get("MESH_DIR"))
    ap.add_argument("--scene", default="wheel")
    ap.add_argument("--frame", type=int, default=130)
    ap.add_argument("--cells", type=int, default=4)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--matrices", default=None, metavar="NPZ",
                    help="keep the captured matrices in this file, and read them from it when it exists")
    args = ap.parse_args()
    if args.matrices and os.path.exists(args.matrices):
        with np.load(args.matrices) as f:
            A, Ar = (sp.csr_matrix((f[k + ".data"], f[k + ".indices"], f[k + ".indptr"])) for k in ("A", "Ar"))
            order = f["order"] if f["order"].size else None
            T, Tr = f["T"], f["Tr"]
    else:
        A, Ar, order, T, Tr = capture(args.mesh_dir, args.scene, args.frame, args.cells)
        if args.matrices:
            np.savez(args.matrices, **{f"{k}.{a}": getattr(M, a) for k, M in (("A", A), ("Ar", Ar))
                                       for a in ("data", "indices", "indptr")},
                     order=np.zeros(0, np.int32) if order is None else order, T=T, Tr=Tr)
    runs = {"full, metis": (A, lambda: plain(A, "metis", T=T)),
            "reduced, given": (Ar, None if order is None else lambda: plain(Ar, None, order, Tr)),
            "reduced, metis": (Ar, lambda: plain(Ar, "metis", T=Tr)),
            "reduced, md": (Ar, lambda: plain(Ar, "md", T=Tr)),
            "full, schur": (A, lambda: schur(A, T)),
            "reduced, schur": (Ar, lambda: schur(Ar, Tr))}
    times = {name: [] for name in runs}
    for _ in range(args.repeat):  # the ways in turn, so that a change of the machine's load hits them alike
        for name, (_, run) in runs.items():
            if run is not None:
                times[name].append(run())
    rows = [(name, M.shape[0], None if not times[name] else
             (*np.median(np.array(times[name])[:, [0, 1, 3]], axis=0), times[name][0][2]))
            for name, (M, _) in runs.items()]
    print(f"{args.scene} frame {args.frame}: A {A.shape[0]} unknowns ({A.nnz} upper entries), "
          f"A_r {Ar.shape[0]} ({Ar.nnz}), touched {T.size} / {Tr.size}")
    print("| factorisation | unknowns | analysis ms | numeric ms | factor nonzeros | touched columns solved, ms |")
    print("|---|---|---|---|---|---|")
    for name, n, r in rows:
        if r is None:
            print(f"| {name} | {n} | - | - | - | - |")
        else:
            print(f"| {name} | {n} | {r[0]:.1f} | {r[1]:.1f} | {r[3]} | {r[2]:.1f} |")


if __name__ == "__main__":
    main()
