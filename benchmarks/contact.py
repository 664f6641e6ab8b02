"""Contact scenes: full vs affinification vs rigidification, in one process (paper Table 1 "Pills").

For each scene and resolution, steps the full solve and both methods frame by frame in turn
(interleaved, so that load from elsewhere on a shared machine hits all alike), the same frames
with the same solver, and prints: wall time, speedup over full, mean contacts per frame, mean PGS sweeps,
the contact share of the step (detection + Delassus operator + PGS + velocity
correction, ``rec["contact"] / rec["wall"]``), the DOFs solved relative to full
space, and the largest centre-of-mass distance to the full run relative to the
scene's size. Usage::

    python benchmarks/contact.py --scenes drop pills --frames 150
"""
import argparse
import json
import os
import sys

# BLAS/MKL threads, set before numpy loads them (default 1: on a shared machine spinning threads
# made small solves 10-100x slower; the same setting holds for every method of a run)
THREADS = sys.argv[sys.argv.index("--threads") + 1] if "--threads" in sys.argv else "1"
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, THREADS)

import numpy as np  # noqa: E402

# measure the checkout this script sits in, not whatever skfem_affine is installed
sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
import skfem_affine as sa  # noqa: E402
from skfem_affine.lab import runners  # noqa: E402


DEFAULT_RESOLUTIONS = {"drop": [2, 3], "pills": [1, 2]}


def run_interleaved(scene, k, frames, solver, reducers):
    """Step every method frame by frame, in turn, in one process (``runners.interleaved``).

    ``reducers`` maps a method's name to its reducer (None: full space, the first). Returns the
    full simulation and a result dict per method; ``com_err`` is the largest centre-of-mass
    coordinate distance to the full run at the same frame, relative to the scene's size.
    """
    sims = {name: sa.scenes.SCENES[scene](resolution=k, solver=solver, reducer=red) for name, red in reducers.items()}
    first = next(iter(sims))
    m = sims[first].system.lumped_mass
    errs = dict.fromkeys(sims, 0.0)

    def com_error(frame, running):
        if first in running:
            ref = m @ running[first].state.x / m.sum()
            for name, sim in running.items():
                errs[name] = max(errs[name], np.abs(m @ sim.state.x / m.sum() - ref).max())

    runs = runners.interleaved(sims, frames, on_frame=com_error)
    out = {}
    for name, run in runs.items():
        sim, st = run.sim, run.sim.stats
        out[name] = {"wall": run.summary["wall_s"], "dofs": st.total("dofs"), "contacts": st.mean("n_contacts"),
                     "sweeps": st.mean("pgs_iterations"),
                     "contact_share": st.total("contact") / max(st.total("wall"), 1e-300),
                     "com_err": errs[name] / sim.size,
                     "reduced": float(np.mean([r.get("reduced_fraction", 0.0) for r in st])),
                     "phases": st.phase_totals()}
    return sims[first], out


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scenes", nargs="+", default=["drop", "pills"])
    p.add_argument("--resolutions", type=int, nargs="+", default=None,
                   help="default: 2 3 for drop (512, 4096 tets), 1 2 for pills (768, 6912 tets)")
    p.add_argument("--frames", type=int, default=150)
    p.add_argument("--tau", default="0.5,1.0", help="affinification tau_a,tau_e")
    p.add_argument("--tau-r", type=float, default=1e-2, help="rigidification tau_r (tau_e = 2 tau_r)")
    p.add_argument("--solver", default="pardiso" if sa.solvers.has_pardiso() else "superlu")
    p.add_argument("--threads", default="1", help="BLAS/MKL threads (read before numpy is imported)")
    p.add_argument("--json", default="benchmarks/results/contact.json")
    args = p.parse_args(argv)
    tau_a, tau_e = map(float, args.tau.split(","))
    # warm-up: numba kernels and thread-pool discovery load once per process, outside the table
    runners.interleaved({i: sa.scenes.stacked_beams(resolution=1, reducer=red, solver=args.solver)
                         for i, red in enumerate((None, sa.Affinification(1e-4, 2e-4), sa.Rigidification(1e-3, 2e-3)))}, 5)
    rows = []
    print(f"{'scene':>7} {'tets':>6} {'method':>15} {'wall_s':>8} {'speedup':>7} {'contacts':>8} {'sweeps':>6} "
          f"{'PGS%':>5} {'dof_ratio':>9} {'reduced':>7} {'com_err':>8}", flush=True)
    for scene in args.scenes:
        for k in args.resolutions or DEFAULT_RESOLUTIONS.get(scene, [1, 2]):
            reducers = {"full": None, f"affine {tau_a:g}/{tau_e:g}": sa.Affinification(tau_a=tau_a, tau_e=tau_e),
                        f"rigid {args.tau_r:g}": sa.Rigidification(tau_r=args.tau_r, tau_e=2 * args.tau_r)}
            sim, results = run_interleaved(scene, k, args.frames, args.solver, reducers)
            full = results["full"]
            for name, res in results.items():
                row = {"scene": scene, "tets": sim.system.m, "resolution": k, "method": name, "frames": args.frames,
                       **res, "speedup": full["wall"] / res["wall"], "dof_ratio": res["dofs"] / full["dofs"]}
                rows.append(row)
                print(f"{scene:>7} {row['tets']:6d} {name:>15} {res['wall']:8.2f} {row['speedup']:7.2f} "
                      f"{res['contacts']:8.1f} {res['sweeps']:6.1f} {100 * res['contact_share']:5.1f} "
                      f"{row['dof_ratio']:9.3f} {res['reduced']:7.2f} {res['com_err']:8.1e}", flush=True)
    if args.json:
        os.makedirs(os.path.dirname(args.json) or ".", exist_ok=True)
        with open(args.json, "w") as fh:
            json.dump(rows, fh, indent=1)


if __name__ == "__main__":
    main()
