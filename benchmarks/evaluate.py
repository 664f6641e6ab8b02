"""Milliseconds per call of the per-frame elastic evaluation, split into its parts.

For each material, on the procedural cantilever (``--resolution k``: 24 k^3 tets) or a
MEDIT mesh (``--mesh``), after ``--warmup`` frames of the full solve (so that elements are
deformed and many are indefinite), prints the median over repeats of:
``evaluate`` (F -> P, projected dP/dF, blocks, f and the scatter of H: what a frame of
the full solve assembles), ``tangent`` (:meth:`ElasticSystem.evaluate_tangent`, no blocks),
``stress`` (P only, :meth:`ElasticSystem.stresses`), ``force`` (f from given P),
``scatter`` (H from the element blocks), and the share of elements whose unprojected
dP/dF is indefinite. Usage::

    python benchmarks/evaluate.py --resolution 10
    python benchmarks/evaluate.py --mesh MESH_DIR/beam1264.mesh
"""
import argparse
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
import skfem_affine as sa  # noqa: E402
from skfem_affine.threads import serial_blas  # noqa: E402

MATERIALS = {"neohookean": sa.NeoHookean, "corotational": sa.Corotational, "stvk": sa.StVK}


def median_ms(f, calls=20, repeats=7):
    f()
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        for _ in range(calls):
            f()
        times.append((time.perf_counter() - t) / calls)
    return 1e3 * float(np.median(times))


def scene(args, material):
    if args.mesh is None:
        return sa.scenes.cantilever(resolution=args.resolution, material=material, damping=None)
    mesh = sa.io.load_mesh(args.mesh)
    z = mesh.p[2]
    body = sa.ElasticBody(mesh, material=material, density=100.0, fixed=np.flatnonzero(z < z.min() + 1e-6 * np.ptp(z)))
    return sa.Simulation(body, dt=0.01, gravity=(0.0, -9.8, 0.0), damping=sa.Rayleigh(alpha=0.03, beta=0.02))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--resolution", type=int, default=6)
    ap.add_argument("--mesh", default=None, help="MEDIT mesh instead of the cantilever")
    ap.add_argument("--warmup", type=int, default=20)
    ap.add_argument("--materials", nargs="+", default=list(MATERIALS), choices=list(MATERIALS))
    args = ap.parse_args(argv)
    print(f"{'material':>13} {'tets':>7} {'evaluate':>9} {'tangent':>8} {'stress':>7} {'force':>6} "
          f"{'scatter':>8} {'indefinite':>10}")
    for name in args.materials:
        sim = scene(args, MATERIALS[name](E=1e5, nu=0.35))
        for _ in range(args.warmup):
            sim.step()
        S, x = sim.system, sim.state.x
        with serial_blas():
            d = S.evaluate(x, project=False)
            indefinite = float(np.mean(np.linalg.eigvalsh(d.C).min(axis=1) < 0))
            ms = [median_ms(lambda: S.evaluate(x)), median_ms(lambda: S.evaluate_tangent(x)),
                  median_ms(lambda: S.stresses(d.F, tangent=False)), median_ms(lambda: S._internal_force(d.P)),
                  median_ms(lambda: S.pattern.scatter(d.He))]
        print(f"{name:>13} {S.m:7d} " + " ".join(f"{v:{w}.2f}" for v, w in zip(ms, (9, 8, 7, 6, 8)))
              + f" {100 * indefinite:9.0f}%", flush=True)


if __name__ == "__main__":
    main()
