"""The routes to Z = (A^-1)_TT on the unknowns T that a frame's contacts touch, each in multiples of the
frame's own numeric factorisation (MKL Pardiso, METIS ordering): one process, one MKL thread, the
routes stepped in turn ``--reps`` times (medians).

- **unit columns**: |T| solves of e_T with the frame's factorisation (what ``Resolvent`` falls back on);
- **Schur complement** (``iparm(36)``, its own handle, T eliminated last): a new analysis (the contacts
  moved), the numeric factorisation of a kept one, and S^-1 (dense, LAPACK potrf/potri);
- **partial solve** (``iparm(31) = 1``, sparse right-hand sides marked at the analysis, which orders
  them last as the Schur complement does): its analysis, its factorisation and the solve of e_T;
- **one factorisation per frame**: the Schur factorisation (mode ``iparm(36) = 2``) and the partial-solve
  one also solve the frame's own system (phase 33); the residual of that solve is printed, since the
  frame would then factorise once.

Each route's Z is compared with the unit columns'. ``--cube M``: an elastic cube of M^3 vertices,
T a square patch of its bottom face; ``MESH_DIR --scene octopus --frame F``: the full-space scene of
``benchmarks/paper_table1.py`` run to frame F, its system and its contacts' touched unknowns::

    python benchmarks/delassus_routes.py --cube 23
    python benchmarks/delassus_routes.py MESH_DIR --scene octopus --frame 75
"""
import argparse
import os
import sys
import time

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"

import numpy as np  # noqa: E402
import scipy.sparse as sp  # noqa: E402
from scipy.linalg import lapack  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))
sys.path.insert(0, HERE)


def cube(m, patch=15):
    """dt^2 K + M of a linear elastic unit cube (m^3 vertices) and the unknowns of a patch of its bottom face."""
    import skfem
    from skfem.helpers import dot
    from skfem.models.elasticity import lame_parameters, linear_elasticity
    mesh = skfem.MeshTet.init_tensor(*(np.linspace(0, 1, m),) * 3)
    basis = skfem.Basis(mesh, skfem.ElementVector(skfem.ElementTetP1()))
    K = linear_elasticity(*lame_parameters(1e4, 0.35)).assemble(basis)
    M = skfem.BilinearForm(lambda u, v, w: dot(u, v)).assemble(basis)
    half = (min(patch, m) // 2) / (m - 1) + 1e-9
    p = mesh.p
    on = np.flatnonzero((p[2] < 1e-9) & (np.abs(p[0] - 0.5) <= half) & (np.abs(p[1] - 0.5) <= half))
    return (1e-4 * K + M).tocsr(), np.sort(basis.nodal_dofs[:, on].ravel())


def scene_frame(mesh_dir, scene, frame):
    """The full-space scene's system matrix and touched unknowns at ``frame`` (run from frame 0)."""
    import paper_table1
    sim = paper_table1.SCENES[scene][2](mesh_dir, frame + 1)(None)
    original, out = sim.contact.resolve, {}

    def resolve(problem, result, rec):
        if problem.frame == frame and sim.contact.current is not None:
            out["A"] = sp.csr_matrix(result.operator.matrix)
            out["T"] = np.flatnonzero(np.diff(sp.csc_matrix(sim.contact.current.J).indptr))
        return original(problem, result, rec)

    sim.contact.resolve = resolve
    for _ in range(frame):
        if "A" in out:
            break
        sim.step()
    if "A" not in out:
        raise SystemExit(f"no contact at frame {frame}")
    return out["A"], out["T"]


class Handle:
    """One Pardiso handle on the upper triangle of A, with ``iparm`` (1-based) set before its analysis."""

    def __init__(self, arrays, **iparm):
        from skfem_affine.solvers import _PardisoLibrary
        self.lib, self.arrays, self.n = _PardisoLibrary(), arrays, arrays[3]
        self.lib._ps.set_iparm(2, 2)  # METIS
        for i, v in iparm.items():
            self.lib._ps.set_iparm(int(i[1:]), v)

    def call(self, phase, b=None, perm=None):
        b = np.zeros((self.n, 1)) if b is None else b
        return self.lib.call(phase, self.arrays, b, perm=perm)

    def close(self):
        self.lib.release(self.arrays)


def inverse(S):
    """S^-1 from its Cholesky factor (lower triangle filled by potri, mirrored)."""
    L, info = lapack.dpotrf(S, lower=1, clean=0)
    L, info = lapack.dpotri(L, lower=1)
    L = np.tril(L)
    return L + np.tril(L, -1).T


def measure(A, T, reps):
    U = sp.triu(A, format="csr")
    U.sort_indices()
    n, k = A.shape[0], T.size
    arrays = (U.data.copy(), U.indptr.astype(np.int32), U.indices.astype(np.int32), n)
    E = np.zeros((n, k), order="F")
    E[T, np.arange(k)] = 1.0
    marks = np.zeros(n, np.int32)
    marks[T] = 1
    rhs = np.random.default_rng(0).normal(size=(n, 1))
    times, Z, residual = {}, {}, {}

    def timed(name, f):
        t0 = time.perf_counter()
        out = f()
        times.setdefault(name, []).append(time.perf_counter() - t0)
        return out

    def solve_residual(h, name):
        x = h.call(33, rhs, perm=marks.copy())
        residual[name] = float(np.abs(A @ x[:, 0] - rhs[:, 0]).max() / np.abs(rhs).max())

    plain = Handle(arrays)
    timed("plain: analysis and factorisation", lambda: plain.call(12))
    buffer = np.zeros((max(n, k * k), 1))
    schur = Handle(arrays, i36=2)
    timed("Schur: analysis and factorisation", lambda: schur.call(12, buffer, perm=marks.copy()))
    partial = Handle(arrays, i31=1)
    timed("partial solve: analysis", lambda: partial.call(11, perm=marks.copy()))
    timed("partial solve: factorisation", lambda: partial.call(22, perm=marks.copy()))

    def step_plain():
        timed("plain: factorisation", lambda: plain.call(22))
        Z["unit columns"] = timed("unit columns: solves of e_T", lambda: plain.call(33, E))[T]

    def step_schur():
        x = timed("Schur: factorisation", lambda: schur.call(22, buffer, perm=marks.copy()))
        Z["Schur"] = timed("Schur: S^-1", lambda: inverse(x[:k * k, 0].reshape(k, k)))
        solve_residual(schur, "Schur (mode 2)")

    def step_partial():
        timed("partial solve: factorisation", lambda: partial.call(22, perm=marks.copy()))
        Z["partial solve"] = timed("partial solve: solve of e_T", lambda: partial.call(33, E, perm=marks.copy()))[T]
        partial.lib._ps.set_iparm(31, 0)  # the frame's own right-hand side is dense
        solve_residual(partial, "partial solve")
        partial.lib._ps.set_iparm(31, 1)

    steps = [step_plain, step_schur, step_partial]
    for r in range(reps):
        for step in steps[r % 3:] + steps[:r % 3]:
            step()
    for h in (plain, schur, partial):
        h.close()
    return times, Z, residual


def report(times, Z, residual, n, k):
    f = float(np.median(times["plain: factorisation"]))
    print(f"n {n}, |T| {k}; the frame's numeric factorisation {1e3 * f:.0f} ms (median); multiples of it:")
    for name, ts in times.items():
        print(f"  {name:40s} {np.median(ts) / f:6.2f}")
    ref = Z["unit columns"]
    for name in ("Schur", "partial solve"):
        print(f"  Z from {name} against the unit columns: {np.abs(Z[name] - ref).max() / np.abs(ref).max():.1e}")
    for name, r in residual.items():
        print(f"  the frame's solve on the {name} factorisation: residual {r:.1e}")
    m = {name: float(np.median(ts)) / f for name, ts in times.items()}
    new_s = m["Schur: analysis and factorisation"]
    new_p = m["partial solve: analysis"] + m["partial solve: factorisation"]
    print("Delassus cost on top of the frame's factorisation (new analysis / kept analysis):")
    print(f"  unit columns                            {m['unit columns: solves of e_T']:.2f}")
    print(f"  Schur complement, its own handle        {new_s + m['Schur: S^-1']:.2f} / "
          f"{m['Schur: factorisation'] + m['Schur: S^-1']:.2f}")
    print(f"  partial solve, its own handle           {new_p + m['partial solve: solve of e_T']:.2f} / "
          f"{m['partial solve: factorisation'] + m['partial solve: solve of e_T']:.2f}")
    print(f"  Schur factorisation as the frame's own  {new_s - 1 + m['Schur: S^-1']:.2f} / "
          f"{m['Schur: factorisation'] - 1 + m['Schur: S^-1']:.2f}")
    print(f"  partial solve as the frame's own        {new_p - 1 + m['partial solve: solve of e_T']:.2f} / "
          f"{m['partial solve: factorisation'] - 1 + m['partial solve: solve of e_T']:.2f}")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("mesh_dir", nargs="?", default=None, help="the paper's meshes (with --scene)")
    ap.add_argument("--cube", type=int, default=None, help="vertices per edge of the cube")
    ap.add_argument("--scene", choices=["octopus", "wheel", "pills"], default=None)
    ap.add_argument("--frame", type=int, default=75)
    ap.add_argument("--reps", type=int, default=3)
    args = ap.parse_args(argv)
    if (args.cube is None) == (args.scene is None):
        ap.error("give --cube M or MESH_DIR --scene NAME")
    if args.scene is not None and args.mesh_dir is None:
        ap.error("--scene needs MESH_DIR (the paper's meshes)")
    A, T = cube(args.cube) if args.cube else scene_frame(args.mesh_dir, args.scene, args.frame)
    report(*measure(A, T, args.reps), A.shape[0], T.size)


if __name__ == "__main__":
    main()
