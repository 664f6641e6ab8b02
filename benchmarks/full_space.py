"""Full-space benchmark: per-frame phase times for each solver on cantilever beams.

For beams of about 1k, 5k, 20k and 100k tets this measures, in one process:

* ``asm_skfem``: scikit-fem's ``asm(linear_elasticity(...))`` on the same mesh
  (default quadrature), the yardstick for assembly cost;
* ``assembly``: our per-frame Neo-Hookean forces + tangent (PSD-projected) + A, b;
* ``factorization`` and ``solve`` for each available solver, every solver stepped
  frame by frame in turn from the same bent state (the Pardiso numeric
  factorization reuses the symbolic analysis, as in a simulation; ``fresh``
  is one analysis + factorization + solve from scratch);
* ``frame``: the whole step.

Ratios printed: assembly / asm_skfem (target <= 0.25) and frame / (factorization +
solve) of the fastest solver (target <= 2). Usage::

    python benchmarks/full_space.py [--sizes 4 6 10 16] [--frames 10] [--json out.json]
"""
import argparse
import json
import os
import sys
import time

import skfem
from skfem.models.elasticity import lame_parameters, linear_elasticity

# measure the checkout this script sits in, not whatever skfem_affine is installed
sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
import skfem_affine as sa  # noqa: E402
from skfem_affine.lab import runners  # noqa: E402


def timed(fn, repeat=1):
    t = time.perf_counter()
    for _ in range(repeat):
        out = fn()
    return (time.perf_counter() - t) / repeat, out


def bench_size(k, frames, solvers):
    row = {"resolution": k}
    sim = sa.scenes.cantilever(resolution=k, solver="superlu", E=1e5, damping=None)
    row.update(tets=sim.system.m, vertices=sim.system.n, dofs=int(sim.system.free.size))
    mesh = sim.bodies[0].mesh
    basis = skfem.Basis(mesh, skfem.ElementVector(skfem.ElementTetP1()))
    row["asm_skfem"], _ = timed(lambda: skfem.asm(linear_elasticity(*lame_parameters(1e5, 0.35)), basis))
    # bend the beam so that the tangent is not the rest one
    warm = sa.scenes.cantilever(resolution=k, solver="amg", E=1e5, damping=None)
    runners.interleaved({"amg": warm}, 20)
    x, v = warm.state.x, warm.state.v
    row["assembly"], (A, b, _) = timed(lambda: warm.linear_system(x, v), repeat=3)
    row["solvers"], fresh, sims = {}, {}, {}
    for name in solvers:
        if name == "superlu" and row["dofs"] > 60000:
            continue  # minutes per frame: not worth measuring
        solver = sa.solvers.make_solver(name)
        fresh[name], _ = timed(lambda: (solver.factorize(A), solver.solve(b)))
        sims[name] = sa.scenes.cantilever(resolution=k, solver=name, E=1e5, damping=None)
        sims[name].state = warm.state.copy()
    # every solver from the same bent state, frame by frame in turn (load from elsewhere hits all alike)
    for name, run in runners.interleaved(sims, frames).items():
        st = run.sim.stats
        row["solvers"][name] = {"fresh_factorize_solve": fresh[name],
                                "assembly": st.mean("assembly"), "factorization": st.mean("factorization"),
                                "solve": st.mean("solve"), "frame": st.mean("wall"),
                                "iterations": st.mean("iterations")}
    return row


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[4, 6, 10, 16],
                        help="beam resolutions k (24 k^3 tets; default 4 6 10 16 = 1.5k, 5k, 24k, 98k)")
    parser.add_argument("--frames", type=int, default=10)
    parser.add_argument("--json", default="benchmarks/results/full_space.json")
    args = parser.parse_args(argv)
    solvers = ["superlu", "amg"] + (["pardiso"] if sa.solvers.has_pardiso() else [])
    rows = []
    print(f"{'tets':>7} {'solver':>8} {'asm_skfem':>9} {'assembly':>8} {'ratio':>6} {'fact':>7} {'solve':>7} "
          f"{'frame':>7} {'fresh':>7} {'frame/(f+s)':>11} {'it':>4}")
    for k in args.sizes:
        row = bench_size(k, args.frames, solvers)
        rows.append(row)
        best = min(s["factorization"] + s["solve"] for s in row["solvers"].values())
        row["assembly_ratio"] = row["assembly"] / row["asm_skfem"]
        row["best_factorize_solve"] = best
        for name, s in row["solvers"].items():
            print(f"{row['tets']:7d} {name:>8} {row['asm_skfem']:9.4f} {row['assembly']:8.4f} "
                  f"{row['assembly_ratio']:6.2f} {s['factorization']:7.4f} {s['solve']:7.4f} {s['frame']:7.4f} "
                  f"{s['fresh_factorize_solve']:7.4f} {s['frame'] / best:11.2f} {s['iterations']:4.0f}", flush=True)
    if args.json:
        os.makedirs(os.path.dirname(args.json) or ".", exist_ok=True)
        with open(args.json, "w") as fh:
            json.dump(rows, fh, indent=1)
        print("wrote", args.json)


if __name__ == "__main__":
    main()
