"""Does the resting pile keep its clusters once its boxes are at elastic equilibrium? DOFs per frame
of affinification at the paper's thresholds (1e-4 / 2e-4) on the pile of four soft boxes
(``benchmarks/budget.py``), three ways:

- ``plain``: from the start, as the reducer runs;
- ``--from-full N``: from the full-space run's state and contact impulses at frame N (its boxes
  closer to elastic equilibrium than the affinified run's, whose boxes were frozen affine while
  still settling);
- ``--hold K``: an experiment, not a reducer option: an element that leaves an affine cluster stays
  elastic for K frames, so that its box can relax before it is frozen again.

Prints the DOFs of each frame from ``--report`` on and the largest vertex distance to the
full-space run (m; the scene is about 1 m across).

Usage::

    python benchmarks/pile_settling.py --frames 200 --report 100
    python benchmarks/pile_settling.py --frames 260 --report 200 --from-full 200
    python benchmarks/pile_settling.py --frames 200 --report 100 --hold 30
"""
import argparse
import copy
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
import skfem_affine as sa  # noqa: E402
from skfem_affine.reducers.affine import affinification  # noqa: E402

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from budget import pile  # noqa: E402


def holding(reducer, frames):
    """Wrap the reducer's clustering: elements that were affine and turn elastic stay elastic ``frames`` frames."""
    labels_of = reducer._labels
    base = reducer.excluded
    hold = None

    def labels(problem, v_pred):
        nonlocal hold
        hold = np.zeros(problem.system.m, dtype=int) if hold is None else hold
        reducer.excluded = (base if base is not None else np.zeros(hold.size, bool)) | (hold > 0)
        was = reducer.was_reduced.copy()
        out = labels_of(problem, v_pred)
        hold = np.maximum(hold - 1, 0)
        hold[was & (out < 0)] = frames
        return out
    reducer._labels = labels


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--cells", type=int, default=4)
    p.add_argument("--frames", type=int, default=200)
    p.add_argument("--report", type=int, default=100)
    p.add_argument("--from-full", type=int, default=0)
    p.add_argument("--hold", type=int, default=0)
    args = p.parse_args(argv)
    full, reduced = pile(args.cells), pile(args.cells, sa.Affinification(1e-4, 2e-4))
    if args.from_full:
        for _ in range(args.from_full):
            full.step()
        reduced.step()  # attach the reducer, then take the full-space state and support
        reduced.state = copy.deepcopy(full.state)
        reduced.contact.load_state_dict(copy.deepcopy(full.contact.state_dict()))
    if args.hold:
        holding(reduced.integrator.reducer, args.hold)
    dofs, error = [], 0.0
    for frame in range(args.from_full + 1, args.frames + 1):
        reduced.step()
        full.step()
        error = max(error, float(np.linalg.norm(reduced.state.x - full.state.x, axis=1).max()))
        if frame > args.report:
            dofs.append(reduced.stats[-1]["dofs"])
    changes = int(np.count_nonzero(np.diff(dofs)))
    print(f"frames {args.report + 1}-{args.frames}: DOFs {dofs}")
    print(f"mean {np.mean(dofs):.1f}, min {min(dofs)}, max {max(dofs)}, DOF changes {changes}, "
          f"distance to full space {error:.2e} m, largest speed {np.abs(reduced.state.v).max():.1e} m/s")


if __name__ == "__main__":
    main()
