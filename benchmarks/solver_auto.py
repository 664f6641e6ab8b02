"""``solver="auto"`` against each solver it chooses from, on the first frames of a full-space run.

The cantilever scene (Neo-Hookean, E = 2e7 by default; ``--E`` for a stiffer part) at several
sizes is run in full space with ``solver="pardiso"`` (or SuperLU without pypardiso), ``"amg"``
and ``"auto"``, the three stepped frame by frame in turn in one process (so that load from
elsewhere hits all alike), after a warm-up of every solver on a small beam (library loading
and compiled kernels are not in the times). Prints, per size, the wall time of the first
frames of each, the per-frame times of the first few frames, and which solver ``auto`` used.
Usage::

    python benchmarks/solver_auto.py [--sizes 4 9 16] [--frames 10] [--E 2e7]

``--sizes`` are the cantilever's resolution k (24 k^3 tets: 4 -> 1536, 9 -> 17496, 16 -> 98304);
``--frames`` one number or one per size.
"""
import argparse
import os
import sys

import numpy as np

# measure the checkout this script sits in, not whatever skfem_affine is installed
sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
from skfem_affine import solvers  # noqa: E402
from skfem_affine.lab import metrics, runners, scenes  # noqa: E402


def build(k, solver, E):
    return scenes.cantilever(resolution=k, E=E, solver=solver)


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[4, 9, 16])
    parser.add_argument("--frames", type=int, nargs="+", default=[10])
    parser.add_argument("--E", type=float, default=2e7, help="Young's modulus, Pa (default 2e7)")
    args = parser.parse_args()
    frames = args.frames * len(args.sizes) if len(args.frames) == 1 else args.frames
    direct = "pardiso" if solvers.has_pardiso() else "superlu"
    names = (direct, "amg", "auto")
    for name in names:  # warm-up: load each solver's library and the compiled kernels
        for _ in build(2, name, args.E).run(2):
            pass
    print(f"cantilever, E = {args.E:g} Pa, full space; {os.cpu_count()} cores, load average "
          f"{os.getloadavg()[0]:.1f}")
    print(f"{'tets':>7} {'DOFs':>7} {'frames':>6} " + " ".join(f"{n + ' s':>10}" for n in names)
          + "  auto used (iterations per frame)")
    for k, n in zip(args.sizes, frames):
        sims = {name: build(k, name, args.E) for name in names}
        runs = runners.interleaved(sims, n)
        walls = {name: metrics.column(r.records, "wall") for name, r in runs.items()}
        auto = runs["auto"].records
        used = [r.get("solver") for r in auto]
        iters = [int(r.get("iterations", 0)) for r in runs["amg"].records]
        sim = sims["auto"]
        print(f"{sim.system.m:7d} {3 * sim.system.n:7d} {n:6d} "
              + " ".join(f"{np.sum(walls[name]):10.2f}" for name in names)
              + f"  {', '.join(f'{u}' for u in used[:6])}{' ...' if len(used) > 6 else ''}"
              + f" (amg: {', '.join(map(str, iters[:6]))})")
        for name in names:
            print(f"{'':22}{name:>8} per frame, s: " + " ".join(f"{w:.2f}" for w in walls[name][:8]))


if __name__ == "__main__":
    main()
