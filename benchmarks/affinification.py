"""Full vs affinification vs rigidification in one process (paper Table 1-2).

Two scenes: our procedural cantilever (``--resolutions``: 24 k^3 tets, rho = 1000,
no damping) and the paper's own beam meshes (``--meshes``, MEDIT files from
``MESH_DIR`` (docs/bodies.md says where to get them): long axis z, the z-min end pinned and kept elastic as in the
paper's Fig. 17, gravity -9.8 along y, density 100, Rayleigh alpha = 0.03 (mass),
beta = 0.02 (stiffness), the values of the rigidification code the paper was built
on). For each scene and material, steps the full solve and every method frame by frame
in turn (interleaved, so that load from elsewhere on a shared machine hits all
alike) with the same solver, and prints: wall time, speedup over full, max vertex error relative to the scene's
size, DOF ratio (DOFs solved summed over frames / full), mean clusters, the share
of the step spent in prediction + clustering + map assembly (the oracle overhead;
the paper's goal is under 15 %), and the mean milliseconds per frame of each phase.
Usage::

    python benchmarks/affinification.py --resolutions 6 10 --frames 370 \\
        --materials neohookean stvk corotational --taus 1e-4,2e-4 0.1,0.2
    python benchmarks/affinification.py --resolutions --meshes MESH_DIR/beam1264.mesh \\
        --taus 1e-4,2e-4
"""
import argparse
import json
import os
import sys

import numpy as np

# measure the checkout this script sits in, not whatever skfem_affine is installed
# (``python benchmarks/x.py`` puts benchmarks/, not the working directory, on sys.path)
sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
import skfem_affine as sa  # noqa: E402
from skfem_affine.lab import runners  # noqa: E402

MATERIALS = {"neohookean": sa.NeoHookean, "stvk": sa.StVK, "corotational": sa.Corotational}
PHASES = ("assembly", "prediction", "clustering", "map_assembly", "reduced_assembly", "factorization", "solve")


def paper_beam(path, material, **sim_kw):
    """The paper's beam scene on a MEDIT mesh: z-min end pinned, gravity along -y."""
    mesh = sa.io.load_mesh(path)
    z = mesh.p[2]
    fixed = np.flatnonzero(z < z.min() + 1e-6 * np.ptp(z))
    body = sa.ElasticBody(mesh, material=material, density=100.0, fixed=fixed)
    return sa.Simulation(body, dt=0.01, gravity=(0.0, -9.8, 0.0), damping=sa.Rayleigh(alpha=0.03, beta=0.02),
                         **sim_kw)


def make_scene(scene, material, solver, reducer):
    mat = MATERIALS[material](E=1e5, nu=0.35)
    if isinstance(scene, int):
        return sa.scenes.cantilever(resolution=scene, material=mat, solver=solver, reducer=reducer, damping=None)
    return paper_beam(scene, mat, solver=solver, reducer=reducer)


def run_interleaved(scene, material, frames, solver, reducers):
    """Step the full solve and every reducer frame by frame, in turn, in one process (``runners.interleaved``).

    Interleaving makes the ratios robust on a shared machine: a burst of load from
    elsewhere slows every method's frame alike. Returns the full simulation and one
    result dict per method (``None`` = full).
    """
    sims = {i: make_scene(scene, material, solver, red) for i, red in enumerate([None] + list(reducers))}
    errs = dict.fromkeys(sims, 0.0)

    def error(frame, running):  # largest coordinate distance to the full solve at the same frame
        if 0 in running:
            for i, sim in running.items():
                errs[i] = max(errs[i], np.abs(sim.state.x - running[0].state.x).max())

    runs = runners.interleaved(sims, frames, on_frame=error)
    out = []
    for i, run in runs.items():
        st = run.sim.stats
        oracle = sum(st.total(p) for p in ("prediction", "clustering", "map_assembly"))
        out.append({"wall": run.summary["wall_s"], "dofs": st.total("dofs"), "err": float(errs[i] / run.sim.size),
                    "clusters": float(np.mean([r.get("n_clusters", 0) for r in st])),
                    "oracle_share": oracle / max(st.total("wall"), 1e-300),
                    "ms_per_frame": {p: 1e3 * st.mean(p) for p in PHASES}})
    return sims[0], out


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--resolutions", type=int, nargs="*", default=[6, 10])
    p.add_argument("--meshes", nargs="*", default=[], help="MEDIT beam meshes (the paper's beam scene)")
    p.add_argument("--frames", type=int, default=370)
    p.add_argument("--materials", nargs="+", default=list(MATERIALS), choices=list(MATERIALS))
    p.add_argument("--taus", nargs="*", default=["1e-4,2e-4", "0.1,0.2"], help="tau_a,tau_e pairs")
    p.add_argument("--tau-r", type=float, nargs="*", default=[1e-3], help="rigidification tau_r (tau_e = 2 tau_r)")
    p.add_argument("--seeding", default="random", choices=["random", "index", "temporal"])
    p.add_argument("--min-body-elements", type=int, nargs="+", default=[2],
                   help="affine bodies with fewer elements are dissolved (2: singletons, as the paper)")
    p.add_argument("--solver", default="pardiso" if sa.solvers.has_pardiso() else "superlu")
    p.add_argument("--phases", action="store_true", help="also print ms per frame of each phase")
    p.add_argument("--json", default="benchmarks/results/affinification.json")
    args = p.parse_args(argv)
    rows = []
    print(f"{'tets':>7} {'scene':>10} {'material':>12} {'method':>22} {'wall_s':>8} {'speedup':>7} {'err':>8} "
          f"{'dof_ratio':>9} {'clusters':>8} {'oracle%':>7}", flush=True)
    scenes = list(args.resolutions) + list(args.meshes)
    # compile (or load from numba's cache) every kernel before any timing
    run_interleaved(2, "neohookean", 3, args.solver, [sa.Affinification(0.1, 0.2), sa.Rigidification(1.0, 2.0)])
    for scene in scenes:
        label = f"k={scene}" if isinstance(scene, int) else os.path.splitext(os.path.basename(scene))[0]
        for mat in args.materials:
            affine = [(t, k) for t in args.taus for k in args.min_body_elements]
            names = ["full"] + [f"affine {t}" + (f" min{k}" if k != 2 else "") for t, k in affine]
            names += [f"rigid {t:g}" for t in args.tau_r]
            reducers = [sa.Affinification(*map(float, t.split(",")), seeding=args.seeding, min_body_elements=k)
                        for t, k in affine]
            reducers += [sa.Rigidification(tau_r=t, tau_e=2 * t) for t in args.tau_r]
            sim, results = run_interleaved(scene, mat, args.frames, args.solver, reducers)
            full = results[0]
            for name, res in zip(names, results):
                row = {"tets": sim.system.m, "scene": label, "material": mat, "method": name, "frames": args.frames,
                       **res, "speedup": full["wall"] / res["wall"], "dof_ratio": res["dofs"] / full["dofs"]}
                rows.append(row)
                print(f"{row['tets']:7d} {label:>10} {mat:>12} {name:>22} {res['wall']:8.2f} {row['speedup']:7.2f} "
                      f"{res['err']:8.1e} {row['dof_ratio']:9.3f} {res['clusters']:8.1f} "
                      f"{100 * res['oracle_share']:7.1f}", flush=True)
                if args.phases:
                    print(" " * 8 + " ".join(f"{k}={v:.1f}" for k, v in res["ms_per_frame"].items()), flush=True)
    if args.json:
        os.makedirs(os.path.dirname(args.json) or ".", exist_ok=True)
        with open(args.json, "w") as fh:
            json.dump(rows, fh, indent=1)


if __name__ == "__main__":
    main()
