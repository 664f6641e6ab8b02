"""Contact scenes of this checkout against another version of the package, in one process.

The contact counterpart of ``benchmarks/versions.py``: both versions' simulations of the same
contact scene (``skfem_affine.lab.scenes``, linearized integrator, PGS contact) are stepped in
turn, frame by frame, so that the load of a shared machine hits both alike. Prints the wall time
of each version, their ratio, the median over frames of the per-frame ratio (less sensitive to
load spikes), the mean contacts per frame of each, and the largest vertex distance between the
two trajectories relative to the scene's size.

The package imports itself by absolute name, so the other version is a copy renamed, e.g.::

    mkdir -p /tmp/old && cp -r /work/main/skfem_affine /tmp/old/skfem_affine_old
    grep -rl skfem_affine /tmp/old/skfem_affine_old | xargs sed -i 's/skfem_affine\\b/skfem_affine_old/g'
    python benchmarks/contact_versions.py /tmp/old/skfem_affine_old --scenes stacked_beams pills --frames 60
"""
import argparse
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
import skfem_affine as sa  # noqa: E402
from versions import load_other, race  # noqa: E402

SCENES = {"stacked_beams": dict(resolution=2, n=3), "pills": dict(n=8, resolution=1),
          "drop": dict(resolution=2, shape="box")}


def make(pkg, scene):
    import importlib
    scenes = importlib.import_module(f"{pkg.__name__}.lab.scenes")
    return getattr(scenes, scene)(**SCENES[scene])


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("other", help="the other version's package folder (renamed, see above)")
    p.add_argument("--scenes", nargs="+", default=["stacked_beams", "pills"], choices=sorted(SCENES))
    p.add_argument("--frames", type=int, default=60)
    p.add_argument("--detection", action="store_true",
                   help="also time contact detection alone: both versions' detectors on the same states")
    args = p.parse_args(argv)
    path = os.path.abspath(args.other)
    other = load_other(path, alias=os.path.basename(path))
    for pkg in (other, sa):  # compile (or load from numba's cache) both versions' kernels
        race([make(pkg, s) for s in args.scenes], 2)
    print(f"{'scene':>14} {'other_s':>8} {'this_s':>8} {'this/other':>10} {'median frame ratio':>18} "
          f"{'contacts':>15} {'max |dx|/size':>13}")
    for scene in args.scenes:
        sims = [make(other, scene), make(sa, scene)]
        times = np.array([race(sims, 1) for _ in range(args.frames)])  # (frames, 2), in turn
        walls = times.sum(axis=0)
        dx = np.abs(sims[0].state.x - sims[1].state.x).max() / sims[1].size
        nc = [np.mean([r.get("n_contacts", 0) for r in s.stats]) for s in sims]
        print(f"{scene:>14} {walls[0]:8.2f} {walls[1]:8.2f} {walls[1] / walls[0]:10.3f} "
              f"{np.median(times[:, 1] / times[:, 0]):18.3f} {nc[0]:7.1f}/{nc[1]:7.1f} {dx:13.1e}", flush=True)
        if args.detection:
            print(f"{'':>14} detection per frame: other {detection(sims, args.frames):s}", flush=True)


def detection(sims, frames, repeats=3):
    """Both versions' contact detection on the states of a fresh run of this version, in turn;
    mean milliseconds per frame of each, as a string."""
    import time
    fresh = make(sa, sims[1].scene)
    states = [(s.x.copy(), s.v.copy()) for s in fresh.run(frames)]
    dets = [sim.contact.detector for sim in sims]
    ms = np.zeros(2)
    for _ in range(repeats):
        for x, v in states:
            for i, det in enumerate(dets):
                t0 = time.perf_counter()
                det.find(x, v, fresh.model.dt)
                ms[i] += time.perf_counter() - t0
    ms *= 1e3 / (repeats * len(states))
    return f"{ms[0]:.2f} ms, this {ms[1]:.2f} ms"


if __name__ == "__main__":
    main()
