"""What pinned affine bodies save on the cantilever: Affinification(pinned_bodies=False | True) against full space.

The cantilever (4 x 1 x 1, clamped at x = 0, Neo-Hookean E 1e5, nu 0.35, rho 100, Rayleigh
0.03 / 0.02, h 0.01, gravity) runs in full space and with affinification, with the elements
touching the clamp kept elastic (the paper's) and allowed into affine bodies (``pinned_bodies``).
Printed per method: the mean DOF ratio (reduced / full DOFs), the max distance error against the
full run relative to the beam's size, and the mean fraction of clamp-touching elements that were
in a body. Timings are not reported (compare ``sim.stats`` on an idle machine).

    python benchmarks/pinned_bodies.py --resolution 3 --frames 200
"""
import argparse

import numpy as np
import skfem

import skfem_affine as sa


def cantilever(resolution):
    k = resolution
    mesh = skfem.MeshTet.init_tensor(np.linspace(0, 4, 4 * k + 1), np.linspace(0, 1, k + 1), np.linspace(0, 1, k + 1))
    clamp = mesh.nodes_satisfying(lambda p: p[0] < 1e-9)
    return sa.ElasticBody(mesh, sa.NeoHookean(E=1e5, nu=0.35), density=100.0, fixed=clamp)


def run(body, frames, reducer):
    """Positions (frames, n, 3) and per-element labels (frames, m) of a run (labels None in full space)."""
    sim = sa.Simulation(body, dt=0.01, gravity=(0, 0, -9.81), damping=sa.Rayleigh(0.03, 0.02), reducer=reducer)
    states = list(sim.run(frames))
    return sim, np.array([s.x for s in states]), [s.clusters for s in states]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--resolution", type=int, default=3)
    ap.add_argument("--frames", type=int, default=200)
    ap.add_argument("--tau", type=float, nargs=2, default=(2e-4, 1e-4), help="tau_a tau_e")
    args = ap.parse_args(argv)
    body = cantilever(args.resolution)
    full, xf, _ = run(body, args.frames, None)
    n_full = full.stats[-1]["dofs"]
    touching = np.any(full.system.fixed[full.system.t], axis=0)
    print(f"cantilever: {full.system.m} tets ({int(touching.sum())} touch the clamp), {n_full} full DOFs, "
          f"{args.frames} frames, tau {args.tau[0]:g} / {args.tau[1]:g}")
    print(f"{'pinned_bodies':>14} {'DOF ratio':>10} {'max err':>10} {'clamp elements in bodies':>25}")
    for pinned in (False, True):
        sim, x, labels = run(body, args.frames, sa.Affinification(*args.tau, pinned_bodies=pinned))
        ratio = np.mean([r["dofs"] for r in sim.stats]) / n_full
        err = np.abs(x - xf).max() / full.size
        in_bodies = np.mean([np.mean(lab[touching] >= 0) for lab in labels])
        print(f"{str(pinned):>14} {ratio:10.3f} {err:10.2e} {in_bodies:25.3f}")


if __name__ == "__main__":
    main()
