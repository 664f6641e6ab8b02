"""The adaptive subspace's never-slower fall-back and error budget measured (docs/budget.md, docs/subspace.md).

Every ratio comes from methods stepped frame by frame in turn in one process
(:func:`skfem_affine.lab.runs.interleaved`), errors against the full-space IPC Newton run
stepped with them, on the scenes of ``benchmarks/subspace_paper.py`` (IPC contact, implicit
Euler). Speedups are over frames 2 to N: the first frame of whichever simulation is stepped
first pays one-time set-up (measured 0.1-0.4 s, as much as a dozen steps at 1.3k tets).

* ``--tables never-slower``: per scene, full-space Newton, the default ``sa.AdaptiveSubspace()``
  and the same reducer with the thresholds given explicitly (``eps_nodal = eps_modal = 0.5``,
  today's behaviour, no fall-back judged by time): run speedup over full, share of steps
  reduced, max distance error; ``--control`` adds a second full-space run (its "speedup" is the
  noise of the measurement);
* ``--tables budget``: per scene and budget in ``--budgets``, ``AdaptiveSubspace(target_error=b)``
  (with its never-slower fall-back unless ``--no-never-slower``): achieved max distance error,
  largest estimate, speedup, share of steps reduced, mean eps_nodal; ``--verbose`` adds one line
  per step (eps_nodal, reduced ``R`` / shadow ``S`` / out of time ``D``, wall time beside full
  space's, reduced DOFs, Newton iterations reduced + full, whether reduction pays, local and
  estimated error), also kept in the JSON as ``steps``.

Usage::

    python benchmarks/subspace_budget.py --tables never-slower --cells 6 --frames 20
    python benchmarks/subspace_budget.py --tables budget --scenes drop --cells 6 --frames 40 --budgets 0.01 0.03
    python benchmarks/subspace_budget.py --tables budget --scenes drop --cells 10 --frames 20 --verbose
"""
import argparse
import json
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
import skfem_affine as sa  # noqa: E402
from skfem_affine.lab import metrics, runs  # noqa: E402

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from subspace_paper import SCENES, scene  # noqa: E402


#: The per-step record keys ``--verbose`` prints (and the JSON keeps).
STEP_KEYS = ("wall", "eps_nodal", "reduced", "shadow", "over_deadline", "reduction_pays", "reduced_dofs",
             "newton_iters", "full_newton_iters", "local_error", "estimated_error")


def print_steps(r, full_walls):
    """One line per step of a reducer's run: the controllers' records beside full space's wall time."""
    for i, (st, fw) in enumerate(zip(r["steps"], full_walls)):
        flags = "".join(c for c, k in (("R", "reduced"), ("S", "shadow"), ("D", "over_deadline"))
                        if st.get(k))
        print(f"    step {i:3d} {flags:<3} eps_nodal {st.get('eps_nodal', float('nan')):.3g}  "
              f"wall {st['wall']:.3f} s (full {fw:.3f})  dofs {st.get('reduced_dofs', 0)}  "
              f"newton {st.get('newton_iters', 0)}+{st.get('full_newton_iters', 0)}  "
              f"pays {st.get('reduction_pays')}  local {st.get('local_error', 0.0):.1e}  "
              f"E {st.get('estimated_error', 0.0):.1e}", flush=True)


def measured(kind, cells, reducers, frames, solver):
    """Full space and each reducer interleaved: name -> dict of run speedup, errors, records."""
    sims = {"full": scene(kind, cells, solver=solver),
            **{name: scene(kind, cells, reducer=red, solver=solver) for name, red in reducers.items()}}
    errors = {name: 0.0 for name in reducers}

    def on_frame(frame, running):
        full = running.get("full")
        for name in reducers:
            if full is not None and name in running:
                errors[name] = max(errors[name], metrics.distance_error(running[name].state.x, full.state.x, full.size))

    result = runs.interleaved(sims, frames, on_frame=on_frame)
    wall_full = sum(r["wall"] for r in result["full"].records)
    out = {}
    for name in reducers:
        rec = result[name].records
        n = min(len(rec), len(result["full"].records))
        out[name] = {"speedup": sum(r["wall"] for r in result["full"].records[1:n]) / sum(r["wall"] for r in rec[1:n]),
                     "reduced": float(np.mean([bool(r.get("reduced", False)) for r in rec])),
                     "max_error": errors[name],
                     "estimate": max((r.get("estimated_error", 0.0) for r in rec), default=0.0),
                     "eps_nodal": float(np.mean([r.get("eps_nodal", np.nan) for r in rec])),
                     "status": result[name].summary["status"], "frames": len(rec),
                     "reduced_steps": [int(bool(r.get("reduced", False))) for r in rec],
                     "walls": [float(r["wall"]) for r in rec],
                     "full_walls": [float(r["wall"]) for r in result["full"].records],
                     "steps": [{k: r[k] for k in STEP_KEYS if k in r} for r in rec]}
    out["full_wall_s"] = wall_full
    return out


def never_slower(args):
    rows = []
    for kind in args.scenes:
        reducers = {"default": sa.AdaptiveSubspace(),
                    "explicit": sa.AdaptiveSubspace(eps_nodal=0.5, eps_modal=0.5)}
        if args.control:
            reducers["full-again"] = None  # a second full-space run: the measurement's noise floor
        res = measured(kind, args.cells, reducers, args.frames, args.solver)
        for name in reducers:
            rows.append({"scene": kind, "reducer": name, **res[name]})
            r = res[name]
            print(f"{kind:>7} {name:>9}: speedup {r['speedup']:.2f}  reduced {r['reduced']:.2f}  "
                  f"max error {r['max_error']:.1e}  steps {''.join(map(str, r['reduced_steps']))}", flush=True)
    return rows


def budget(args):
    rows = []
    for kind in args.scenes:
        reducers = {b: sa.AdaptiveSubspace(target_error=b, relative_to="size", never_slower=args.never_slower) for b in args.budgets}
        res = measured(kind, args.cells, {str(b): r for b, r in reducers.items()}, args.frames, args.solver)
        for b in args.budgets:
            r = res[str(b)]
            rows.append({"scene": kind, "budget": b, **r})
            print(f"{kind:>7} budget {b:<6}: achieved {r['max_error']:.1e}  estimate {r['estimate']:.1e}  "
                  f"speedup {r['speedup']:.2f}  reduced {r['reduced']:.2f}  mean eps_nodal {r['eps_nodal']:.2g}  "
                  f"steps {''.join(map(str, r['reduced_steps']))}", flush=True)
            if args.verbose:
                print_steps(r, r["full_walls"])
    return rows


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--tables", nargs="+", choices=("never-slower", "budget"), default=["never-slower", "budget"])
    p.add_argument("--scenes", nargs="+", choices=SCENES, default=list(SCENES))
    p.add_argument("--cells", type=int, default=6)
    p.add_argument("--frames", type=int, default=20)
    p.add_argument("--budgets", nargs="+", type=float, default=[0.01, 0.03])
    p.add_argument("--control", action="store_true", help="never-slower table: also a second full-space run")
    p.add_argument("--no-never-slower", dest="never_slower", action="store_false",
                   help="budget table: the error budget without the fall-back (it reduces even where it does not pay)")
    p.add_argument("--verbose", action="store_true", help="budget table: one line per step (eps_nodal, reduced, "
                   "shadow, over deadline, reduction pays)")
    p.add_argument("--solver", default="pardiso" if sa.solvers.has_pardiso() else "superlu")
    p.add_argument("--json", default="benchmarks/results/subspace_budget.json")
    args = p.parse_args(argv)
    out = {"args": vars(args)}
    if "never-slower" in args.tables:
        out["never_slower"] = never_slower(args)
    if "budget" in args.tables:
        out["budget"] = budget(args)
    if args.json:
        os.makedirs(os.path.dirname(os.path.abspath(args.json)), exist_ok=True)
        with open(args.json, "w") as fh:
            json.dump(out, fh, indent=1, default=float)
    return out


if __name__ == "__main__":
    main()
