"""What ``volumetric="nodal"`` costs per frame, against the default ``"element"``.

A clamped beam (1 x 0.1 x 0.3 m, ``--cells`` cells along, a tenth of them across and three
tenths over the height, 6 tets a cell), stable Neo-Hookean E = 1e6, nu = 0.49, under gravity,
dt = 0.01, in full space and under ``Affinification(target_error=0.05)``. The simulations are
stepped in turn, frame by frame, in this process; per frame the CPU time (time.process_time) and
the wall time of ``Simulation.step``, their medians over the frames after ``--warmup``. Run with one
thread::

    OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 MKL_NUM_THREADS=1 NUMBA_NUM_THREADS=1 \\
        python benchmarks/nodal_volume.py --cells 30 --frames 30
"""
import argparse
import os
import sys
import time
import warnings

import numpy as np
import skfem

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
import skfem_affine as sa  # noqa: E402


def simulation(mesh, volumetric, reducer):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", sa.SimulationWarning)  # the locking warning of "element"
        body = sa.ElasticBody(mesh, sa.NeoHookean(E=1e6, nu=0.49), fixed=mesh.p[0] < 1e-9, volumetric=volumetric)
    return sa.Simulation(body, dt=0.01, gravity=(0, 0, -9.81), reducer=reducer)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cells", type=int, default=30, help="cells along the beam")
    ap.add_argument("--frames", type=int, default=30)
    ap.add_argument("--warmup", type=int, default=5)
    a = ap.parse_args()
    k = a.cells
    mesh = skfem.MeshTet.init_tensor(np.linspace(0, 1, k + 1), np.linspace(0, 0.1, max(k // 10, 1) + 1),
                                     np.linspace(0, 0.3, max(3 * k // 10, 1) + 1))
    sims = {}
    for reducer in ("full", "affinification"):
        for volumetric in ("element", "nodal"):
            r = None if reducer == "full" else sa.Affinification(target_error=0.05, never_slower=False)
            sims[(reducer, volumetric)] = simulation(mesh, volumetric, r)
    cpu = {key: [] for key in sims}
    wall = {key: [] for key in sims}
    for frame in range(a.frames):
        for key, sim in sims.items():
            c0, w0 = time.process_time(), time.perf_counter()
            sim.step()
            cpu[key].append(time.process_time() - c0)
            wall[key].append(time.perf_counter() - w0)
    print(f"{mesh.t.shape[1]} tets, {mesh.p.shape[1]} vertices, {a.frames} frames ({a.warmup} warm-up)")
    print(f"{'reducer':16s} {'volumetric':10s} {'cpu ms':>8s} {'wall ms':>8s} {'cpu ratio':>9s} {'tip z':>9s}")
    tip = np.flatnonzero(mesh.p[0] > 1 - 1e-9)
    for (reducer, volumetric), sim in sims.items():
        c, w = 1e3 * np.median(cpu[(reducer, volumetric)][a.warmup:]), 1e3 * np.median(wall[(reducer, volumetric)][a.warmup:])
        base = 1e3 * np.median(cpu[(reducer, "element")][a.warmup:])
        dz = sim.state.x[tip, 2].mean() - mesh.p[2, tip].mean()
        print(f"{reducer:16s} {volumetric:10s} {c:8.1f} {w:8.1f} {c / base:9.2f} {dz:9.4f}")


if __name__ == "__main__":
    main()
