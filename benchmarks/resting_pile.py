"""A pile of four soft boxes at rest for many frames: does it stay at rest, reduced?

Steps the pile of ``benchmarks/budget.py`` (``--pile``) in full space and under the default
``Affinification()``, frame by frame in turn in one process, and prints per body the drift of
its centre of mass between the end of settling (``--settle``) and the last frame, the lowest
vertex (sinking into the ground), the largest vertex distance between the two runs over the
scene size, the reduced run's share of reduced frames and of affine elements at rest, and the
speedup at rest.

Usage::

    python benchmarks/resting_pile.py --frames 1000 --settle 100 --cells 4
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


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--frames", type=int, default=1000)
    p.add_argument("--settle", type=int, default=100)
    p.add_argument("--cells", type=int, default=4)
    args = p.parse_args(argv)
    sims = {"full": pile(args.cells), "default": pile(args.cells, sa.Affinification())}
    settled, low, gap = {}, {name: np.inf for name in sims}, [0.0]

    def on_frame(frame, running):
        for name, sim in running.items():
            if frame + 1 == args.settle:
                settled[name] = centres(sim)
            low[name] = min(low[name], float(sim.state.x[:, 2].min()))
        if len(running) == 2:
            gap[0] = max(gap[0], metrics.distance_error(running["default"].state.x, running["full"].state.x,
                                                        running["full"].size))

    runs = runners.interleaved(sims, args.frames, on_frame=on_frame)
    rest = {name: runs[name].records[args.settle:] for name in sims}
    out = {name: {"drift_m": float(np.abs(centres(runs[name].sim) - settled[name]).max()) if name in settled else None,
                  "lowest_vertex_m": low[name], "wall_at_rest_s": sum(r["wall"] for r in rest[name])}
           for name in sims}
    red = rest["default"]
    out["default"].update(reduced_frames=float(np.mean([bool(r.get("reduced")) for r in red])) if red else None,
                          affine_elements=float(np.mean([r.get("reduced_fraction", 0.0) for r in red])) if red else None)
    out["speedup_at_rest"] = out["full"]["wall_at_rest_s"] / out["default"]["wall_at_rest_s"] if red else None
    out["distance_error"] = gap[0]
    print(json.dumps(out, indent=1))
    return out


if __name__ == "__main__":
    main()
