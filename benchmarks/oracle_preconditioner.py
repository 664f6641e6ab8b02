"""Quality of the oracle's preconditioners: the one-iteration prediction residual (eq. 13-14).

On the damped cantilever (``--resolution k``: 24 k^3 tets) bent by ``--frames`` frames under
gravity, builds A dv = b (gravity split out, as the oracle uses it) and prints, per
preconditioner of S (A_p = S (x) I_3), the relative residual ||b - A dv|| / ||b|| after one PCG
iteration (lower is better), the nonzeros of the factor and the setup time. Rows: the default
``ichol`` (threshold IC after RCM), IC(0) after RCM, threshold IC in the mesh's own order and in a
random order, ``amg``, and an exact solve with A_p. Usage::

    python benchmarks/oracle_preconditioner.py --resolution 6
"""
import argparse
import os
import sys
import time

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from scipy.sparse.csgraph import reverse_cuthill_mckee

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
import skfem_affine as sa  # noqa: E402
from skfem_affine.reducers.affine import oracle  # noqa: E402
from skfem_affine.reducers.affine.ichol import incomplete_cholesky  # noqa: E402


def scalar_solver(S, perm, **kw):
    t0 = time.perf_counter()
    ic = incomplete_cholesky(S[perm][:, perm], **kw)
    setup = time.perf_counter() - t0

    def apply(r):
        R = r.reshape(-1, 3)
        Z = np.empty_like(R)
        Z[perm] = ic.solve(R[perm])
        return Z.ravel()
    return apply, ic.L.nnz, setup


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--resolution", type=int, default=6)
    p.add_argument("--frames", type=int, default=10)
    args = p.parse_args()
    sim = sa.scenes.cantilever(resolution=args.resolution, damping=sa.Rayleigh(0.03, 0.02))
    for _ in sim.run(args.frames):
        pass
    A, b, data = sim.linear_system(sim.state.x, sim.state.v)
    sysm = sim.system
    b = b - sim.dt * sim.f_gravity[sysm.free]
    S = oracle.scalar_matrix(sysm, sim.dt, sim.damping)
    n = S.shape[0]
    rcm = reverse_cuthill_mckee(S, symmetric_mode=True)
    rows = {
        "ichol (threshold, RCM)": scalar_solver(S, rcm, fill=oracle.ICHOL_FILL, drop=oracle.ICHOL_DROP),
        "IC(0), RCM": scalar_solver(S, rcm, fill=None),
        "threshold, mesh order": scalar_solver(S, np.arange(n), fill=oracle.ICHOL_FILL, drop=oracle.ICHOL_DROP),
        "threshold, random order": scalar_solver(S, np.random.default_rng(0).permutation(n),
                                                 fill=oracle.ICHOL_FILL, drop=oracle.ICHOL_DROP),
    }
    t0 = time.perf_counter()
    amg = oracle.Preconditioner(sysm, sim.dt, sim.damping, kind="amg")
    rows["amg"] = (amg.apply, 0, time.perf_counter() - t0)
    lu = spla.splu(sp.csc_matrix(oracle.Preconditioner(sysm, sim.dt, sim.damping).matrix))
    rows["exact A_p"] = (lu.solve, lu.L.nnz, 0.0)
    print(f"{sysm.m} tets, S: {n} x {n}, {sp.tril(S).nnz} nonzeros in its lower triangle")
    print(f"{'preconditioner':26s} {'residual':>9s} {'nnz':>8s} {'setup ms':>9s}")
    for name, (apply, nnz, setup) in rows.items():
        dv = oracle.predict(A, b, apply)
        print(f"{name:26s} {np.linalg.norm(A @ dv - b) / np.linalg.norm(b):9.4f} {nnz:8d} {1e3 * setup:9.2f}")


if __name__ == "__main__":
    main()
