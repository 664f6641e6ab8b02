"""The 16 pills at rest in the bowl, full space against ``Affinification()``, default threads against one.

``sa.scenes.pills(n=16)`` (alternately soft and stiff capsules in an ``sa.Bowl``) is stepped in full
space and under the default ``Affinification()`` in turn, frame by frame in one process, on one
thread for ``--settle`` frames (by about frame 300 every body is affine). Over the next ``--frames``
frames the thread settings alternate frame by frame: the package's and the libraries' defaults
(every core for the compiled passes, OpenBLAS and MKL), then one thread for everything
(``threads.set_num_threads(1)`` and ``threadpool_limits(1)``). Printed per method and setting: CPU
ms per frame (``time.process_time``: every thread of the process) by phase, each phase the CPU
time spent inside one function, callees included:

- detection: ``Contact.detect`` (contacts, Jacobian, warm start, prediction impulses);
- elastic frame: the reducer's ``solve`` (assembly, prediction, clustering, reduced assembly,
  factorisation and solve; their wall ms from the frame's record follow the table);
- Delassus: ``Resolvent.delassus``; grouping: ``contact_groups``; PGS: the sweeps without the
  grouping; correction: ``Resolvent.apply``;
- checks: the monitor's checks; other: the rest of the frame (the record's ``cpu``).

Usage (from the checkout, so that it measures this checkout)::

    python -m benchmarks.resting_bowl --settle 300 --frames 40
"""
import argparse
import time

import numpy as np
from threadpoolctl import threadpool_limits

import skfem_affine as sa
from skfem_affine import threads
from skfem_affine.contact import delassus, pgs
from skfem_affine.monitor import Monitor

PHASES = ("detection", "elastic frame", "Delassus", "grouping", "PGS", "correction", "checks", "other")
WALL = ("assembly", "prediction", "clustering", "map_assembly", "factorization", "solve")
SETTINGS = ("default threads", "one thread")


class Timer:
    """CPU time (process) of wrapped functions into the phases of the frame being stepped."""

    def __init__(self):
        self.now, self.replaced = None, []

    def wrap(self, owner, name, phase, inner=None):
        fn = getattr(owner, name) if not isinstance(owner, dict) else owner[name]
        self.replaced.append((owner, name, fn))

        def call(*args, **kwargs):
            t0 = time.process_time()
            try:
                return fn(*args, **kwargs)
            finally:
                if self.now is not None:
                    spent = time.process_time() - t0
                    self.now[phase] += spent
                    if inner is not None:  # the phase nested in it is not counted twice
                        self.now[inner] -= spent
        if isinstance(owner, dict):
            owner[name] = call
        else:
            setattr(owner, name, call)

    def restore(self):
        for owner, name, fn in reversed(self.replaced):
            if isinstance(owner, dict):
                owner[name] = fn
            else:
                setattr(owner, name, fn)


def one_thread():
    threads.set_num_threads(1)
    return threadpool_limits(limits=1)


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--settle", type=int, default=300)
    p.add_argument("--frames", type=int, default=40)
    args = p.parse_args(argv)
    sims = {"full": sa.scenes.pills(n=16), "affinification": sa.scenes.pills(n=16, reducer=sa.Affinification())}
    with one_thread():
        for _ in range(args.settle):
            for sim in sims.values():
                sim.step()
    threads.set_num_threads(None)
    timer = Timer()
    timer.wrap(pgs.Contact, "detect", "detection")
    timer.wrap(delassus.Resolvent, "delassus", "Delassus")
    timer.wrap(delassus.Resolvent, "apply", "correction")
    timer.wrap(pgs.SOLVERS, sims["full"].contact.settings.solver, "PGS")
    timer.wrap(pgs, "contact_groups", "grouping", inner="PGS")
    timer.wrap(Monitor, "check", "checks")
    for name, sim in sims.items():
        timer.wrap(sim.integrator.reducer, "solve", "elastic frame")
    rows = {(name, s): [] for name in sims for s in SETTINGS}
    try:
        for f in range(args.frames):
            setting = SETTINGS[f % 2]
            for name, sim in sims.items():
                timer.now = dict.fromkeys(PHASES, 0.0)
                if setting == "one thread":
                    with one_thread():
                        sim.step()
                    threads.set_num_threads(None)
                else:
                    sim.step()
                rec = sim.stats[-1]
                timer.now["other"] = rec["cpu"] - sum(timer.now.values())
                rows[name, setting].append({**timer.now, "frame": rec["cpu"], "reduced": bool(rec.get("reduced")),
                                            "contacts": rec["n_contacts"], "sweeps": rec["pgs_iterations"],
                                            **{k: rec.get(k, 0.0) for k in WALL}})
    finally:
        timer.restore()
        timer.now = None
    names = [f"{name}, {s}" for name, s in rows]
    print(f"16 pills at rest in the bowl, frames {args.settle + 1}-{args.settle + args.frames}, settings alternating "
          f"frame by frame; CPU ms per frame (mean)")
    print("| phase | " + " | ".join(names) + " |")
    print("|---|" + "---|" * len(names))
    for phase in PHASES + ("frame",):
        cells = [f"{1e3 * np.mean([r[phase] for r in rs]):.2f}" for rs in rows.values()]
        print(f"| {phase} | " + " | ".join(cells) + " |")
    for key, label in (("contacts", "contacts"), ("sweeps", "PGS sweeps"), ("reduced", "reduced frames")):
        cells = [f"{np.mean([r[key] for r in rs]):.3g}" for rs in rows.values()]
        print(f"| {label} | " + " | ".join(cells) + " |")
    print("elastic frame, recorded wall ms per frame: " + "; ".join(
        f"{n}: " + ", ".join(f"{k} {1e3 * np.mean([r[k] for r in rs]):.2f}" for k in WALL)
        for n, rs in zip(names, rows.values())))
    for name in sims:
        one, default = (np.mean([r["frame"] for r in rows[name, s]]) for s in ("one thread", "default threads"))
        print(f"{name}: default threads / one thread CPU time {default / one:.2f}")
    full, red = (np.mean([r["frame"] for r in rows[n, "one thread"]]) for n in sims)
    print(f"one thread: affinification {full / red:.2f}x full space (CPU)")


if __name__ == "__main__":
    main()
