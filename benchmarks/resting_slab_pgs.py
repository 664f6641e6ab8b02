"""PGS on one affine body with a few hundred warm-started contacts: a slab resting on the ground.

A soft slab (``--cells`` x ``--cells`` x 1 cells, 0.4 x 0.4 x 0.05 m, its whole bottom face on a
plane: (cells + 1)^2 contacts) under the default ``Affinification()`` runs ``--frames`` frames on
one thread; the last frame's W, velocities and warm start are kept, and the block PGS solve
(``PGS(solver="block")``) and its parts are timed on them (CPU ms, mean of ``--repeat``): the
grouping (``contact_groups``: the coupled pairs, their sort strongest first, the capped join) and
the whole solve.

Usage (from the checkout)::

    python -m benchmarks.resting_slab_pgs --cells 17 --frames 70
"""
import argparse
import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import time  # noqa: E402

import numpy as np  # noqa: E402

import skfem_affine as sa  # noqa: E402
from skfem_affine.contact import pgs  # noqa: E402
from skfem_affine.lab.scenes import box_mesh  # noqa: E402


def timed(repeat, fn, *args):
    fn(*args)  # compiled and warm
    t0 = time.process_time()
    for _ in range(repeat):
        out = fn(*args)
    return 1e3 * (time.process_time() - t0) / repeat, out


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--cells", type=int, default=17)
    p.add_argument("--frames", type=int, default=70)
    p.add_argument("--repeat", type=int, default=10)
    args = p.parse_args(argv)
    kept = {}
    solve = pgs.SOLVERS["block"]

    def keep(W, u0, lam, *rest):
        kept.update(W=W.copy(), u0=u0.copy(), lam=lam.copy(), rest=rest)
        return solve(W, u0, lam, *rest)

    pgs.SOLVERS["block"] = keep
    slab = sa.ElasticBody(box_mesh((0.4, 0.4, 0.05), (args.cells, args.cells, 1), (0.0, 0.0, 0.025)),
                          sa.NeoHookean(E=1e6, nu=0.3), density=1000.0)
    sim = sa.Simulation([slab], dt=0.01, gravity=(0.0, 0.0, -9.81), colliders=[sa.Plane()],
                        reducer=sa.Affinification())
    try:
        for _ in range(args.frames):
            sim.step()
    finally:
        pgs.SOLVERS["block"] = solve
    rec, W = sim.stats[-1], kept["W"]
    k = W.shape[0] // 3
    pair_ms, (pairs, values) = timed(args.repeat, pgs._coupled_pairs, W, pgs.COUPLING)
    sort_ms, order = timed(args.repeat, pgs._strongest_first, values)
    join_ms, _ = timed(args.repeat, pgs._joined, pairs, order, k, pgs.GROUP)
    group_ms, (ptr, _) = timed(args.repeat, pgs.contact_groups, W)
    solve_ms, sweeps = timed(args.repeat, lambda: solve(W, kept["u0"], kept["lam"].copy(), *kept["rest"]))
    print(f"frame {rec['frame']}: {k} contacts, {rec['dofs']} unknowns solved, reduced {rec.get('reduced')}, "
          f"{sweeps} sweep(s)")
    print(f"block PGS solve {solve_ms:.2f} ms CPU, of it grouping {group_ms:.2f} ms: coupled pairs {pair_ms:.2f} "
          f"({values.size} pairs), sorted strongest first {sort_ms:.2f}, joined under the cap {join_ms:.2f}; "
          f"{ptr.size - 1} groups")


if __name__ == "__main__":
    main()
