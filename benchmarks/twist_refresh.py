"""The oracle follows the pose: affinification on a twisting beam with and without preconditioner refresh.

A beam (length 4, section 1 x 1) is clamped at x = 0 while its other end is turned about the
beam's axis by ``--step`` degrees every ``--period`` seconds (``sa.Prescribed``), producing a
progressive twist with pauses in which the beam settles (the paper's Fig. 9). Affinification runs with the oracle's preconditioner factorised at rest
(``refresh=False``, the paper's) and rebuilt at the pose when its residual grows
(``refresh="laplacian"``, ``"tangent"``); a full-space run is the reference. Printed per method,
over the late part of the twist (the last ``--late`` fraction of the frames): the DOF ratio
(reduced DOFs / full DOFs, mean), the max distance error against the full run (relative to the
beam's size, max over those frames), the oracle's mean residual and the number of refreshes,
each averaged over ``--seeds`` clustering seeds (single runs differ by seed as much as by method).
Timings are not reported (compare them on an idle machine with ``sim.stats``).

    python benchmarks/twist_refresh.py --resolution 3 --frames 400 --tau 5e-2 2.5e-2
    python benchmarks/twist_refresh.py --scene --resolution 2 --frames 400 --tau 1.1e-3 1e-3
"""
import argparse
import sys

import numpy as np
import skfem

import skfem_affine as sa


def twist_angle(t, step, period, turning):
    """Successive rotations: ``step`` rad over the first ``turning`` s of every ``period`` s (smoothstep), then a hold."""
    k, r = np.divmod(t, period)
    u = np.clip(r / turning, 0.0, 1.0)
    return step * (k + u * u * (3 - 2 * u))


def twisting_beam(resolution=3, length=4.0, step=np.pi / 2, period=1.0, turning=0.3, E=1e5, nu=0.38,
                  density=100.0):
    """The beam, clamped at x = 0, its end at x = length turned by ``step`` rad every ``period`` s."""
    k = resolution
    mesh = skfem.MeshTet.init_tensor(np.linspace(0, length, 4 * k + 1), np.linspace(0, 1, k + 1),
                                     np.linspace(0, 1, k + 1))
    clamp = mesh.nodes_satisfying(lambda p: p[0] < 1e-9)
    end = mesh.nodes_satisfying(lambda p: p[0] > length - 1e-9)
    centre = np.array([0.0, 0.5, 0.5])

    def turn(t, X):
        a = twist_angle(t, step, period, turning)
        c, s = np.cos(a), np.sin(a)
        return (X - centre) @ np.array([[1, 0, 0], [0, c, s], [0, -s, c]]) + centre

    body = sa.ElasticBody(mesh, sa.NeoHookean(E=E, nu=nu), density=density, fixed=clamp,
                          prescribed=sa.Prescribed(end, turn))
    return body


def run(body, frames, reducer, dt=0.01, damping=None):
    sim = sa.Simulation(body, dt=dt, reducer=reducer, damping=damping)
    xs = [s.x for s in sim.run(frames)]
    return sim, np.array(xs)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--resolution", type=int, default=3)
    ap.add_argument("--frames", type=int, default=300)
    ap.add_argument("--step", type=float, default=90.0, help="rotation of the end per period (degrees)")
    ap.add_argument("--period", type=float, default=1.0, help="s between rotations (each over 0.3 s)")
    ap.add_argument("--damping", type=float, nargs=2, default=(0.03, 0.02), help="Rayleigh alpha beta")
    ap.add_argument("--E", type=float, default=1e5)
    ap.add_argument("--tau", type=float, nargs=2, default=(2e-4, 1e-4), help="tau_a tau_e")
    ap.add_argument("--late", type=float, default=1 / 3, help="fraction of the frames reported")
    ap.add_argument("--seeds", type=int, default=3, help="clustering seeds averaged over (runs differ by seed)")
    ap.add_argument("--scene", action="store_true",
                    help="the registered scene sa.scenes.twisting_beam instead (continuous twist at pi/4 rad/s, "
                         "the paper's E 5e3 unless --E is given)")
    args = ap.parse_args(argv)
    damping = sa.Rayleigh(*args.damping)
    if args.scene:
        E = args.E if "--E" in (argv if argv is not None else sys.argv) else 5e3
        body = sa.scenes.twisting_beam(args.resolution, E=E, damping=damping).bodies[0]
        args.E = E
    else:
        body = twisting_beam(args.resolution, step=np.radians(args.step), period=args.period, E=args.E)
    full, xf = run(body, args.frames, None, damping=damping)
    n_full = full.stats[-1]["dofs"]
    late = slice(int(round((1 - args.late) * args.frames)), args.frames)
    size = full.size
    how = "sa.scenes.twisting_beam" if args.scene else f"{args.step:g} deg every {args.period:g} s"
    print(f"twisting beam: {full.system.m} tets, {n_full} full DOFs, {args.frames} frames, {how}, "
          f"E {args.E:g}; late frames {late.start}-{late.stop}")
    print(f"{'refresh':>10} {'DOF ratio':>10} {'max err':>10} {'oracle res':>11} {'refreshes':>10}")
    for refresh in (False, "laplacian", "tangent"):
        rows = []
        for seed in range(args.seeds):
            red = sa.Affinification(*args.tau, refresh=refresh, seed=seed)
            sim, x = run(body, args.frames, red, damping=damping)
            rows.append((np.mean([r["dofs"] for r in sim.stats[late]]) / n_full,
                         np.abs(x[late] - xf[late]).max() / size,
                         np.mean([r.get("oracle_residual", np.nan) for r in sim.stats[late]]), red.refreshes))
        ratio, err, res, count = np.mean(rows, axis=0)
        print(f"{str(refresh):>10} {ratio:10.3f} {err:10.2e} {res:11.3f} {count:10.1f}")


if __name__ == "__main__":
    main()
