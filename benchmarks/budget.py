"""The error budget, the time budget and "never slower" measured (docs/budget.md).

Budgets here are relative to the scene size (the unit of these tables in docs/budget.md; the
response unit: benchmarks/budget_response.py). Three tables, every ratio measured with the methods stepped frame by frame in turn in one
process (``runners.interleaved``), errors against the full-space run stepped with them:

1. ``--budgets``: for each scene (the paper's beams from ``--meshes``, our cantilever at
   ``--resolution``, the contact scene ``drop``) and budget, the error-budget affinification's
   achieved max distance error, its largest estimate, its speedup, and the best speedup of the
   fixed thresholds (tau_a in ``--taus``, tau_e = 2 tau_a) whose error meets the same budget;
2. ``--tables time``: on the last mesh, a budget of half the full frame's mean wall time, the
   fraction of frames after ``--warm`` frames that met it (``--repeat`` runs), the budgeted run
   stepped in turn with the full-space run, whose median frame time beside it is reported
   relative to the warm-up's (a change of load from elsewhere);
3. ``--never-slower``: default ``sa.Affinification()`` against full space at each scene;
4. ``--tables estimate``: the largest error estimate against the measured error, per budget.

The contact scene ``--pile`` (four boxes coming to rest; ``--rest`` frames excluded from the
speedups, so that they are those of the rest phase) measures the default budget on bodies at rest.

Usage (the tables of docs/budget.md; run on a quiet machine)::

    python benchmarks/budget.py --meshes MESH_DIR/beam1264.mesh MESH_DIR/beam5232.mesh \\
        --resolution 6 --frames 200
    python benchmarks/budget.py --tiny     # a seconds-long check that the script runs
    python benchmarks/budget.py --resolution 0 --drop 0 --pile 5 --frames 200 --rest 100 --budgets 0.01 \
        --taus 1e-4 1e-3 0.01 0.03 0.1 --tables budgets never-slower      # docs/affinification.md
    python benchmarks/budget.py --tables estimate --resolution 4 --drop 2 --frames 150   # docs/budget.md
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
from affinification import paper_beam  # noqa: E402


def scene_factories(args):
    """Name -> factory(reducer) of the measured scenes."""
    out = {}
    for path in args.meshes:
        name = os.path.splitext(os.path.basename(path))[0]
        out[name] = (lambda p: lambda reducer: paper_beam(p, sa.NeoHookean(E=1e5, nu=0.35), solver="direct",
                                                           reducer=reducer))(path)
    if args.resolution:
        out[f"cantilever{args.resolution}"] = lambda reducer: sa.scenes.cantilever(
            resolution=args.resolution, solver="direct", reducer=reducer)
    if args.drop:
        out[f"drop{args.drop}"] = lambda reducer: sa.scenes.drop(resolution=args.drop, solver="direct",
                                                                  reducer=reducer)
    if args.pile:
        out[f"pile{args.pile}"] = lambda reducer: pile(args.pile, reducer)
    return out


def pile(cells, reducer=None):
    """Four soft boxes (E = 1e6) coming to rest on the ground: two side by side, a third across
    both, a fourth on top, off centre (no vertex on another box's edge); ``cells`` per box edge."""
    mat = sa.NeoHookean(E=1e6, nu=0.35)
    boxes = [(0.3, (-0.16, 0.0, 0.152)), (0.3, (0.16, 0.0, 0.152)), (0.24, (0.0, 0.01, 0.424)),
             (0.18, (0.02, -0.01, 0.636))]
    bodies = [sa.ElasticBody(sa.scenes.box_mesh(size, cells, centre), mat, density=1000.0, name=f"box{i}")
              for i, (size, centre) in enumerate(boxes)]
    return sa.Simulation(bodies, dt=0.01, gravity=(0.0, 0.0, -9.81), colliders=[sa.Plane()], solver="direct",
                         reducer=reducer)


def measured(factory, reducers, frames, rest=0):
    """Full space and each reducer interleaved: name -> (max distance error, speedup, runs record list);
    with ``rest``, the speedup of the frames after that one."""
    sims = {"full": factory(None), **{name: factory(red) for name, red in reducers.items()}}
    full = sims["full"]
    errors = {name: 0.0 for name in reducers}

    def on_frame(frame, running):
        for name in reducers:
            if name in running:
                errors[name] = max(errors[name], metrics.distance_error(running[name].state.x, full.state.x,
                                                                        full.size))

    runs = runners.interleaved(sims, frames, on_frame=on_frame)

    def speedup(name):
        if not rest:
            return runs[name].summary.get("speedup")
        wall = [sum(r["wall"] for r in runs[n].records[rest:]) for n in ("full", name)]
        return wall[0] / wall[1] if wall[1] else None

    return {name: (errors[name], speedup(name), runs[name].records) for name in reducers}, runs


def warm(factory, most=400):
    """Compile (or load) the kernels of both paths before any timed frame: a scene with contact
    is stepped until its first contact (at most ``most`` frames), whose kernels compile there."""
    factory(None).step()
    sim = factory(sa.Affinification(0.1, 0.2, min_fraction=0.5))
    sim.step()
    sim.step()
    if sim.contact is not None:
        while not sim.stats[-1].get("n_contacts", 0) and sim.state.frame < most:
            sim.step()
        sim.step()


def budget_table(args, scenes):
    rows = []
    for scene, factory in scenes.items():
        warm(factory)
        reducers = {f"budget {b:g}": sa.Affinification(target_error=b, relative_to="size")
                    for b in args.budgets}
        reducers.update({f"fixed {t:g}": sa.Affinification(t, 2 * t) for t in args.taus})
        res, _ = measured(factory, reducers, args.frames, args.rest)
        for b in args.budgets:
            err, speed, recs = res[f"budget {b:g}"]
            ok = [(s, t) for t in args.taus for e, s, _ in [res[f"fixed {t:g}"]] if e <= b and s is not None]
            best = max(ok) if ok else (None, None)
            rows.append({"scene": scene, "budget": b, "achieved": err,
                         "estimated": max(r.get("estimated_error", 0.0) for r in recs), "speedup": speed,
                         "reduced_frames": float(np.mean([bool(r.get("reduced")) for r in recs])),
                         "best_fixed_speedup": best[0], "best_fixed_tau_a": best[1],
                         "ratio_to_best": speed / best[0] if best[0] else None})
            print(json.dumps(rows[-1]), flush=True)
    return rows


def estimate_table(args, scenes):
    """The estimator against the measured error: never_slower=False, so that small scenes reduce at all."""
    rows = []
    for scene, factory in scenes.items():
        reducers = {f"budget {b:g}": sa.Affinification(target_error=b, relative_to="size", never_slower=False)
                    for b in args.budgets}
        res, runs = measured(factory, reducers, args.frames)
        free = runs["full"].sim.system.free.size
        for b in args.budgets:
            err, _, recs = res[f"budget {b:g}"]
            rows.append({"scene": scene, "budget": b, "achieved": err,
                         "estimated": max(r.get("estimated_error", 0.0) for r in recs),
                         "mean_reduced_dofs": float(np.mean([r.get("reduced_dofs", r["dofs"]) for r in recs])),
                         "free_dofs": int(free), "mean_tau_a": float(np.mean([r["tau_a"] for r in recs]))})
            print(json.dumps(rows[-1]), flush=True)
    return rows


def time_budget_table(args, scenes):
    """Half the full frame's mean wall time (frames 1 to ``--warm``; frame 0 has the solver's
    analysis) as the budget; the budgeted run is then stepped frame by frame in turn with the
    full-space run, so that a change of load from elsewhere shows in the full frames beside it."""
    scene, factory = list(scenes.items())[0] if not args.meshes else \
        (os.path.splitext(os.path.basename(args.meshes[-1]))[0], scene_factories(args)[
            os.path.splitext(os.path.basename(args.meshes[-1]))[0]])
    rows = []
    for _ in range(args.repeat):
        full = factory(None)
        for _ in full.run(args.warm):
            pass
        budget = 0.5 * float(np.mean([r["wall"] for r in full.stats[1:]]))
        sim = factory(sa.Affinification(time_budget=budget))
        runs = runners.interleaved({"full": full, "budget": sim}, args.frames)
        after = runs["budget"].records[args.warm:]
        beside = runs["full"].records[args.warm:]
        met = float(np.mean([not r.get("time_budget_miss", False) for r in after])) if after else None
        row = {"scene": scene, "time_budget_s": budget, "frames": len(after), "met_fraction": met,
               "mean_min_fraction": float(np.mean([r.get("min_fraction", 0.0) for r in after])) if after else None,
               "shadow_frames": int(sum(bool(r.get("shadow")) for r in after)),
               # load from elsewhere: the full frame stepped just before took over 1.25 its warm-up mean
               "misses_beside_load_spike": int(sum(bool(r.get("time_budget_miss")) and f["wall"] > 2.5 * budget
                                                   for r, f in zip(after, beside))),
               # the controller had nothing left to force: at least 95 % of the elements were forced into bodies
               "misses_at_full_forcing": int(sum(bool(r.get("time_budget_miss")) and r.get("min_fraction", 0.0) >= 0.95
                                                 for r in after)),
               "full_frame_beside_over_warm": float(np.median([r["wall"] for r in beside])) / (2 * budget)
               if beside else None}
        rows.append(row)
        print(json.dumps(row), flush=True)
    return rows


def never_slower_table(args, scenes):
    rows = []
    for scene, factory in scenes.items():
        warm(factory)
        res, runs = measured(factory, {"default": sa.Affinification(relative_to="size")}, args.frames, args.rest)
        err, speed, recs = res["default"]
        rows.append({"scene": scene, "elements": int(runs["full"].sim.system.m), "ratio": speed, "error": err,
                     "reduced_frames": float(np.mean([bool(r.get("reduced")) for r in recs]))})
        print(json.dumps(rows[-1]), flush=True)
    return rows


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--meshes", nargs="*", default=[], help="MEDIT meshes of the paper's beam scene")
    p.add_argument("--resolution", type=int, default=6, help="our cantilever's resolution (0: none)")
    p.add_argument("--drop", type=int, default=2, help="the contact scene drop's resolution (0: none)")
    p.add_argument("--pile", type=int, default=0, help="cells per box of the resting pile of four boxes (0: none)")
    p.add_argument("--rest", type=int, default=0, help="speedups over the frames after this one (the rest phase)")
    p.add_argument("--frames", type=int, default=200)
    p.add_argument("--warm", type=int, default=20, help="frames before the time budget is judged")
    p.add_argument("--repeat", type=int, default=1, help="runs of the time-budget table")
    p.add_argument("--budgets", type=float, nargs="+", default=[0.003, 0.01, 0.03])
    p.add_argument("--taus", type=float, nargs="+", default=[0.01, 0.03, 0.1, 0.3, 1.0])
    p.add_argument("--tables", nargs="+", default=["budgets", "time", "never-slower"],
                   choices=["budgets", "estimate", "time", "never-slower"],
                   help="estimate: the estimator against the measured error, without the fall-back")
    p.add_argument("--tiny", action="store_true", help="tiny scenes and few frames: check that the script runs")
    args = p.parse_args(argv)
    if args.tiny:
        args.meshes, args.resolution, args.drop, args.frames, args.warm = [], 2, 1, 12, 4
        args.pile = 1 if args.pile else 0
        args.taus = [0.1, 1.0]
    scenes = scene_factories(args)
    out = {}
    if "budgets" in args.tables:
        out["budgets"] = budget_table(args, scenes)
    if "estimate" in args.tables:
        out["estimate"] = estimate_table(args, scenes)
    if "time" in args.tables:
        out["time"] = time_budget_table(args, scenes)
    if "never-slower" in args.tables:
        out["never_slower"] = never_slower_table(args, scenes)
    return out


if __name__ == "__main__":
    main()
