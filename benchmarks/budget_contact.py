"""The default error budget on contact scenes against the best fixed threshold that meets it.

For each scene, full space, the default ``sa.Affinification()`` (1 % of the response) and
``Affinification(tau_a, 2 tau_a)`` for each ``--taus`` are stepped frame by frame in turn in one
process (``runners.interleaved``). Per method: the largest vertex distance to the full-space run
over the full-space run's response (its largest displacement from rest), in budgets (the
default's own unit); the speedup over the full-space run, summed over the frames after ``--rest``
(the rest phase) and after the first frame; the DOF ratio and the share of affine elements at
rest; and, for the default, the share of its rest frames that returned the reduced solution,
were shadows, impacts or solved in full space (the fall-back). The best fixed threshold is the
fastest at rest whose error is within ``--tolerance`` budgets; the last line of each scene is the
default's speed at rest over it.

Scenes: ``pileC`` (the four boxes of ``benchmarks/budget.py``, C cells per box edge), ``beamsK``
(``sa.scenes.stacked_beams``, resolution K), ``dropK`` (``sa.scenes.drop`` with a box, resolution K,
dropped by 5 cm).

Usage::

    python benchmarks/budget_contact.py --scenes pile4 pile6 beams2 drop3 --frames 200 --rest 100
    python benchmarks/budget_contact.py --tiny      # seconds: the script runs
"""
import argparse
import json
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
import skfem_affine as sa  # noqa: E402
from skfem_affine.lab import metrics, runners  # noqa: E402

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from budget import pile, warm  # noqa: E402


def factory(scene):
    """reducer -> Simulation of the scene named ``pileC``, ``beamsK`` or ``dropK``."""
    kind, size = scene.rstrip("0123456789"), scene[len(scene.rstrip("0123456789")):]
    if not size:
        raise ValueError(f"--scenes: {scene!r} needs its size, e.g. pile4, beams2, drop3")
    k = int(size)
    if kind == "pile":
        return lambda reducer: pile(k, reducer)
    if kind == "beams":
        return lambda reducer: sa.scenes.stacked_beams(resolution=k, solver="direct", reducer=reducer)
    if kind == "drop":
        return lambda reducer: sa.scenes.drop(resolution=k, shape="box", height=0.05, solver="direct",
                                              reducer=reducer)
    raise ValueError(f"--scenes: unknown scene {scene!r} (pileC, beamsK, dropK)")


def share(records, key):
    return float(np.mean([bool(r.get(key)) for r in records])) if records else 0.0


def measure(scene, taus, frames, rest, budget=0.01, tolerance=1.0):
    """One scene: a row per method (dicts), the default's ratio to the best fixed threshold last."""
    make = factory(scene)
    warm(make)
    reducers = {"default": sa.Affinification(), **{f"tau {t:g}": sa.Affinification(t, 2 * t) for t in taus}}
    sims = {"full": make(None), **{name: make(r) for name, r in reducers.items()}}
    worst, response = dict.fromkeys(reducers, 0.0), [0.0]

    def on_frame(frame, running):
        full = running["full"]
        response[0] = max(response[0], metrics.response_amplitude(full.state.x, full.system.p0))
        for name in reducers:
            if name in running:
                worst[name] = max(worst[name], metrics.distance_m(running[name].state.x, full.state.x))

    runs = runners.interleaved(sims, frames, on_frame=on_frame)
    full = runs["full"].records

    def wall(records, start):
        return sum(r["wall"] for r in records[start:])

    rows = []
    for name in reducers:
        recs = runs[name].records
        at_rest = recs[rest:]
        row = {"scene": scene, "method": name, "error_budgets": worst[name] / response[0] / budget,
               "speedup_rest": wall(full, rest) / wall(recs, rest), "speedup_run": wall(full, 1) / wall(recs, 1),
               "dof_ratio_rest": float(np.mean([r["dofs"] for r in at_rest]) / np.mean([r["dofs"] for r in full[rest:]])),
               "affine_elements_rest": float(np.mean([r.get("reduced_fraction", 0.0) for r in at_rest])),
               "status": runs[name].summary["status"]}
        if name == "default":  # what the controller did with the frames at rest
            row.update(reduced=share(at_rest, "reduced"), shadow=share(at_rest, "shadow"),
                       impact=share(at_rest, "impact"),
                       full_space=float(np.mean([not (r.get("reduced") or r.get("shadow") or r.get("impact"))
                                                 for r in at_rest])) if at_rest else 0.0)
        rows.append(row)
        print(json.dumps(row), flush=True)
    fixed = [r for r in rows if r["method"] != "default" and r["error_budgets"] <= tolerance and r["status"] == "ok"]
    best = max(fixed, key=lambda r: r["speedup_rest"]) if fixed else None
    default = rows[0]
    summary = {"scene": scene, "response_m": response[0], "tolerance": tolerance, "best_fixed": best["method"] if best else None,
               "best_fixed_speedup_rest": best["speedup_rest"] if best else None,
               "default_speedup_rest": default["speedup_rest"],
               "ratio_to_best": default["speedup_rest"] / best["speedup_rest"] if best else None}
    print(json.dumps(summary), flush=True)
    return rows, summary


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--scenes", nargs="+", default=["pile4", "pile6", "beams2", "drop3"],
                   help="pileC (four boxes, C cells per edge), beamsK (stacked beams), dropK (a box dropped)")
    p.add_argument("--taus", type=float, nargs="+", default=[1e-4, 1e-3, 1e-2, 3e-2, 0.1])
    p.add_argument("--frames", type=int, default=200)
    p.add_argument("--rest", type=int, default=100, help="speedups over the frames after this one (the rest phase)")
    p.add_argument("--tolerance", type=float, default=1.0,
                   help="the fixed thresholds compared: error within this many budgets (the table's rows show all)")
    p.add_argument("--json", help="write the rows and summaries here")
    p.add_argument("--tiny", action="store_true", help="one tiny scene, a few frames: check that the script runs")
    args = p.parse_args(argv)
    if args.tiny:
        args.scenes, args.taus, args.frames, args.rest = ["pile1"], [1e-3, 0.1], 8, 4
    out = [measure(s, args.taus, args.frames, args.rest, tolerance=args.tolerance) for s in args.scenes]
    if args.json:
        with open(args.json, "w") as f:
            json.dump(out, f, indent=1)
    return out


if __name__ == "__main__":
    main()
