"""What a superset of the touched unknowns costs the frame's Schur factorisation, against the analyses it
could save: a full-space run resumed from a checkpoint (``Simulation.save``) is stepped to ``--frame``
and on, its frames' matrices and touched unknowns T kept; then, on the first of them, one process, one MKL
thread, medians of the rounds, in multiples of the plain numeric factorisation (its analysis kept):

- the plain factorisation with a new analysis;
- the factorisation in Pardiso's Schur mode that also solves, with T last, with a new analysis and with a
  kept one (numeric), and Z = (A^-1)_TT from its complement (``inverse_on_positions``);
- the same with the union of T over the next 2, 3 and 5 frames last (the smallest sets that would serve
  those frames), Z still on T.

Usage::

    python benchmarks/schur_superset.py MESH_DIR --scene octopus --resume RUN.npz --frame 74
"""
import argparse
import os
import sys
import time

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"

import numpy as np  # noqa: E402
import scipy.sparse as sp  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))
sys.path.insert(0, HERE)


def frames(mesh_dir, scene, resume, first, count):
    """{frame: (A, T)} of ``count`` frames with contacts from ``first`` on, the run resumed from ``resume``."""
    import paper_table1
    from skfem_affine.reducers.full import touched_unknowns
    sim = paper_table1.SCENES[scene][2](mesh_dir, first + count + 1)(None)
    sim.load_state(resume)
    out, original = {}, sim.contact.resolve

    def resolve(problem, result, rec):
        cs = sim.contact.current
        if problem.frame >= first and cs is not None:
            out[problem.frame] = (sp.csr_matrix(result.operator.matrix), touched_unknowns(cs.J))
        return original(problem, result, rec)

    sim.contact.resolve = resolve
    while len(out) < count and len(sim.stats) < first + 4 * count:
        sim.step()
    return out


def timed(fn, reps=1):
    best, out = np.inf, None
    for _ in range(reps):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return best, out


def main(argv=None):
    from skfem_affine.contact.schur import inverse_on_positions
    from skfem_affine.solvers import Pardiso, PardisoSchur
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("mesh_dir")
    ap.add_argument("--scene", default="octopus")
    ap.add_argument("--resume", required=True, metavar="CHECKPOINT")
    ap.add_argument("--frame", type=int, required=True)
    ap.add_argument("--rounds", type=int, default=2)
    args = ap.parse_args(argv)
    got = frames(args.mesh_dir, args.scene, args.resume, args.frame, 5)
    first = min(got)
    A, T = got[first]
    Ts = [got[f][1] for f in sorted(got)]
    sets = [("T", T)] + [(f"union of {k} frames' T", np.unique(np.concatenate(Ts[:k]))) for k in (2, 3, 5)
                         if k <= len(Ts)]
    res = {}
    for _ in range(args.rounds):
        plain = Pardiso()
        res.setdefault("plain, new analysis", []).append(timed(lambda: plain.factorize(A))[0])
        res.setdefault("plain, numeric", []).append(timed(lambda: plain.factorize(A), 2)[0])
        for name, keep in sets:
            schur = PardisoSchur(solves=True)
            label = f"{name} ({keep.size})"
            res.setdefault(f"{label} last, new analysis", []).append(timed(lambda: schur.complement(A, keep))[0])
            t, S = timed(lambda: schur.complement(A, keep), 2)
            res.setdefault(f"{label} last, numeric", []).append(t)
            pos = np.searchsorted(keep, T)
            res.setdefault(f"{label}: Z on T", []).append(timed(lambda: inverse_on_positions(S.copy(), pos))[0])
            del schur
    unit = np.median(res["plain, numeric"])
    print(f"{args.scene} frame {first}: {T.size} touched of {A.shape[0]} unknowns; plain numeric factorisation "
          f"{1e3 * unit:.0f} ms; touched per frame {[t.size for t in Ts]}")
    print("| route | ms | plain factorisations |\n|---|---|---|")
    for k, v in res.items():
        print(f"| {k} | {1e3 * np.median(v):.0f} | {np.median(v) / unit:.2f} |")


if __name__ == "__main__":
    main()
