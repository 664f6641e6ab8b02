"""This checkout against another version of the package, stepped frame by frame in one process.

A refactor must not slow a frame down. Timing two versions in two processes on a shared
machine mixes the change with the load of the moment; here both versions are imported into
one process (the other version under another package name) and their simulations of the same
scene are stepped in turn, frame by frame, so that load hits both alike. Prints the wall time
of each version, their ratio, and the largest vertex distance between the two trajectories.

The other version is a copy of the ``skfem_affine`` package folder whose modules import each
other relatively (as this package did up to its re-layout), e.g.::

    mkdir -p /tmp/old && git archive 7e632f5 skfem_affine | tar -x -C /tmp/old
    python benchmarks/versions.py /tmp/old/skfem_affine --meshes PATH/beam1264.mesh PATH/beam5232.mesh \\
        --frames 100
"""
import argparse
import importlib.util
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
import skfem_affine as sa  # noqa: E402


def load_other(package_dir, alias="skfem_affine_other"):
    """Import the package folder ``package_dir`` under the name ``alias``."""
    init = os.path.join(package_dir, "__init__.py")
    if not os.path.isfile(init):
        raise SystemExit(f"error: {package_dir} is not a package folder (no __init__.py)")
    spec = importlib.util.spec_from_file_location(alias, init, submodule_search_locations=[package_dir])
    module = importlib.util.module_from_spec(spec)
    sys.modules[alias] = module
    spec.loader.exec_module(module)
    return module


def beam(pkg, path, material, reducer):
    """The paper's beam scene (z-min end pinned, gravity along -y, rho 100, Rayleigh 0.03 / 0.02)."""
    mesh = pkg.io.load_mesh(path)
    z = mesh.p[2]
    fixed = np.flatnonzero(z < z.min() + 1e-6 * np.ptp(z))
    mat = getattr(pkg, material)(E=1e5, nu=0.35)
    body = pkg.ElasticBody(mesh, material=mat, density=100.0, fixed=fixed)
    return pkg.Simulation(body, dt=0.01, gravity=(0.0, -9.8, 0.0), damping=pkg.Rayleigh(alpha=0.03, beta=0.02),
                          solver="pardiso" if pkg.solvers.has_pardiso() else "superlu",
                          reducer=None if reducer is None else getattr(pkg, reducer[0])(*reducer[1:]))


def race(sims, frames):
    """Step every simulation once per frame, in turn; wall seconds of each."""
    walls = np.zeros(len(sims))
    for _ in range(frames):
        for i, sim in enumerate(sims):
            t0 = time.perf_counter()
            sim.step()
            walls[i] += time.perf_counter() - t0
    return walls


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("other", help="the other version's skfem_affine package folder")
    p.add_argument("--meshes", nargs="+", required=True, help="MEDIT beam meshes")
    p.add_argument("--frames", type=int, default=100)
    p.add_argument("--material", default="NeoHookean", choices=["NeoHookean", "StVK", "Corotational"])
    p.add_argument("--taus", nargs="*", default=["0.1,0.2"], help="affinification tau_a,tau_e pairs")
    args = p.parse_args(argv)
    other = load_other(os.path.abspath(args.other))
    methods = [None] + [("Affinification", *map(float, t.split(","))) for t in args.taus]
    # compile (or load from numba's cache) both versions' kernels before timing
    for pkg in (other, sa):
        race([beam(pkg, args.meshes[0], args.material, m) for m in methods], 3)
    print(f"{'mesh':>12} {'method':>22} {'other_s':>8} {'this_s':>8} {'this/other':>10} {'max |dx|/size':>13}")
    for path in args.meshes:
        for m in methods:
            sims = [beam(other, path, args.material, m), beam(sa, path, args.material, m)]
            walls = race(sims, args.frames)
            dx = np.abs(sims[0].state.x - sims[1].state.x).max() / sims[1].size
            name = "full" if m is None else f"affine {m[1]:g},{m[2]:g}"
            print(f"{os.path.basename(path):>12} {name:>22} {walls[0]:8.2f} {walls[1]:8.2f} "
                  f"{walls[1] / walls[0]:10.3f} {dx:13.1e}", flush=True)


if __name__ == "__main__":
    main()
