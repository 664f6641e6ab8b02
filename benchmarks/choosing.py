"""When to use which method: the adaptive subspace and affinification on the same scenes.

Each method is measured against its own full-space run, with the same integrator and contact
model, stepped frame by frame in turn in one process (:func:`skfem_affine.lab.runs.interleaved`):

* ``AdaptiveSubspace`` at each ``--eps`` (eps_nodal = eps_modal) against full-space Newton
  (implicit Euler, IPC contact, direct solver);
* ``Affinification`` at each ``--taus`` against the full-space linearized integrator (PGS contact).

Scenes (``benchmarks/subspace_paper.py``'s boxes of ``--cells`` cells per side, and the beam):
``drop`` (soft, E = 1e5), ``stiff`` (the same drop at E = 1e7), ``stack`` (three boxes, friction),
``hetero`` (two materials), ``ramp`` (Fig. 5's slide), ``beam`` (the cantilever, E = 1e5, no
contact, large deformation; ``--cells`` cells across).

Per run: speedup (total wall of the full run over the method's), max vertex distance error
(largest vertex distance to the full run at the same frame, over the frames, relative to the
scene size), the mean enriched fraction (subspace) or elastic DOF ratio (affinification). The
trade picture (:func:`skfem_affine.lab.plots.trade_plot`) is written beside the JSON.

Usage::

    python benchmarks/choosing.py --cells 6 --frames 20
    python benchmarks/choosing.py --scenes drop stiff beam --cells 10 --frames 30 --eps 0.02 0.1 0.5
"""
import argparse
import json
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import skfem_affine as sa  # noqa: E402
from skfem_affine.lab import plots, runs  # noqa: E402
import subspace_paper  # noqa: E402

SCENES = ("drop", "stiff", "stack", "hetero", "ramp", "beam")


def build(kind, cells, reducer=None, linearized=False, solver="auto"):
    """The scene ``kind`` for the Newton family (IPC) or, ``linearized=True``, the linearized one (PGS)."""
    if kind == "beam":
        kw = dict(integrator="linearized") if linearized else dict(integrator="implicit_euler", newton_tol=1e-3)
        return sa.scenes.cantilever(resolution=cells, E=1e5, damping=None, reducer=reducer, solver=solver, **kw)
    base = {"stiff": "drop"}.get(kind, kind)
    E = 1e7 if kind == "stiff" else 1e5
    return subspace_paper.scene(base, cells, reducer=reducer, solver=solver, linearized=linearized, E=E)


def family(sims, frames):
    """Interleave ``sims`` (the full run first); speedup, max error and mean statistics of each other run."""
    names = list(sims)
    full = sims[names[0]]
    err = dict.fromkeys(names, 0.0)

    def on_frame(frame, running):
        if names[0] in running:
            for name, sim in running.items():
                d = np.linalg.norm(sim.state.x - running[names[0]].state.x, axis=1).max()
                err[name] = max(err[name], d / full.size)

    result = runs.interleaved(sims, frames, on_frame=on_frame)
    wall_full = sum(r["wall"] for r in result[names[0]].records)
    out = {}
    for name in names[1:]:
        rec = result[name].records
        n = min(len(rec), len(result[names[0]].records))
        wall = sum(r["wall"] for r in rec)
        out[name] = {"speedup": wall_full / max(wall, 1e-12) if n == frames else None,
                     "wall_s": wall, "wall_full_s": wall_full,
                     "error": err[name], "frames": n, "status": result[name].summary["status"],
                     "enriched": float(np.mean([r.get("enriched_ratio", 0.0) for r in rec])) if rec else None,
                     "reduced_steps": float(np.mean([r.get("reduced", True) for r in rec])) if rec else None,
                     "dofs": float(np.mean([r.get("dofs", 0) for r in rec])) if rec else None,
                     "dofs_full": float(np.mean([r.get("dofs", 0) for r in result[names[0]].records]))}
    return out


def run_scene(kind, args):
    rows = []
    sims = {"full Newton": build(kind, args.cells, solver=args.solver)}
    for eps in args.eps:
        red = sa.AdaptiveSubspace(basis=sa.SkinningEigenmodes(n=args.modes), eps_nodal=eps, eps_modal=eps,
                                  subdomains=args.subdomains)
        sims[f"subspace eps={eps:g}"] = build(kind, args.cells, reducer=red)
    for name, r in family(sims, args.frames).items():
        rows.append({"scene": kind, "method": "adaptive subspace", "setting": name, **r})
    sims = {"full linearized": build(kind, args.cells, linearized=True, solver=args.solver)}
    for taus in args.taus:
        ta, te = map(float, taus.split(","))
        sims[f"affinification {taus}"] = build(kind, args.cells, reducer=sa.Affinification(tau_a=ta, tau_e=te),
                                               linearized=True, solver=args.solver)
    for name, r in family(sims, args.frames).items():
        rows.append({"scene": kind, "method": "affinification", "setting": name, **r})
    tets = int(sims["full linearized"].system.m)
    for r in rows:
        r["tets"] = tets
    return rows


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scenes", nargs="+", choices=SCENES, default=list(SCENES))
    p.add_argument("--cells", type=int, default=6)
    p.add_argument("--frames", type=int, default=20)
    p.add_argument("--eps", type=float, nargs="+", default=[0.02, 0.1, 0.5])
    p.add_argument("--taus", nargs="+", default=["0.1,0.3", "0.3,0.6"], help="affinification tau_a,tau_e pairs")
    p.add_argument("--modes", type=int, default=16)
    p.add_argument("--subdomains", type=int, default=50)
    p.add_argument("--solver", default="pardiso" if sa.solvers.has_pardiso() else "superlu")
    p.add_argument("--json", default="benchmarks/results/choosing.json")
    p.add_argument("--picture", default=None, help="default: the JSON's name with .png")
    args = p.parse_args(argv)
    rows = []
    print(f"{'scene':>7} {'tets':>6} {'setting':>26} {'wall s':>7} {'full s':>7} {'speedup':>7} {'max err':>8} "
          f"{'enriched':>8} {'reduced':>7} {'dofs':>7} {'status':>8}", flush=True)
    for kind in args.scenes:
        for r in run_scene(kind, args):
            rows.append(r)
            sp = "-" if r["speedup"] is None else f"{r['speedup']:.2f}"
            print(f"{r['scene']:>7} {r['tets']:>6} {r['setting']:>26} {r['wall_s']:>7.2f} {r['wall_full_s']:>7.2f} "
                  f"{sp:>7} {r['error']:>8.1e} "
                  f"{(r['enriched'] or 0):>8.3f} {(r['reduced_steps'] or 0):>7.2f} {(r['dofs'] or 0):>7.0f} "
                  f"{r['status']:>8}", flush=True)
    if args.json:
        os.makedirs(os.path.dirname(os.path.abspath(args.json)), exist_ok=True)
        with open(args.json, "w") as fh:
            json.dump({"args": vars(args), "rows": rows}, fh, indent=1, default=float)
        picture = args.picture or os.path.splitext(args.json)[0] + ".png"
        plots.trade_plot([dict(r, label=r["setting"]) for r in rows if r["speedup"] is not None], picture,
                            title=f"adaptive subspace vs affinification ({args.frames} frames)")
    return rows


if __name__ == "__main__":
    main()
