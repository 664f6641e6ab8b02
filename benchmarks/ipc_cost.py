"""Per-step cost of IPC contact (ipctk, contact/ipc.py) against the plain barrier (contact/barrier.py).

The same drop scene (a soft cube or ball thrown at a plane, full-space implicit Euler) runs
with both contact models (``Simulation(..., contact=None)`` and ``contact=sa.IPC(...)``), interleaved in chunks of frames in one process so that the machine's
load hits both alike. Prints per run: ms per step, Newton iterations per step, ms per Newton
iteration, the share of the step spent in the contact calls (energy, gradient, Hessian, CCD) and
the lowest gap to the plane. Usage::

    python benchmarks/ipc_cost.py --resolution 3 --frames 60 --chunk 5
"""
import argparse
import os
import sys
sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
import time

THREADS = sys.argv[sys.argv.index("--threads") + 1] if "--threads" in sys.argv else "1"
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, THREADS)

import ipctk  # noqa: E402
import numpy as np  # noqa: E402

import skfem_affine as sa  # noqa: E402


class Timed:
    """Wraps a contact object and adds the time of its calls to ``self.seconds``."""

    def __init__(self, contact):
        self.contact, self.seconds = contact, 0.0

    def __getattr__(self, name):
        attr = getattr(self.contact, name)
        if not callable(attr):
            return attr

        def call(*args, **kw):
            t0 = time.perf_counter()
            try:
                return attr(*args, **kw)
            finally:
                self.seconds += time.perf_counter() - t0
        return call


def scene(args, contact):
    """The drop scene with ``contact=None`` (the plain barrier) or ``sa.IPC(...)``."""
    plane = sa.Plane((0, 0, -0.3), (0, 0, 1))
    sim = sa.scenes.free_body(resolution=args.resolution, shape=args.shape, size=0.5, velocity=(0, 0, -2.0),
                              spin=(0, 0, 0), gravity=(0, 0, -9.81), integrator="implicit_euler",
                              dt=args.dt, solver="direct", colliders=[plane], contact=contact)
    return sim, plane


class Run:
    """One contact model's simulation, its contact calls timed (the integrator's contact object wrapped)."""

    def __init__(self, name, args, contact):
        self.name = name
        self.sim, self.plane = scene(args, contact)
        self.sim.step()  # not timed: first-step set-up
        self.contact = Timed(self.sim.integrator.barrier)
        self.sim.integrator.barrier = self.contact
        self.steps, self.seconds, self.iters, self.gap = 0, 0.0, 0, np.inf

    def frames(self, n):
        for _ in range(n):
            t0 = time.perf_counter()
            self.sim.step()
            self.seconds += time.perf_counter() - t0
            self.iters += self.sim.stats[-1]["newton_iters"]
            self.steps += 1
            self.gap = min(self.gap, float(self.plane.query(self.sim.state.x)[0].min()))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--resolution", type=int, default=3)
    ap.add_argument("--shape", default="cube", choices=["cube", "ball"])
    ap.add_argument("--frames", type=int, default=60)
    ap.add_argument("--chunk", type=int, default=5)
    ap.add_argument("--dt", type=float, default=0.01)
    ap.add_argument("--friction", type=float, default=0.0)
    ap.add_argument("--threads", default="1", help="BLAS/MKL and ipctk (TBB) threads")
    args = ap.parse_args(argv)
    ipctk.set_num_threads(int(args.threads))
    runs = [Run("barrier", args, None), Run("ipc", args, sa.IPC(friction=args.friction))]
    for _ in range(0, args.frames, args.chunk):
        for r in runs:
            r.frames(args.chunk)
    n_tets = runs[0].sim.system.m
    print(f"{args.shape} res {args.resolution} ({n_tets} tets), {args.frames} frames, dt {args.dt}, "
          f"friction {args.friction}, threads {args.threads}")
    print("model    ms/step  iters/step  ms/iter  contact %   lowest gap / dhat")
    for r in runs:
        print(f"{r.name:8s} {1e3 * r.seconds / r.steps:7.1f}  {r.iters / r.steps:10.2f}  "
              f"{1e3 * r.seconds / r.iters:7.2f}  {100 * r.contact.seconds / r.seconds:8.0f}   "
              f"{r.gap / r.contact.dhat:.2f}")
    b, i = runs
    print(f"ratio ipc/barrier: per step {i.seconds / i.steps / (b.seconds / b.steps):.2f}, "
          f"per Newton iteration {i.seconds / i.iters / (b.seconds / b.iters):.2f}")


if __name__ == "__main__":
    main()
