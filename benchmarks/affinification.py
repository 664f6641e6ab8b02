"""Full vs affinification vs rigidification on the cantilever, in one process (paper Table 1-2).

For each resolution and material, runs the same frames with the same solver and
prints: wall time, speedup over full, max vertex error relative to the beam's
size, DOF ratio (DOFs solved summed over frames / full), mean clusters, and the
share of the step spent in prediction + clustering + map assembly (the oracle
overhead; the paper's goal is under 15 %). Usage::

    python benchmarks/affinification.py --resolutions 6 10 --frames 370 \\
        --materials neohookean stvk corotational --taus 1e-4,2e-4 0.1,0.2
"""
import argparse
import json
import os
import time

import numpy as np

import skfem_affine as sa

MATERIALS = {"neohookean": sa.NeoHookean, "stvk": sa.StVK, "corotational": sa.Corotational}


def run(k, material, frames, solver, reducer=None, reference=None):
    sim = sa.scenes.cantilever(resolution=k, material=MATERIALS[material](E=1e5, nu=0.35), solver=solver,
                               reducer=reducer)
    t0 = time.perf_counter()
    xs, err = [], 0.0
    for i, s in enumerate(sim.run(frames)):
        if reference is None:
            xs.append(s.x)
        else:
            err = max(err, np.abs(s.x - reference[i]).max())
    wall = time.perf_counter() - t0
    st = sim.stats
    oracle = sum(st.total(p) for p in ("prediction", "clustering", "map_assembly"))
    return sim, {"wall": wall, "dofs": st.total("dofs"), "clusters": float(np.mean([r.get("n_clusters", 0) for r in st])),
                 "oracle_share": oracle / max(st.total("wall"), 1e-300), "err": err / sim.size,
                 "phases": st.phase_totals()}, xs


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--resolutions", type=int, nargs="+", default=[6, 10])
    p.add_argument("--frames", type=int, default=370)
    p.add_argument("--materials", nargs="+", default=list(MATERIALS), choices=list(MATERIALS))
    p.add_argument("--taus", nargs="+", default=["1e-4,2e-4", "0.1,0.2"], help="tau_a,tau_e pairs")
    p.add_argument("--tau-r", type=float, default=1e-3)
    p.add_argument("--solver", default="pardiso" if sa.solvers.has_pardiso() else "superlu")
    p.add_argument("--json", default="benchmarks/results/affinification.json")
    args = p.parse_args(argv)
    rows = []
    print(f"{'tets':>7} {'material':>12} {'method':>22} {'wall_s':>8} {'speedup':>7} {'err':>8} {'dof_ratio':>9} "
          f"{'clusters':>8} {'oracle%':>7}", flush=True)
    for k in args.resolutions:
        for mat in args.materials:
            sim, full, ref = run(k, mat, args.frames, args.solver)
            methods = [("full", None)]
            methods += [(f"affine {t}", tuple(map(float, t.split(",")))) for t in args.taus]
            methods += [(f"rigid {args.tau_r:g}", "rigid")]
            for name, spec in methods:
                if spec is None:
                    res = full
                else:
                    red = (sa.Rigidification(tau_r=args.tau_r, tau_e=2 * args.tau_r) if spec == "rigid"
                           else sa.Affinification(tau_a=spec[0], tau_e=spec[1]))
                    _, res, _ = run(k, mat, args.frames, args.solver, red, ref)
                row = {"tets": sim.system.m, "resolution": k, "material": mat, "method": name, **res,
                       "speedup": full["wall"] / res["wall"], "dof_ratio": res["dofs"] / full["dofs"]}
                rows.append(row)
                print(f"{row['tets']:7d} {mat:>12} {name:>22} {res['wall']:8.2f} {row['speedup']:7.2f} "
                      f"{res['err']:8.1e} {row['dof_ratio']:9.3f} {res['clusters']:8.1f} "
                      f"{100 * res['oracle_share']:7.1f}", flush=True)
    if args.json:
        os.makedirs(os.path.dirname(args.json) or ".", exist_ok=True)
        with open(args.json, "w") as fh:
            json.dump(rows, fh, indent=1)


if __name__ == "__main__":
    main()
