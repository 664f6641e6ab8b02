"""The CPU time of each part of a resting pile's contact phase, and of the frame outside contact.

The pile of ``benchmarks/budget.py`` (four soft boxes on the ground, ``--cells`` per box edge) under one
method (``--method``, default affinification at tau_a = 1e-4, tau_e = 2e-4) runs from frame 0; over the
frames ``--start`` to ``--end`` the contact functions are timed by the CPU time of the calling thread
(``time.thread_time``: a loaded machine inflates it far less than wall time, and no profiler adds its
overhead), their callees included, and the frame by the CPU time of the process (``time.process_time``,
the worker threads of the element passes included). One BLAS/MKL thread. Prints ms per frame:

- detection: ``find`` (of it ``_body_contacts`` with ``closest_surface_points``, the sharp edges'
  ``frame`` and ``find``, ``_reach``), the Jacobian, the warm start, the prediction impulses;
- resolve: the Delassus operator (the Resolvent made and ``delassus``), the PGS sweeps, the residual's
  report, the velocity correction (``apply``), the split impulse (``_rigid_motions`` and its low-rank
  PGS);
- the frame, its contact (detection and resolve) and the rest.

``--dense 160,0`` runs the method once per value of the largest body block whose part of the Delassus
operator comes from its dense Cholesky factor (``skfem_affine.contact.dense``; 0: every block's unit
columns solved with the frame's factorisation), stepped in turn frame by frame in one process.

Usage::

    python benchmarks/contact_cpu.py --cells 4 --start 100 --end 119
    python benchmarks/contact_cpu.py --cells 4 --start 100 --end 119 --dense 160,0
"""
import argparse
import os
import sys
import time

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import numpy as np  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))  # measure the checkout this script sits in
sys.path.insert(0, HERE)
import skfem_affine as sa  # noqa: E402
from skfem_affine.contact import delassus, geometry, pgs  # noqa: E402
from skfem_affine.contact.dense import DENSE_MAX  # noqa: E402

METHODS = {"affinification": lambda: sa.Affinification(tau_a=1e-4, tau_e=2e-4),
           "rigidification": lambda: sa.Rigidification(tau_r=1e-4, tau_e=2e-4), "full": lambda: None}


REPLACED = []  # (owner, name, original) of every function timed, restored at the end of main


def timed(owner, name, label, spent):
    """Replace ``owner.name`` by a wrapper adding its thread CPU time (s) to ``spent[0][label]`` (``spent``: a
    one-entry list holding the dict of the run being stepped)."""
    fn = getattr(owner, name)
    REPLACED.append((owner, name, fn))

    def call(*args, **kwargs):
        t0 = time.thread_time()
        try:
            return fn(*args, **kwargs)
        finally:
            spent[0][label] = spent[0].get(label, 0.0) + time.thread_time() - t0

    setattr(owner, name, call)


class _Holder:
    """An entry of a dict as the attribute ``fn``, so that :func:`timed` can replace it."""

    def __init__(self, table, key):
        self.table, self.key = table, key

    @property
    def fn(self):
        return self.table[self.key]

    @fn.setter
    def fn(self, value):
        self.table[self.key] = value


def instrument(sim, spent):
    """Time the contact functions of ``sim`` (module docstring) into ``spent`` (:func:`timed`); the module
    functions once per process (``sim`` None: only them, else only the simulation's own)."""
    if sim is not None:
        c, d = sim.contact, sim.contact.detector
        for name in ("detect", "resolve", "_warm_start", "_predicted_impulses", "_rigid_motions", "_report"):
            timed(c, name, name, spent)
        for name in ("find", "_body_contacts", "_reach"):
            timed(d, name, name, spent)
        if d.edge_pairs is not None:
            for name in ("frame", "find"):
                timed(d.edge_pairs, name, f"edges.{name}", spent)
        return
    timed(geometry, "closest_surface_points", "closest_surface_points", spent)
    timed(pgs, "jacobian", "jacobian", spent)
    timed(pgs, "projected_gauss_seidel_lowrank", "split-impulse PGS", spent)
    for key in list(pgs.SOLVERS):  # the PGS iterations, looked up in this dict by name at each frame
        timed(_Holder(pgs.SOLVERS, key), "fn", "PGS sweeps", spent)
    for name in ("delassus", "apply", "__init__"):
        timed(delassus.Resolvent, name, f"Resolvent.{name}", spent)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cells", type=int, default=4, help="cells per box edge")
    ap.add_argument("--method", choices=sorted(METHODS), default="affinification")
    ap.add_argument("--start", type=int, default=100)
    ap.add_argument("--end", type=int, default=119)
    ap.add_argument("--dense", default=str(DENSE_MAX),
                    help="comma-separated largest dense blocks, one run each, stepped in turn")
    args = ap.parse_args(argv)
    from budget import pile
    values = [int(v) for v in args.dense.split(",")]
    sims = [pile(args.cells, METHODS[args.method]()) for _ in values]
    spent, frame = [{} for _ in values], [0.0 for _ in values]
    current, dense = [None], pgs.DENSE_MAX
    instrument(None, current)
    try:
        for frame_no in range(args.end):
            if frame_no == args.start:  # the module functions were timed from frame 0: count from here
                for sim, used in zip(sims, spent):
                    instrument(sim, current)
                    used.clear()
            for i in (range(len(sims)) if frame_no % 2 else reversed(range(len(sims)))):
                pgs.DENSE_MAX, current[0] = values[i], spent[i]
                t0 = time.process_time()
                sims[i].step()
                if frame_no >= args.start:
                    frame[i] += time.process_time() - t0
    finally:  # the modules as they were (the script may run inside another program's process)
        pgs.DENSE_MAX = dense
        while REPLACED:
            owner, name, fn = REPLACED.pop()
            setattr(owner, name, fn)
    n = args.end - args.start
    out = []
    for value, sim, used, total in zip(values, sims, spent, frame):
        ms = {k: 1e3 * v / n for k, v in used.items()}
        contact = ms.get("detect", 0.0) + ms.get("resolve", 0.0)
        recs = sim.stats[args.start:args.end]
        print(f"pile of {args.cells}-cell boxes, {args.method}, dense blocks up to {value} unknowns, frames "
              f"{args.start}-{args.end - 1}: {np.mean([r['n_contacts'] for r in recs]):.0f} contacts, "
              f"{np.mean([r['dofs'] for r in recs]):.0f} DOFs, {np.mean([r['pgs_iterations'] for r in recs]):.1f} "
              f"PGS sweeps; CPU ms per frame")
        print("| part | ms |\n|---|---|")
        for k, v in sorted(ms.items(), key=lambda kv: -kv[1]):
            print(f"| {k} | {v:.2f} |")
        print(f"| frame | {1e3 * total / n:.2f} |\n| contact (detect + resolve) | {contact:.2f} |")
        print(f"| frame outside contact | {1e3 * total / n - contact:.2f} |")
        print(f"| contact share | {100 * contact / (1e3 * total / n):.0f} % |\n")
        out.append((ms, 1e3 * total / n))
    return out


if __name__ == "__main__":
    main()
