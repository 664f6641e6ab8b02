"""Adaptive subspace vs full-space Newton vs affinification on the cantilever (paper Tables 1 and 3).

For each resolution, in one process:

1. end to end: the same frames with the full-space Newton integrator (implicit Euler, direct
   solver), with ``AdaptiveSubspace`` at each error threshold, and with affinification (its
   linearized integrator), stepped frame by frame in turn (interleaved, so that load from
   elsewhere on a shared machine hits all alike); wall time, speedup over full Newton, max vertex error relative to the
   beam size, mean enriched-node ratio, active modes, Newton and PCG iterations;
2. linear solve (Table 3): at the first Newton iterate of the frame after the run, the coupled
   system (eq. 19) solved by the Schur complement against the full-space Newton system at the same
   iterate solved by the direct solver (factorization + solve) and by 3 x 3 block-Jacobi CG, both
   iterative solves to relative residual 1e-5; nonzeros of each system.

Usage::

    python benchmarks/subspace.py --resolutions 10 16 --frames 20 4 --eps 2e-3 0.5
    python benchmarks/subspace.py --scene drop --resolutions 16 26 --frames 15 3

The drop scene is a soft cube falling at 2 m/s on a plane: an IPC barrier for the Newton
integrators, PGS contact for affinification (its linearized integrator).
"""
import argparse
import json
import os
import sys
import time
import types

import numpy as np

# measure the checkout this script sits in, not whatever skfem_affine is installed
sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
import skfem_affine as sa  # noqa: E402
from skfem_affine.contact.barrier import barrier_of  # noqa: E402
from skfem_affine.integrators.potential import IncrementalPotential  # noqa: E402
from skfem_affine.lab import runners  # noqa: E402
from skfem_affine.reducers.subspace import linalg  # noqa: E402


def scene(k, kind="cantilever", **kw):
    """The cantilever (24 k^3 tets), or a soft cube (6 k^3 tets) dropped at 2 m/s on a plane."""
    material = sa.NeoHookean(E=1e5, nu=0.35)
    if kind == "cantilever":
        return sa.scenes.cantilever(resolution=k, material=material, damping=None, **kw)
    # the plane enters the Newton integrators as an IPC barrier, the linearized one (affinification) as PGS contact
    return sa.scenes.free_body(resolution=k, velocity=(0, 0, -2.0), spin=(0, 0, 0), gravity=(0, 0, -9.81),
                               material=material, colliders=[sa.Plane(point=(0, 0, -0.52), normal=(0, 0, 1))], **kw)


def run_interleaved(sims, frames):
    """Step every simulation frame by frame, in turn, in one process (``runners.interleaved``).

    ``sims`` maps a method's name to its simulation, the full-space Newton run first; ``err``
    is the largest vertex coordinate distance to it at the same frame, relative to the size.
    """
    first = next(iter(sims))
    errs = dict.fromkeys(sims, 0.0)

    def error(frame, running):
        if first in running:
            for name, sim in running.items():
                errs[name] = max(errs[name], np.abs(sim.state.x - running[first].state.x).max())

    out = {}
    for name, run in runners.interleaved(sims, frames, on_frame=error).items():
        st = run.sim.stats

        def mean(key):
            return float(np.mean([r.get(key, 0) for r in st]))

        out[name] = {"wall": run.summary["wall_s"], "err": errs[name] / run.sim.size,
                     "enriched": mean("enriched_ratio"), "modes": mean("active_modes"), "newton": mean("newton_iters"), "pcg": mean("pcg_iters"),
                     "phases": st.phase_totals()}
    return out


def model_of(sim):
    """The run's fixed data (the attributes of a Model) read off a Simulation."""
    return types.SimpleNamespace(system=sim.system, dt=sim.dt, damping=sim.damping, gravity=sim.gravity,
                                 f_gravity=sim.f_gravity, project_hessian=sim.project_hessian, size=sim.size)


def linear_solves(sim, solver):
    """Times of the Schur solve of eq. 19 and of the full Newton system at the same iterate x_t."""
    model, s = model_of(sim), sim.state
    # one Newton iterate from x_t: the reducer's coupled system at the iterate of the full system
    ip = IncrementalPotential(model, s.x, s.v, barrier=barrier_of(model, sim.colliders), tol=1e-3, max_iters=1)
    A = ip.hessian(ip.start.H, ip.x_t)
    g = ip.gradient(ip.x_t, ip.start.f)
    direct = sa.solvers.make_solver(solver)
    t0 = time.perf_counter()
    direct.factorize(A)
    direct.solve(-g)
    t_direct = time.perf_counter() - t0
    t0 = time.perf_counter()
    _, it_cg = linalg.pcg(lambda p: A @ p, -g, linalg.block_jacobi(A), 1e-5, 20000)
    t_cg = time.perf_counter() - t0
    red = sim.reducer
    keep, red.fallback = red.fallback, None  # the coupled system itself, whatever the enrichment
    try:
        red.solve(ip)
    finally:
        red.fallback = keep
    Hq, C, Hx, gq, gx = red.last_system
    t0 = time.perf_counter()
    _, _, it_schur, _ = linalg.schur_solve(Hq, C, Hx, gq, gx, 1e-5, 20000)
    t_schur = time.perf_counter() - t0
    nnz_ours = Hq.size + 2 * C.size + Hx.nnz
    return {"schur_s": t_schur, "direct_s": t_direct, "bjcg_s": t_cg, "schur_iters": it_schur, "bjcg_iters": it_cg,
            "nnz_ours": int(nnz_ours), "nnz_full": int(A.nnz), "enriched_dofs": int(Hx.shape[0]),
            "modes": int(Hq.shape[0])}


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scene", choices=["cantilever", "drop"], default="cantilever",
                   help="drop: no affinification run (its contact lives in another module)")
    p.add_argument("--resolutions", type=int, nargs="+", default=[10, 16])
    p.add_argument("--frames", type=int, nargs="+", default=[20, 4], help="frames per resolution")
    p.add_argument("--eps", type=float, nargs="+", default=[2e-3, 0.5], help="eps_nodal = eps_modal values")
    p.add_argument("--modes", type=int, default=16, help="Skinning Eigenmodes weights")
    p.add_argument("--subdomains", type=int, default=200)
    p.add_argument("--tau", default="0.3,0.6", help="affinification tau_a,tau_e")
    p.add_argument("--solver", default="pardiso" if sa.solvers.has_pardiso() else "superlu")
    p.add_argument("--json", default="benchmarks/results/subspace.json")
    args = p.parse_args(argv)
    frames = dict(zip(args.resolutions, args.frames + [args.frames[-1]] * len(args.resolutions)))
    rows, solves = [], []
    print(f"{'tets':>7} {'method':>24} {'wall_s':>8} {'speedup':>7} {'err':>8} {'enriched':>8} {'modes':>6} "
          f"{'newton':>6} {'pcg':>6}", flush=True)
    for k in args.resolutions:
        n = frames[k]
        full = scene(k, args.scene, integrator="implicit_euler", newton_tol=1e-3, solver=args.solver)
        m = full.system.m
        sims, reducers = {"full Newton": full}, {}
        for eps in args.eps:
            red = sa.AdaptiveSubspace(basis=sa.SkinningEigenmodes(n=args.modes), eps_nodal=eps, eps_modal=eps,
                                      subdomains=args.subdomains)
            sims[f"subspace eps={eps:g}"] = scene(k, args.scene, integrator="implicit_euler", newton_tol=1e-3,
                                                  reducer=red)
            reducers[eps] = red
        ta, te = map(float, args.tau.split(","))
        sims[f"affinification {args.tau}"] = scene(k, args.scene, solver=args.solver,
                                                   reducer=sa.Affinification(tau_a=ta, tau_e=te))
        results = run_interleaved(sims, n)  # every method frame by frame in turn
        base = results["full Newton"]
        for eps, red in reducers.items():
            results[f"subspace eps={eps:g}"]["setup_s"] = red.setup_time
            sol = linear_solves(sims[f"subspace eps={eps:g}"], args.solver)
            sol.update(tets=m, eps=eps)
            solves.append(sol)
        methods = list(results.items())
        for name, r in methods:
            r.update(tets=m, method=name, frames=n, speedup=base["wall"] / r["wall"])
            rows.append(r)
            print(f"{m:>7} {name:>24} {r['wall']:>8.2f} {r['speedup']:>7.2f} {r['err']:>8.1e} {r['enriched']:>8.3f} "
                  f"{r['modes']:>6.0f} {r['newton']:>6.1f} {r['pcg']:>6.0f}", flush=True)
    print(f"\n{'tets':>7} {'eps':>6} {'schur_s':>8} {'direct_s':>8} {'bjcg_s':>8} {'direct/schur':>12} "
          f"{'bjcg/schur':>10} {'schur_it':>8} {'bjcg_it':>8} {'nnz ours':>9} {'nnz full':>9} {'enr dofs':>8}")
    for s in solves:
        print(f"{s['tets']:>7} {s['eps']:>6g} {s['schur_s']:>8.4f} {s['direct_s']:>8.4f} {s['bjcg_s']:>8.4f} "
              f"{s['direct_s'] / s['schur_s']:>12.1f} {s['bjcg_s'] / s['schur_s']:>10.1f} {s['schur_iters']:>8} "
              f"{s['bjcg_iters']:>8} {s['nnz_ours']:>9} {s['nnz_full']:>9} {s['enriched_dofs']:>8}")
    if args.json:
        os.makedirs(os.path.dirname(args.json), exist_ok=True)
        with open(args.json, "w") as fh:
            json.dump({"runs": rows, "linear_solves": solves}, fh, indent=1, default=float)


if __name__ == "__main__":
    main()
