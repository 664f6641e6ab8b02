"""Two soft cubes meeting head-on (tests/test_contact_reliability.py): the path of each contact
iteration and tolerance, frame by frame.

Each ``--runs`` entry ``SOLVER:TOLERANCE`` (e.g. ``block:1e-10``) steps the scene on its own, the
sweeps capped at ``--cap`` (a tolerance below the default needs more than 50; ``max_iterations`` =
the cap); ``--newton-iters`` iterates the step by Newton. Prints per frame: contacts, sweeps, the
contact residual over the velocity to remove, inverted elements, the energy (J) and the largest
speed (m/s); a run that diverges says where. At twice the wave speed the runs part where the
tolerance lets them (docs/contact.md, "PGS on the pills"). Usage::

    python benchmarks/head_on_paths.py --speed 200 --runs gauss-seidel:1e-6 block:1e-6 gauss-seidel:1e-8 block:1e-8 \\
        gauss-seidel:1e-10 block:1e-10 --cap 20000 --frames 8
"""
import argparse
import os
import sys
import warnings

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import numpy as np  # noqa: E402

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
import skfem_affine as sa  # noqa: E402
from skfem_affine.lab import scenes  # noqa: E402


def cubes(speed, solver, tolerance, cap, newton_iters):
    """The test's two 0.5 m cubes (4 cells an edge, E = 1e7, wave speed 100 m/s), 0.05 m apart."""
    size, gap = 0.5, 0.05
    mat = sa.NeoHookean(E=1e7, nu=0.35)
    bodies = [sa.ElasticBody(scenes.box_mesh(size, 4, (s * (size + gap) / 2, 0, 0)), mat, density=1000.0,
                             velocity=(-s * speed, 0, 0)) for s in (-1, 1)]
    contact = sa.PGS(solver=solver, tolerance=tolerance, iterations=cap, max_iterations=cap)
    return sa.Simulation(bodies, dt=0.01, gravity=(0, 0, 0), contact=contact, newton_iters=newton_iters)


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--speed", type=float, default=200.0, help="each cube's speed (m/s)")
    p.add_argument("--runs", nargs="+", default=["gauss-seidel:1e-6", "block:1e-6"], metavar="SOLVER:TOLERANCE")
    p.add_argument("--cap", type=int, default=50, help="the sweep cap of every run")
    p.add_argument("--frames", type=int, default=8)
    p.add_argument("--newton-iters", type=int, default=1)
    args = p.parse_args(argv)
    for run in args.runs:
        solver, tolerance = run.split(":")
        sim = cubes(args.speed, solver, float(tolerance), args.cap, args.newton_iters)
        print(f"{solver}, tolerance {tolerance}: frame, contacts, sweeps, residual / scale, inverted, energy, "
              "largest speed")
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", sa.SimulationWarning)
            try:
                for state in sim.run(args.frames):
                    r = sim.stats[-1]
                    rel = r["contact_residual"] / r["contact_scale"] if r.get("contact_scale") else 0.0
                    print(f"  {r['frame']:3d} {r.get('n_contacts', 0):4d} {r.get('pgs_iterations', 0):6d} {rel:9.1e} "
                          f"{r['inverted_elements']:4d} {r['energy']:10.4g} {np.linalg.norm(state.v, axis=1).max():7.3g}")
            except sa.SimulationDiverged as err:
                print(f"  diverged: {err}")


if __name__ == "__main__":
    main()
