"""What an error budget costs and keeps on every registered scene (docs/budget.md).

For each scene of ``sa.scenes.SCENES`` (default sizes), the full-space run and one reducer per
method and budget are stepped frame by frame in turn in one process; per reducer the table gives
the achieved largest vertex distance to the full-space run over the full-space run's response, in
budgets, the speedup (the full-space run's wall time over the reducer's, summed over the frames after
the first),
the DOF ratio (mean DOFs solved over the full-space run's), and the fraction of frames that
returned the reduced solution. Rigidification runs on the contact-free scenes and the twisting
beam. ``never_slower=False`` by default, so that these small scenes reduce at all.

Usage::

    python benchmarks/budget_scenes.py                       # the docs/budget.md table
    python benchmarks/budget_scenes.py --tiny                # seconds: the script runs
    python benchmarks/budget_scenes.py --json out.json       # the rows, for comparing two versions
"""
import argparse
import json
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
import skfem_affine as sa  # noqa: E402
from skfem_affine.lab import metrics  # noqa: E402

RIGID = ("cantilever", "paper_beam", "free_body", "drop", "twisting_beam")


def measure(name, budgets, frames, never_slower, tiny):
    """One scene: full space and every (method, budget) stepped in turn; a row per reducer."""
    factory = sa.scenes.SCENES[name]
    kw = dict(solver="direct")
    if tiny:
        kw.update({"pills": dict(n=2), "bowling": dict(n=1), "toothbrush": {}, "wheel": {},
                   "octopus": {}}.get(name, dict(resolution=1)))
    methods = [("affinification", sa.Affinification)] + ([("rigidification", sa.Rigidification)]
                                                         if name in RIGID else [])
    runs = [(m, b, factory(reducer=R(target_error=b, never_slower=never_slower), **kw))
            for m, R in methods for b in budgets]
    full = factory(reducer=None, **kw)  # reducer=None: the armadillo has its own
    worst, response = np.zeros(len(runs)), 0.0
    for _ in range(frames):
        full.step()
        response = max(response, metrics.response_amplitude(full.state.x, full.system.p0))
        for i, (_, _, sim) in enumerate(runs):
            sim.step()
            worst[i] = max(worst[i], metrics.distance_m(sim.state.x, full.state.x))
    def seconds(sim):  # the first frame pays the solvers' symbolic analysis
        return sum(r["wall"] for r in sim.stats[1:])
    wall, dofs = seconds(full), full.stats.mean("dofs")
    return [dict(scene=name, tets=int(full.system.m), method=m, budget=b, error=float(w / response / b),
                 speedup=wall / seconds(sim), dof_ratio=sim.stats.mean("dofs") / dofs,
                 reduced=float(np.mean([bool(r.get("reduced", False)) for r in sim.stats])),
                 estimate=float(max(r.get("estimated_error", 0.0) for r in sim.stats) / b),
                 amplification=float(max(r.get("amplification", 1.0) for r in sim.stats)))
            for (m, b, sim), w in zip(runs, worst)]


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--scenes", nargs="*", default=sorted(sa.scenes.SCENES))
    p.add_argument("--budgets", type=float, nargs="+", default=[0.01, 0.03])
    p.add_argument("--frames", type=int, default=100)
    p.add_argument("--never-slower", action="store_true", help="the fall-back to full space on (the default of "
                                                                  "a reducer given a budget)")
    p.add_argument("--json", help="write the rows here")
    p.add_argument("--tiny", action="store_true", help="smallest scenes, 3 frames: check that the script runs")
    args = p.parse_args(argv)
    frames = 3 if args.tiny else args.frames
    rows = []
    if not args.tiny:  # the reducers' kernels are compiled (or loaded from the cache) before any timing
        for name in args.scenes:
            measure(name, args.budgets, 3, args.never_slower, True)
    print("| scene | tets | method | budget (of R) | error (budgets) | largest estimate (budgets) | "
          "speedup | DOF ratio | reduced frames |")
    print("|---|---|---|---|---|---|---|---|---|")
    for name in args.scenes:
        for r in measure(name, args.budgets, frames, args.never_slower, args.tiny):
            rows.append(r)
            print(f"| {r['scene']} | {r['tets']} | {r['method']} | {r['budget']:g} | {r['error']:.2f} | "
                  f"{r['estimate']:.2f} | {r['speedup']:.2f} | {r['dof_ratio']:.2f} | {r['reduced']:.2f} |",
                  flush=True)
    if args.json:
        with open(args.json, "w") as f:
            json.dump(rows, f, indent=1)
    return rows


if __name__ == "__main__":
    main()
