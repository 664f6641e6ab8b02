"""The error budget stated relative to the response, measured on three scenes (docs/budget.md).

For each scene and budget, affinification with ``target_error=b, relative_to="response"`` is
stepped frame by frame in turn with the full-space run; the table gives the achieved largest
vertex distance to the full-space run relative to the response R (the full-space run's largest
displacement from rest), relative to the scene size L and in metres, the reducer's largest
estimate, the largest element stress error, and the interleaved speedup. The budget holds when
the achieved response error is at most 1.25 budgets (the margin the tests allow).

Scenes: a clamped 0.2 x 0.2 x 1 m steel-like bar under a ramped tip load and gravity (``bar``),
the cantilever (``cantilever``), and the paper's beam (``paper_beam``, procedural, or a mesh
file of the paper's via ``--mesh``).

Usage::

    python benchmarks/budget_response.py                      # the docs/budget.md table
    python benchmarks/budget_response.py --tiny               # seconds: the script runs
"""
import argparse
import json
import os
import sys

import numpy as np
import skfem

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
import skfem_affine as sa  # noqa: E402
from skfem_affine.lab import metrics, runners  # noqa: E402

MARGIN = 1.25


def bar(resolution=2, reducer=None, load=2.0e4, ramp=0.2, E=2e9, frames=None):
    """A clamped 0.2 x 0.2 x 1 m bar (clamp at z = 0), a tip load ramped over ``ramp`` s, and gravity."""
    k = int(resolution)
    mesh = skfem.MeshTet.init_tensor(np.linspace(0, 0.2, k + 1), np.linspace(0, 0.2, k + 1),
                                     np.linspace(0, 1.0, 5 * k + 1))
    tip = np.flatnonzero(mesh.p[2] > 1.0 - 1e-9)
    per_vertex = np.array([load / tip.size, 0.0, 0.0])
    force = sa.VertexForce(tip, lambda t, x, v: min(t / ramp, 1.0) * per_vertex)
    body = sa.ElasticBody(mesh, sa.NeoHookean(E=E, nu=0.3), density=2000.0,
                          fixed=np.flatnonzero(mesh.p[2] < 1e-9))
    return sa.Simulation(body, dt=0.005, gravity=(0.0, 0.0, -9.81), damping=sa.Rayleigh(2.0, 0.0005),
                         reducer=reducer, solver="direct", forces=[force])


def factories(args):
    mesh = args.mesh
    return {
        "bar": lambda red: bar(args.bar, red),
        "cantilever": lambda red: sa.scenes.cantilever(resolution=args.cantilever, reducer=red, solver="direct"),
        "paper_beam": lambda red: sa.scenes.paper_beam(mesh=mesh, resolution=args.paper_beam, reducer=red,
                                                       solver="direct"),
    }


def measure(factory, budgets, frames, never_slower):
    """Full space and one reducer per budget, interleaved; a row per budget."""
    sims = {"full": factory(None)}
    for b in budgets:
        sims[b] = factory(sa.Affinification(target_error=b, relative_to="response", never_slower=never_slower))
    full = sims["full"]
    rest = full.system.p0
    worst = {b: 0.0 for b in budgets}
    stress = {b: 0.0 for b in budgets}
    peaks = {"response": 0.0, "stress": 0.0}

    def on_frame(frame, running):
        peaks["response"] = max(peaks["response"], metrics.response_amplitude(full.state.x, rest))
        sigma_ref = metrics.cauchy_stress(full.system, full.state.x)
        peaks["stress"] = max(peaks["stress"], metrics.largest_stress(sigma_ref))
        for b in budgets:
            if b in running:
                x = running[b].state.x
                worst[b] = max(worst[b], metrics.distance_m(x, full.state.x))
                stress[b] = max(stress[b], metrics.stress_error(metrics.cauchy_stress(full.system, x), sigma_ref, 0.0))

    runs = runners.interleaved(sims, frames, on_frame=on_frame)
    rows = []
    for b in budgets:
        recs = runs[b].records
        est = max((r.get("estimated_error", 0.0) for r in recs), default=0.0)
        rows.append({"budget": b, "response_m": peaks["response"], "size_m": full.size,
                     "response_error": worst[b] / peaks["response"], "size_error": worst[b] / full.size,
                     "error_m": worst[b], "estimated": est, "stress_error": stress[b] / peaks["stress"],
                     "speedup": runs[b].summary.get("speedup"), "elements": int(full.system.m),
                     "status": runs[b].summary["status"]})
    return rows


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--budgets", type=float, nargs="+", default=[0.01, 0.03])
    p.add_argument("--frames", type=int, default=120)
    p.add_argument("--bar", type=int, default=3, help="bar cells across (120 k^3 tets)")
    p.add_argument("--cantilever", type=int, default=4)
    p.add_argument("--paper-beam", type=int, default=3)
    p.add_argument("--mesh", default=None, help="the paper's beam mesh file instead of the procedural beam")
    p.add_argument("--never-slower", action="store_true", help="keep the fall-back to full space on")
    p.add_argument("--scenes", nargs="+", default=["bar", "cantilever", "paper_beam"])
    p.add_argument("--tiny", action="store_true")
    p.add_argument("--json", default=None)
    args = p.parse_args(argv)
    if args.tiny:
        args.frames, args.bar, args.cantilever, args.paper_beam, args.budgets = 10, 1, 2, 1, [0.03]
    made = factories(args)
    out = []
    print(f"{'scene':>11} {'tets':>6} {'budget':>7} {'resp err':>9} {'dist err':>9} {'dist m':>9} "
          f"{'estimate':>9} {'stress err':>10} {'speedup':>8} {'holds':>6}")
    for name in args.scenes:
        for r in measure(made[name], args.budgets, args.frames, args.never_slower):
            r["scene"] = name
            out.append(r)
            holds = r["response_error"] <= MARGIN * r["budget"]
            print(f"{name:>11} {r['elements']:6d} {r['budget']:7.3g} {r['response_error']:9.2e} "
                  f"{r['size_error']:9.2e} {r['error_m']:9.2e} {r['estimated']:9.2e} {r['stress_error']:10.2e} "
                  f"{r['speedup'] or float('nan'):8.2f} {str(holds):>6}", flush=True)
    print("resp err = max vertex distance to the full-space run / the full-space run's largest displacement "
          "from rest;\ndist err = the same / the scene size; dist m in metres; stress err = max element "
          "|sigma - sigma_ref| / max |sigma_ref|")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(out, fh, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
