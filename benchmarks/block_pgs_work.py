"""Where the block Gauss-Seidel contact solve spends its work on a resting pile: groups, sweeps, visits.

The pile of ``benchmarks/budget.py`` (four soft boxes on the ground, ``--cells`` per box edge) under
affinification at tau_a = 1e-4, tau_e = 2e-4 runs to frame ``--end``; the contact problems (W, u0, warm
start) of the frames ``--start`` to ``--end`` are kept and solved again by the default block sweeps
(``skfem_affine.contact.pgs.block_gauss_seidel``), visit by visit, counting per frame: the groups (their
sizes), the sweeps, the group visits made and passed over (already within the tolerance), the inner
sweeps of the visits made and how many of them stopped at their work cap, and the work in multiply-adds:
inner sweeps ((3c)^2 each for a group of c contacts), the visits' changes passed to all velocities (3c
rows of W each) and the steps of contacts alone (3 rows). The counts follow the kernel's own steps (the
same impulses, checked at the end of each frame). One BLAS/MKL thread.

Usage::

    python benchmarks/block_pgs_work.py --cells 4 --start 100 --end 119
"""
import argparse
import os
import sys

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import numpy as np  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))  # measure the checkout this script sits in
sys.path.insert(0, HERE)
import skfem_affine as sa  # noqa: E402
from skfem_affine.contact import pgs  # noqa: E402


def problems(cells, start, end):
    """The block solver's arguments (W, u0, warm start, the rest) of the pile's frames start to end - 1."""
    from budget import pile
    sim, seen, solve = pile(cells, sa.Affinification(tau_a=1e-4, tau_e=2e-4)), [], pgs.SOLVERS["block"]

    def keeping(W, u0, lam, *args):
        if len(sim.stats) >= start:
            seen.append((W.copy(), u0.copy(), lam.copy(), args))
        return solve(W, u0, lam, *args)

    pgs.SOLVERS["block"] = keeping
    try:
        for _ in range(end):
            sim.step()
    finally:
        pgs.SOLVERS["block"] = solve
    return seen


def counted(W, u0, lam, mu, iterations, tolerance, max_iterations, loose, floor):
    """The steps of ``pgs._block_gauss_seidel`` one visit at a time, counted (module docstring)."""
    ptr, members = pgs.contact_groups(W)
    u = pgs._velocities(W, u0, lam)
    scale = max(pgs.velocity_scale(u0), floor)
    goal, m = tolerance * scale, lam.size
    out = dict(sweeps=0, visits=0, passed=0, inner=0, capped=0, inner_work=0, spread_work=0, single_work=0)
    for sweep in range(max(iterations, max_iterations)):
        for g in range(ptr.size - 1):
            group = members[ptr[g]:ptr[g + 1]]
            c = group.size
            rows = (3 * group[:, None] + np.arange(3)).ravel()
            if c == 1:
                pgs._contact_step(W, u, lam, mu, rows[0], 1.0)
                out["single_work"] += 3 * m
                continue
            if pgs._group_worst(W, u, lam, mu, rows) <= goal:
                out["passed"] += 1
                continue
            Wl = W[np.ix_(rows, rows)].copy()
            cap = min(pgs.INNER, max(1, (pgs.WORK * m) // (3 * c)))
            ul, ll, n = u[rows], lam[rows], 0
            for n in range(1, cap + 1):
                for r in range(0, 3 * c, 3):
                    pgs._contact_step(Wl, ul, ll, mu, r, 1.0)
                if pgs._worst(Wl, ul, ll, mu) <= pgs.VISIT * goal:
                    break
            d = ll - lam[rows]
            lam[rows] = ll
            u += W[rows].T @ d
            out["visits"] += 1
            out["inner"] += n
            out["capped"] += n == cap and pgs._worst(Wl, ul, ll, mu) > pgs.VISIT * goal
            out["inner_work"] += n * (3 * c) ** 2
            out["spread_work"] += 3 * c * m
        out["sweeps"] = sweep + 1
        worst = pgs._worst(W, u, lam, mu)
        if worst <= goal or (sweep + 1 >= iterations and worst <= loose * scale):
            break
    return out, np.diff(ptr)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cells", type=int, default=4, help="cells per box edge")
    ap.add_argument("--start", type=int, default=100)
    ap.add_argument("--end", type=int, default=119)
    args = ap.parse_args(argv)
    total = {}
    print("| frame | contacts | groups (sizes) | sweeps | visits / passed over | inner sweeps (at the cap) "
          "| work: inner / spread / alone (k multiply-adds) |\n|---|---|---|---|---|---|---|")
    found = problems(args.cells, args.start, args.end)
    for i, (W, u0, lam0, rest) in enumerate(found):
        lam, kernel = lam0.copy(), lam0.copy()
        out, sizes = counted(W, u0, lam, *rest)
        pgs.block_gauss_seidel(W, u0, kernel, *rest)
        if not np.allclose(lam, kernel, rtol=1e-9, atol=1e-12 * np.abs(kernel).max(initial=1.0)):
            print(f"frame {args.start + i}: the counted steps left the kernel's impulses", file=sys.stderr)
        for k, v in out.items():
            total[k] = total.get(k, 0) + v
        print(f"| {args.start + i} | {u0.size // 3} | {sizes.size} ({', '.join(map(str, sizes))}) | {out['sweeps']} "
              f"| {out['visits']} / {out['passed']} | {out['inner']} ({out['capped']}) | {out['inner_work'] / 1e3:.0f} / "
              f"{out['spread_work'] / 1e3:.0f} / {out['single_work'] / 1e3:.0f} |")
    n = max(len(found), 1)
    print("\nmeans per frame: " + ", ".join(f"{k} {v / n:.1f}" for k, v in total.items()))
    return total


if __name__ == "__main__":
    main()
