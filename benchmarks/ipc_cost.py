"""Per-step cost of IPC contact (ipctk, contact/ipc.py) against the plain barrier (contact/barrier.py).

The same drop scene (a soft cube or ball thrown at a plane, full-space implicit Euler) runs
with both contact models, interleaved in chunks of frames in one process so that the machine's
load hits both alike. Prints per run: ms per step, Newton iterations per step, ms per Newton
iteration, the share of the step spent in the contact calls (energy, gradient, Hessian, CCD) and
the lowest gap to the plane. Usage::

    python benchmarks/ipc_cost.py --resolution 3 --frames 60 --chunk 5
"""
import argparse
import os
import sys
import time

THREADS = sys.argv[sys.argv.index("--threads") + 1] if "--threads" in sys.argv else "1"
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, THREADS)

import ipctk  # noqa: E402
import numpy as np  # noqa: E402

import skfem_affine as sa  # noqa: E402
from skfem_affine.contact import ipc  # noqa: E402
from skfem_affine.integrators import newton  # noqa: E402


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


class IPCPotential(newton.IncrementalPotential):
    """The incremental potential with IPC contact (the wiring the Simulation is to get)."""

    def __init__(self, sim, x_t, v_t, contact):
        super().__init__(sim, x_t, v_t, contact=contact)
        contact.begin_step(self.x_t, self.x_hat, self.c)

    def hessian(self, H, x=None):
        A = super().hessian(H, x)
        if x is not None:
            A = A + self.weight * self.contact.hessian(x)
        return A.tocsr()


def scene(args):
    sim = sa.scenes.free_body(resolution=args.resolution, shape=args.shape, size=0.5, velocity=(0, 0, -2.0),
                              spin=(0, 0, 0), gravity=(0, 0, -9.81), integrator="implicit_euler",
                              dt=args.dt, solver="direct")
    plane = sa.Plane((0, 0, -0.3), (0, 0, 1))
    return sim, plane


class BarrierRun:
    name = "barrier"

    def __init__(self, args):
        self.sim, self.plane = scene(args)
        self.sim.colliders = [self.plane]
        self.sim.step()  # builds the stepper's contact, which is then timed
        self.contact = Timed(self.sim.stepper.contact)
        self.sim.stepper.contact = self.contact
        self.sim.stepper._colliders = tuple(self.sim.colliders)
        self.steps, self.seconds, self.iters, self.gap = 0, 0.0, 0, np.inf

    def frames(self, n):
        for _ in range(n):
            t0 = time.perf_counter()
            self.sim.step()
            self.seconds += time.perf_counter() - t0
            self.iters += self.sim.stats[-1]["newton_iters"]
            self.steps += 1
            self.gap = min(self.gap, float(self.plane.query(self.sim.state.x)[0].min()))


class IPCRun(BarrierRun):
    name = "ipc"

    def __init__(self, args):
        self.sim, self.plane = scene(args)
        self.contact = Timed(ipc.IPCContact(self.sim, [self.plane], ipc.IPC(friction=args.friction)))
        self.x = self.sim.state.x.reshape(-1).copy()
        self.v = self.sim.state.v.reshape(-1).copy()
        self.steps, self.seconds, self.iters, self.gap = 0, 0.0, 0, np.inf
        self.frames(1)  # as the barrier run: the first step is not timed
        self.steps, self.seconds, self.iters, self.gap, self.contact.seconds = 0, 0.0, 0, np.inf, 0.0

    def frames(self, n):
        for _ in range(n):
            t0 = time.perf_counter()
            ip = IPCPotential(self.sim, self.x, self.v, self.contact)
            rec = {}
            x = newton.newton_solve(ip, self.sim.newton_tol, self.sim.newton_iters, self.sim.solve, rec)
            self.v, self.x = ip.velocity(x), x
            self.seconds += time.perf_counter() - t0
            self.iters += rec["newton_iters"]
            self.steps += 1
            self.gap = min(self.gap, float(self.plane.query(self.x.reshape(-1, 3))[0].min()))


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
    runs = [BarrierRun(args), IPCRun(args)]
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
