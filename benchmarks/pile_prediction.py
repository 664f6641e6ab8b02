"""Why the resting pile's affine boxes change their clusters every frame: the oracle's predicted
deformation rates on the pile of four soft boxes, against exact predictions and the actual rates.

Steps the pile of ``benchmarks/budget.py`` (``--pile``) in full space or under affinification at the
paper's thresholds (1e-4 / 2e-4) and, in each frame from ``--from``, prints per box the spread of the
deformation rates over its elements, ``max_e || F_dot_e - median(F_dot) ||`` (1/s), of

- ``oracle``: the velocities the oracle predicts (affinification only; one PCG step, eq. 13-14),
- ``exact``: the exact solve of the same system, ``A dv = b`` with the warm-started support taken
  as an explicit force, as the oracle takes it,
- ``held-n``: the exact solve with the supported contacts' normal velocities held (their normal
  impulses free to adjust, as the contact solve lets them),
- ``held-stick``: the same with the tangential velocities held too (sticking friction),
- ``actual``: the frame's start velocities,

and the DOFs of the frame. The clustering compares the rates of neighbouring elements with tau_e
= 2e-4 (elements affine the frame before) and tau_a = 1e-4; spreads above them break clusters.

Usage::

    python benchmarks/pile_prediction.py --method affinification --frames 125 --from 120
    python benchmarks/pile_prediction.py --method full --frames 125 --from 120
"""
import argparse
import os
import sys

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
import skfem_affine as sa  # noqa: E402
from skfem_affine.reducers.affine import oracle  # noqa: E402

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from budget import pile  # noqa: E402


def spread(system, v, dv, elements):
    """Largest distance of an element's deformation rate to the median over ``elements`` (1/s)."""
    w = v.copy()
    w.reshape(-1)[system.free] += dv
    F = system.deformation_gradients(w).reshape(-1, 9)[elements]
    return float(np.linalg.norm(F - np.median(F, axis=0), axis=1).max())


def held_solve(A, b, rhs_rows, rows):
    """dv of ``A dv = b + rows^T mu`` with ``rows dv = rhs_rows`` (the held contacts' velocities)."""
    k = rows.shape[0]
    K = sp.bmat([[A, rows.T], [rows, -1e-10 * sp.identity(k)]]).tocsc()
    return spla.spsolve(K, np.concatenate([b, rhs_rows]))[:A.shape[0]]


def predictions(problem):
    """name -> predicted velocity change (n_free,) of the exact solves of the frame's system."""
    model, system = problem.model, problem.system
    h, free = model.dt, system.free
    cm, ck = model.coefficients
    A = (cm * system.Mff + ck * problem.Hmat).tocsc()
    gravity_dv = h * np.tile(model.gravity, system.n)[free]
    support = problem.support_impulse if np.ndim(problem.support_impulse) else np.zeros(free.size)
    b = problem.b - h * model.f_gravity[free] + support  # gravity split out (eq. 13)
    out = {"exact": spla.spsolve(A, b) + gravity_dv}
    cs = problem.contacts
    if cs is not None and cs.size:
        J = sp.csr_matrix(cs.J)
        held = np.flatnonzero(J[0::3] @ support > 0)  # the contacts carrying warm-started support
        for name, rows in (("held-n", 3 * held), ("held-stick", (3 * held[:, None] + np.arange(3)).ravel())):
            Js = J[rows]
            # the total velocity change (gravity's step included) keeps the held contacts' velocities
            out[name] = held_solve(A, b, -(Js @ gravity_dv), Js) + gravity_dv
    return out


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--method", choices=["affinification", "full"], default="affinification")
    p.add_argument("--cells", type=int, default=4)
    p.add_argument("--frames", type=int, default=125)
    p.add_argument("--from", dest="start", type=int, default=120)
    args = p.parse_args(argv)
    sim = pile(args.cells, sa.Affinification(1e-4, 2e-4) if args.method == "affinification" else None)
    seen = {}
    reducer = sim.integrator.reducer
    solve, predict = reducer.solve, oracle.predict

    def recording_solve(problem):
        seen["problem"] = problem
        return solve(problem)

    def recording_predict(*a, **k):
        seen["oracle"] = predict(*a, **k)
        return seen["oracle"]
    reducer.solve = recording_solve
    oracle.predict = recording_predict
    system = sim.system
    vertex_body = np.searchsorted(system.vertex_offsets, np.arange(system.n), side="right") - 1
    element_body = vertex_body[system.t[0]]
    for frame in range(1, args.frames + 1):
        seen.pop("oracle", None)
        sim.step()
        if frame < args.start:
            continue
        problem = seen["problem"]
        dvs = predictions(problem)
        if "oracle" in seen:
            dvs = {"oracle": seen["oracle"], **dvs}
        dvs["actual"] = np.zeros(system.free.size)
        boxes = []
        for b in range(len(sim.bodies)):
            e = element_body == b
            boxes.append(f"box{b} " + " ".join(f"{name} {spread(system, problem.v, dv, e):.1e}"
                                               for name, dv in dvs.items()))
        print(f"frame {frame} dofs {sim.stats[-1]['dofs']}: " + " | ".join(boxes), flush=True)


if __name__ == "__main__":
    main()
