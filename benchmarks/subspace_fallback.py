"""Calibrating the adaptive subspace's full-space fallback by counting (no timings).

On the drop scene of ``benchmarks/subspace_paper.py`` (IPC, a soft box in contact with the
ground), the reducer's nodal enrichment is forced to a fraction f of the free DOFs (whole METIS
subdomains, lowest first: where contact enriches) with r active modal columns, and one coupled
system (eq. 19) is built at the state after ``--settle`` frames. Counted, for each (f, r):

* nonzeros of the coupled system (H_q, C, C^T, H_x) against the full-space Newton system, and
  the estimate of :func:`skfem_affine.reducers.subspace.reducer.coupled_nonzeros` that the
  fallback rule uses;
* PCG iterations of the Schur complement (eq. 21-22) and of block-Jacobi CG on the full system
  (both to relative residual 1e-5);
* work per solve in multiply-adds: Schur PCG ``iters * (2 |C| + nnz(H_x) + 2 r^2) + r^3 / 3``,
  CG ``iters * nnz(A)``, and a direct sparse Cholesky ``sum_j c_j^2`` over the column counts c_j
  of SuperLU's factor (MMD ordering; a nested-dissection solver such as Pardiso fills less).

Usage::

    python benchmarks/subspace_fallback.py --cells 6 8 --fractions 0 0.05 0.1 0.2 0.3 0.5 --blocks 1 4 8
"""
import argparse
import os
import sys

import numpy as np
import scipy.sparse.linalg as spla

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import skfem_affine as sa  # noqa: E402
from skfem_affine.integrators.potential import IncrementalPotential  # noqa: E402
from skfem_affine.reducers.subspace import linalg  # noqa: E402
from skfem_affine.reducers.subspace.reducer import coupled_nonzeros  # noqa: E402
import subspace_paper  # noqa: E402


def cholesky_work(A):
    """Multiply-adds of a sparse Cholesky of A: sum of squared column counts of SuperLU's L (MMD)."""
    lu = spla.splu(A.tocsc(), permc_spec="MMD_AT_PLUS_A", options=dict(SymmetricMode=True))
    counts = np.diff(lu.L.tocsc().indptr).astype(float)
    return float(np.sum(counts ** 2))


def count(cells, fractions, blocks, settle=4, subdomains=50, modes=16):
    red = sa.AdaptiveSubspace(basis=sa.SkinningEigenmodes(n=modes), eps_nodal=1e30, eps_modal=1e30,
                              subdomains=subdomains, fallback=None)
    sim = subspace_paper.scene("drop", cells, reducer=red)
    for _ in range(settle):
        sim.step()
    x, v = sim.state.x.reshape(-1), sim.state.v.reshape(-1)
    contact = sim.integrator.barrier
    ip = IncrementalPotential(sim.model, x, v, barrier=contact, tol=1e-3, max_iters=1)
    contact.begin_step(ip.x_t, ip.x_hat, ip.c)
    A = ip.hessian(ip.start.H, ip.x_t)
    g = ip.gradient(ip.x_t, ip.start.f)
    _, it_cg = linalg.pcg(lambda p: A @ p, -g, linalg.block_jacobi(A), 1e-5, 10000)
    direct = cholesky_work(A)
    nfree, nnz = A.shape[0], A.nnz
    z = sim.system.p0[:, 2]
    parts = red.sub.parts
    order = np.argsort([z[parts == l].mean() for l in range(red.sub.L)])  # lowest subdomains first
    rows = []
    for nb in blocks:
        for f in fractions:
            red.active = list(range(min(nb, len(red.basis.blocks))))
            red.enriched[:] = False
            for l in order:
                if red._enriched_dofs().size >= f * nfree:
                    break
                red.enriched |= (parts == l) & red.free_vertex
            red.solve(IncrementalPotential(sim.model, x, v, barrier=contact, tol=1e-3, max_iters=1))
            Hq, C, Hx, gq, gx = red.last_system
            _, _, it_s, _ = linalg.schur_solve(Hq, C, Hx, gq, gx, 1e-5, 10000)
            r, s = Hq.shape[0], Hx.shape[0]
            ours = Hq.size + 2 * C.size + Hx.nnz
            rows.append({"tets": sim.system.m, "f": s / nfree, "r": r, "s": s, "nnz_ours": ours,
                         "nnz_est": coupled_nonzeros(s, r, nnz / nfree), "nnz_full": nnz,
                         "schur_it": it_s, "cg_it": it_cg,
                         "schur_work": it_s * (2 * C.size + Hx.nnz + 2 * r * r) + r ** 3 / 3,
                         "cg_work": it_cg * nnz, "direct_work": direct})
    return rows


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--cells", type=int, nargs="+", default=[6, 8])
    p.add_argument("--fractions", type=float, nargs="+", default=[0.0, 0.05, 0.1, 0.2, 0.3, 0.5])
    p.add_argument("--blocks", type=int, nargs="+", default=[1, 4, 8], help="active blocks of 12 columns")
    p.add_argument("--settle", type=int, default=4, help="frames before the counted state (in contact)")
    args = p.parse_args(argv)
    print(f"{'tets':>6} {'f':>5} {'r':>4} {'s':>6} {'nnz ours':>9} {'estimate':>9} {'nnz full':>9} {'ours/full':>9} "
          f"{'schur it':>8} {'cg it':>6} {'schur work':>10} {'cg work':>10} {'direct work':>11}")
    rows = []
    for cells in args.cells:
        for r in count(cells, args.fractions, args.blocks, args.settle):
            rows.append(r)
            print(f"{r['tets']:>6} {r['f']:>5.2f} {r['r']:>4} {r['s']:>6} {r['nnz_ours']:>9} {r['nnz_est']:>9.0f} "
                  f"{r['nnz_full']:>9} {r['nnz_ours'] / r['nnz_full']:>9.2f} {r['schur_it']:>8} {r['cg_it']:>6} "
                  f"{r['schur_work']:>10.3g} {r['cg_work']:>10.3g} {r['direct_work']:>11.3g}", flush=True)
    return rows


if __name__ == "__main__":
    main()
