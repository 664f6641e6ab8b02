"""``python -m skfem_affine compile``: compile every numba kernel of the package at once, into the disk cache.

The kernels are compiled on first use (:mod:`skfem_affine._compile_notice`), so a scene that
reaches contact, the clustering or the Newton integrators for the first time compiles those
there, in the middle of a run. :func:`warm_up` steps a few tiny scenes through every code path
(full space, affinification, rigidification, contact between bodies and against colliders, the
Newton integrators with the barrier, the adaptive subspace, and IPC where ipctk is installed),
so that afterwards every run loads its kernels from the cache.
"""
import sys
import time


def scenes():
    """``(what, simulation)`` of the tiny scenes :func:`warm_up` steps: one per code path of the kernels."""
    import skfem_affine as sa
    from skfem_affine.solvers import has_pardiso

    out = [("full space", sa.scenes.cantilever(resolution=1)),
           ("affinification", sa.scenes.cantilever(resolution=1, reducer=sa.Affinification(tau_a=0.1, tau_e=0.2))),
           ("rigidification", sa.scenes.cantilever(resolution=1, reducer=sa.Rigidification(tau_r=0.1, tau_e=0.2))),
           ("contact with a collider", sa.scenes.drop(resolution=1)),
           ("contact between bodies", sa.scenes.stacked_beams(resolution=1)),
           ("contact between reduced bodies", sa.scenes.stacked_beams(resolution=1, reducer=sa.Affinification(
               tau_a=0.5, tau_e=1.0))),
           ("reduced bodies pushed out of each other", _pressed_ball(sa)),
           ("Newton with the barrier", sa.scenes.cantilever(
               resolution=1, integrator="implicit_euler", colliders=[sa.Plane(point=(0, 0, -1.0), normal=(0, 0, 1))])),
           ("adaptive subspace", sa.scenes.cantilever(
               resolution=1, integrator="implicit_euler",
               reducer=sa.AdaptiveSubspace(basis=sa.SkinningEigenmodes(n=4, cache=False), subdomains=1)))]
    if not has_pardiso():
        out.append(("full space, SuperLU", sa.scenes.cantilever(resolution=1, solver="superlu")))
    try:
        import ipctk  # noqa: F401
    except ModuleNotFoundError:
        pass
    else:
        out.append(("IPC between bodies", sa.scenes.stacked_beams(resolution=1, integrator="implicit_euler",
                                                                   contact=sa.IPC())))
    return out


def _pressed_ball(sa):
    """A stiff ball starting inside a soft pad on a plane, reduced: the split impulse that pushes
    penetrations out (low-rank PGS) and the oracle's coarse guess over several bodies."""
    ball = sa.ElasticBody(sa.scenes.ball_mesh(0.2, 1, center=(0.0, 0.0, 0.25)), material=sa.NeoHookean(E=1e7, nu=0.3),
                          density=1500.0)
    pad = sa.ElasticBody(sa.scenes.box_mesh((1.0, 1.0, 0.2), (3, 3, 1), center=(0.0, 0.0, 0.1)),
                         material=sa.NeoHookean(E=2e4, nu=0.3), density=200.0)
    return sa.Simulation([ball, pad], dt=0.01, gravity=(0, 0, -9.81), colliders=[sa.Plane()],
                         reducer=sa.Affinification(tau_a=0.5, tau_e=1.0))


def warm_up(frames=3, stream=None):
    """Step each of :func:`scenes` for ``frames`` frames, so that their kernels are compiled (or
    loaded) and in the disk cache; returns the seconds it took."""
    t0 = time.perf_counter()
    for what, sim in scenes():
        for _ in sim.run(frames):
            pass
        if stream is not None:
            print(f"  {what}: done at {time.perf_counter() - t0:.0f} s", file=stream, flush=True)
    return time.perf_counter() - t0


def main(argv=None):
    """The ``compile`` command: :func:`warm_up`, saying how long it took."""
    if argv:
        print(f"skfem-affine compile: takes no arguments, got {' '.join(argv)}", file=sys.stderr)
        return 2
    t0, cpu = time.perf_counter(), time.process_time()
    print("skfem-affine: compiling every numba kernel into the disk cache ...", file=sys.stderr, flush=True)
    warm_up(stream=sys.stderr)
    print(f"skfem-affine: the kernels are in the disk cache ({time.perf_counter() - t0:.0f} s, "
          f"{time.process_time() - cpu:.0f} s of CPU)", file=sys.stderr, flush=True)
    return 0
