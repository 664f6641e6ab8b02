"""A pile of four soft boxes (or a stack of two) at rest for many frames: does it stay at rest, reduced?

Steps the pile of ``benchmarks/budget.py`` (``--pile``), or with ``--stack`` the two-box stack of
``tests/test_resting_contact.py``, in full space and under each ``--methods`` (``default``:
``Affinification()``; ``budget``: the default budget without the fall-back to full space,
``never_slower=False``; ``paper``: the paper's thresholds 1e-4 / 2e-4), frame by frame in turn in
one process, and prints per run the drift of the bodies' centres of mass between the end of
settling (``--settle``) and any later frame, the lowest vertex (sinking into the ground), the
largest vertex distance to the full-space run over the scene size, the share of reduced frames and
of affine elements at rest, and the speedup at rest.

Usage::

    python benchmarks/resting_pile.py --frames 1000 --settle 100 --cells 4
    python benchmarks/resting_pile.py --stack --cells 2 --frames 1000 --methods budget paper
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
from budget import pile  # noqa: E402


def centres(sim):
    x, out, start = sim.state.x, [], 0
    for body in sim.bodies:
        n = body.mesh.p.shape[1]
        out.append(x[start:start + n].mean(axis=0))
        start += n
    return np.array(out)


def stack(cells, reducer=None):
    """The stack of ``tests/test_resting_contact.py``: a soft box on the ground, a smaller one on it."""
    mat = sa.NeoHookean(E=1e6, nu=0.3)
    bodies = [sa.ElasticBody(sa.scenes.box_mesh(0.2, cells, (0.0, 0.0, 0.1)), mat, density=1000.0),
              sa.ElasticBody(sa.scenes.box_mesh(0.12, cells, (0.02, 0.01, 0.26)), mat, density=1000.0)]
    return sa.Simulation(bodies, dt=0.01, gravity=(0.0, 0.0, -9.81), colliders=[sa.Plane()], reducer=reducer)


METHODS = {"default": lambda: sa.Affinification(), "budget": lambda: sa.Affinification(never_slower=False),
           "paper": lambda: sa.Affinification(1e-4, 2e-4)}


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--frames", type=int, default=1000)
    p.add_argument("--settle", type=int, default=100)
    p.add_argument("--cells", type=int, default=4)
    p.add_argument("--stack", action="store_true", help="the two-box stack instead of the pile of four")
    p.add_argument("--methods", nargs="+", default=["default"], choices=sorted(METHODS))
    args = p.parse_args(argv)
    make = stack if args.stack else pile
    sims = {"full": make(args.cells), **{name: make(args.cells, METHODS[name]()) for name in args.methods}}
    settled, low, gap = {}, {name: np.inf for name in sims}, dict.fromkeys(args.methods, 0.0)
    drift = dict.fromkeys(sims, 0.0)

    def on_frame(frame, running):
        for name, sim in running.items():
            if frame + 1 == args.settle:
                settled[name] = centres(sim)
            elif name in settled:
                drift[name] = max(drift[name], float(np.abs(centres(sim) - settled[name]).max()))
            low[name] = min(low[name], float(sim.state.x[:, 2].min()))
        for name in args.methods:
            if name in running and "full" in running:
                gap[name] = max(gap[name], metrics.distance_error(running[name].state.x, running["full"].state.x,
                                                                  running["full"].size))

    runs = runners.interleaved(sims, args.frames, on_frame=on_frame)
    rest = {name: runs[name].records[args.settle:] for name in sims}
    out = {name: {"drift_m": drift[name] if name in settled else None, "lowest_vertex_m": low[name],
                  "wall_at_rest_s": sum(r["wall"] for r in rest[name])} for name in sims}
    for name in args.methods:
        red = rest[name]
        out[name].update(reduced_frames=float(np.mean([bool(r.get("reduced", r.get("n_clusters", 0) > 0))
                                                       for r in red])) if red else None,
                         affine_elements=float(np.mean([r.get("reduced_fraction", 0.0) for r in red])) if red else None,
                         speedup_at_rest=out["full"]["wall_at_rest_s"] / out[name]["wall_at_rest_s"] if red else None,
                         distance_error=gap[name])
    print(json.dumps(out, indent=1))
    return out


if __name__ == "__main__":
    main()
