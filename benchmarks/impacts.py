"""Fast impacts between bodies under PGS contact: penetration, passing through, inverted elements.

The measurements behind the body-body rows of docs/reliability.md ("Measured largest impact
speed without tunnelling"). Scenes (h = 0.01, no gravity, 15-20 frames each):

* ``cubes``: two 0.5 m cubes (4^3 cells, 384 tets each) 5 cm apart meeting head on, each at v;
  passed through = the mean x of the first cube ever exceeds the second's.
* ``bars``: two 1 m bars of 0.1 m section (5 cells) crossing like an X, each at v; only edges
  meet (no vertex of one comes near a face of the other); passed through = the mean x of the
  first bar's vertices within 0.1 m of the crossing ever exceeds the second's.
* ``plate``: a 0.1 m cube (2^3 cells) at v against a 2 cm plate (1 x 1 m, 8 x 8 cells, one
  element thick, E = 1e6) pinned at its rim; passed through = the plate's surface point closest
  to the cube's centre has a normal towards +x (the cube's centre is behind the plate).

Prints per scene and speed the largest recorded penetration (``sim.stats[i]["max_penetration"]``),
whether the bodies passed through each other, the largest number of inverted elements in a frame,
and ``SimulationDiverged`` when the divergence policy stopped the run. Usage::

    python benchmarks/impacts.py --E 1e5 1e7 --speeds 12.5 20 50 200
    python benchmarks/impacts.py --package /tmp/old/skfem_affine_old ...   # another version (renamed copy,
                                                                           # see benchmarks/contact_versions.py)
"""
import argparse
import importlib
import os
import sys
import warnings

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def pair(sa, first, second, speed, E_first, E_second, fixed_second=None, still_second=False):
    bodies = [sa.ElasticBody(first, sa.NeoHookean(E=E_first, nu=0.35), density=1000.0, velocity=(speed, 0, 0)),
              sa.ElasticBody(second, sa.NeoHookean(E=E_second, nu=0.35), density=1000.0,
                             velocity=(0, 0, 0) if still_second else (-speed, 0, 0), fixed=fixed_second)]
    return sa.Simulation(bodies, dt=0.01, gravity=(0, 0, 0), contact=sa.PGS())


def run(pkg, scene, speed, E):
    sa = pkg
    scenes = importlib.import_module(f"{pkg.__name__}.lab.scenes")
    geometry = importlib.import_module(f"{pkg.__name__}.contact.geometry")
    if scene == "cubes":
        first, second = (scenes.box_mesh(0.5, 4, (s * 0.275, 0, 0)) for s in (-1, 1))
        sim, frames = pair(sa, first, second, speed, E, E), 20
        middle = np.ones(first.nvertices + second.nvertices, dtype=bool)
    elif scene == "bars":
        first = scenes.box_mesh((0.1, 1.0, 0.1), (1, 5, 1), (-0.075, 0, 0))
        second = scenes.box_mesh((0.1, 0.1, 1.0), (1, 1, 5), (0.075, 0, 0))
        sim, frames = pair(sa, first, second, speed, E, E), 15
        middle = np.concatenate([np.abs(first.p[1]) < 0.11, np.abs(second.p[2]) < 0.11])
    else:
        first = scenes.box_mesh(0.1, 2, (-0.085, 0.03, 0.02))
        second = scenes.box_mesh((0.02, 1.0, 1.0), (1, 8, 8))
        rim = np.flatnonzero(np.abs(second.p[1:]).max(axis=0) > 0.499)
        sim, frames = pair(sa, first, second, speed, E, 1e6, fixed_second=rim, still_second=True), 12
        tris, owner = geometry.boundary_surface(sim.system)
        tris = tris[owner == 1]
    n0 = sim.system.vertex_offsets[1]
    through, stopped = False, ""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            for s in sim.run(frames):
                if scene == "plate":
                    c = s.x[:n0].mean(axis=0)[None]
                    *_, n = geometry.closest_surface_points(c, np.zeros(len(tris), dtype=int), np.arange(len(tris)),
                                                            s.x[tris], 1e-12)
                    through |= bool(n[0, 0] > 0)
                else:
                    through |= bool(s.x[:n0][middle[:n0], 0].mean() > s.x[n0:][middle[n0:], 0].mean())
    except sa.SimulationDiverged as err:
        stopped = f"SimulationDiverged at frame {err.frame}"
    pen = max((r["max_penetration"] for r in sim.stats), default=float("nan"))
    inv = max((r.get("inverted_elements") or 0 for r in sim.stats), default=0)
    return pen, through, inv, stopped


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--package", help="another version's package folder (renamed copy); default this checkout")
    p.add_argument("--scenes", nargs="+", default=["cubes", "bars", "plate"], choices=["cubes", "bars", "plate"])
    p.add_argument("--speeds", nargs="+", type=float, default=[12.5, 20.0, 50.0, 200.0])
    p.add_argument("--E", nargs="+", type=float, default=[1e5, 1e7], help="Young's modulus of the moving bodies")
    args = p.parse_args(argv)
    if args.package:
        from versions import load_other
        path = os.path.abspath(args.package)
        pkg = load_other(path, alias=os.path.basename(path))
    else:
        import skfem_affine as pkg
    print(f"{'scene':>6} {'E':>7} {'v m/s':>6} {'max pen m':>10} {'through':>8} {'inverted':>8}  stopped")
    for scene in args.scenes:
        for E in args.E:
            for v in args.speeds:
                pen, through, inv, stopped = run(pkg, scene, v, E)
                print(f"{scene:>6} {E:7.0e} {v:6g} {pen:10.2e} {str(through):>8} {inv:8d}  {stopped}", flush=True)


if __name__ == "__main__":
    main()
