"""What an exact Delassus operator cannot avoid on one contact frame, against the frame's plain factorisation.

One full-space frame of a contact scene (``benchmarks/contact_phases.py``'s scenes, run from frame 0 to
``--frame`` or from ``--resume CHECKPOINT``): its matrix A, the bodies' blocks A_b, the unknowns T_b each
body's contacts touch and the rows J_b of J on them. Per body, each step timed alone (one MKL thread, the
steps in turn, medians of ``--reps``), summed over the bodies, in ms and in multiples of the plain
factorisation of the frame (every body's block on its own handle, METIS; Pardiso's flop count,
``iparm(19)``, and the entries of its factor, ``iparm(18)``, beside them):

- **plain factorisation**, and the same with **T_b eliminated last** in Pardiso's mode that factorises S_b
  too (``iparm(36) = 2``), and in its mode that forms S_b without factorising it (``iparm(36) = 1``, the
  full-space frame's, whose solves S_b's LAPACK factor completes), all on a kept analysis;
- **the dense work on S_b** (|T_b| x |T_b|): its Cholesky factor (``potrf``, |T_b|^3 / 3 flops), the
  inverse from it (``potri``, 2 |T_b|^3 / 3), W_b = J_b S_b^-1 J_b^T from that inverse (``fill``, the
  sparse J_b on both sides), and instead of the inverse, Y = L^-1 J_b^T (``trsm``, m_b |T_b|^2) and
  W_b = Y^T Y (``syrk``, m_b^2 |T_b|), m_b the body's rows of J;
- **the frame's solve** with the factorisation with T_b last (phase 33), and in the complement-only mode:
  forward substitution (phase 331), S_b's own Cholesky factor on T_b, backward substitution (phase 333),
  its residual printed;
- **the partial solve** (``iparm(31) = 1``, the unit columns e_{T_b} marked as sparse right-hand sides at
  the analysis, which orders them last): its factorisation and the solve of e_{T_b}, Z compared with S_b^-1.

The least an exact W costs on top of the frame's plain factorisation through a factorisation of A is
then: the cheaper factorisation with T_b last less the plain one (the complement is formed inside it),
plus, from S_b, the cheaper of (potrf + potri + fill) and (potrf + trsm + syrk). Usage::

    python benchmarks/delassus_bound.py MESH_DIR --scene pills --resume RUNS/pills/full-002900.npz
    python benchmarks/delassus_bound.py MESH_DIR --scene octopus --frame 74
    python benchmarks/delassus_bound.py --scene bowling --cells 3 --frame 22
"""
import argparse
import os
import sys
import time

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"

import numpy as np  # noqa: E402
import scipy.sparse as sp  # noqa: E402
from scipy.linalg import blas, lapack  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))
sys.path.insert(0, HERE)
import contact_phases  # noqa: E402
from delassus_routes import Handle  # noqa: E402
from skfem_affine.contact.blocks import body_bounds  # noqa: E402
from skfem_affine.contact.delassus import _add_symmetric  # noqa: E402

# Largest n |T| for the partial solve's dense right-hand sides e_T (8 bytes each): above it, not timed.
PARTIAL_MAX = 5e7


def frame_blocks(mesh_dir, scene, cells, frame, resume):
    """Per body with contacts: (A_b CSR, T_b, J_b on T_b as CSR) of the full-space frame ``frame``
    (its first contact frame from there on), and the frame's number."""
    sim = contact_phases.builders(mesh_dir, scene, frame + 1, cells, frame_schur=True)[1]
    if resume is not None:
        contact_phases.load_checkpoint(sim, resume)
    original, out = sim.contact.resolve, {}

    def resolve(problem, result, rec):
        if problem.frame >= frame and "A" not in out and sim.contact.current is not None:
            out.update(A=sp.csr_matrix(result.operator.matrix), J=sp.csc_matrix(sim.contact.current.J),
                       bodies=np.asarray(sim.contact.bodies), frame=problem.frame)
        return original(problem, result, rec)

    sim.contact.resolve = resolve
    for _ in range(frame + 50):
        if "A" in out:
            break
        sim.step()
    if "A" not in out:
        raise SystemExit(f"no contact at frame {frame} or the 50 after it")
    A, J = out["A"], out["J"]
    bounds = body_bounds(out["bodies"])
    blocks = []
    for s, e in zip(bounds[:-1], bounds[1:]):
        Jb = J[:, s:e]
        T = np.flatnonzero(np.diff(Jb.indptr))
        if 2 * T.size > e - s:  # the frame factorises such a body plainly too
            print(f"body of unknowns {s}-{e - 1}: {T.size} touched, more than half, taken as without contacts",
                  file=sys.stderr)
            T = T[:0]
        Jt = sp.csr_matrix(Jb[:, T])
        blocks.append((sp.csr_matrix(A[s:e, s:e]), T, Jt[np.flatnonzero(np.diff(Jt.indptr))]))
    return blocks, out["frame"]


STEPS = ("plain factorisation", "factorisation with T last", "the same, complement only", "potrf", "potri", "fill",
         "trsm", "syrk", "partial solve: factorisation", "partial solve: solve of e_T", "frame's solve, T last",
         "frame's solve, complement only")
ALIKE = ("plain factorisation", "factorisation with T last", "the same, complement only",
         "partial solve: factorisation")


def body(A, T, Jt, reps):
    """One body's steps (seconds, medians), flops and factor entries, and the largest difference of Z
    between the routes over Z's largest entry; a body without contacts (empty T) is factorised plainly
    on every route."""
    U = sp.triu(A, format="csr")
    U.sort_indices()
    n, k = A.shape[0], T.size
    arrays = (U.data.copy(), U.indptr.astype(np.int32), U.indices.astype(np.int32), n)
    if k == 0:
        plain = Handle(arrays, i18=-1, i19=-1)
        plain.call(12)
        ts = []
        for _ in range(reps):
            t0 = time.perf_counter()
            plain.call(22)
            ts.append(time.perf_counter() - t0)
        info = dict(n=n, k=0, m=0, plain_mflops=int(plain.lib._ps.iparm[18]), plain_nnz=int(plain.lib._ps.iparm[17]))
        info.update(schur_mflops=info["plain_mflops"], schur_nnz=info["plain_nnz"], residual=0.0)
        plain.close()
        f = float(np.median(ts))
        return {s: f if s in ALIKE else 0.0 for s in STEPS}, info, 0.0
    marks = np.zeros(n, np.int32)
    marks[T] = 1
    buffer = np.zeros((max(n, k * k), 1))
    plain = Handle(arrays, i18=-1, i19=-1)
    plain.call(12)
    schur = Handle(arrays, i18=-1, i19=-1, i36=2)
    schur.call(12, buffer, perm=marks.copy())
    only = Handle(arrays, i36=1)
    only.call(12, buffer, perm=marks.copy())
    partial = Handle(arrays, i31=1) if n * k <= PARTIAL_MAX else None
    if partial is not None:
        partial.call(11, perm=marks.copy())
    info = dict(n=n, k=k, m=Jt.shape[0], plain_mflops=int(plain.lib._ps.iparm[18]),
                plain_nnz=int(plain.lib._ps.iparm[17]), schur_mflops=int(schur.lib._ps.iparm[18]),
                schur_nnz=int(schur.lib._ps.iparm[17]))
    times, Z, residual = {}, {}, []
    rhs = np.random.default_rng(0).normal(size=(n, 1))
    Jd = np.asfortranarray(Jt.T.toarray())  # |T| x m

    def timed(name, f):
        t0 = time.perf_counter()
        x = f()
        times.setdefault(name, []).append(time.perf_counter() - t0)
        return x

    def step_plain():
        timed("plain factorisation", lambda: plain.call(22))

    def step_schur():
        x = timed("factorisation with T last", lambda: schur.call(22, buffer, perm=marks.copy()))
        S = np.asfortranarray(x[:k * k, 0].reshape(k, k))
        L, _ = timed("potrf", lambda: lapack.dpotrf(S, lower=1, clean=1))
        Zi, _ = timed("potri", lambda: lapack.dpotri(L, lower=1))
        Zi = np.tril(Zi)
        Zi = Zi + np.tril(Zi, -1).T
        Z["Schur"] = Zi
        timed("fill", lambda: _add_symmetric(np.zeros((Jt.shape[0],) * 2), np.arange(Jt.shape[0]), Jt @ (Jt @ Zi).T))
        Y = timed("trsm", lambda: blas.dtrsm(1.0, L, Jd, lower=1))
        timed("syrk", lambda: blas.dsyrk(1.0, Y, trans=1))

    def step_only():
        x = timed("the same, complement only", lambda: only.call(22, buffer, perm=marks.copy()))
        L, _ = lapack.dpotrf(np.asfortranarray(x[:k * k, 0].reshape(k, k)), lower=1, clean=1)

        def solve():  # forward substitution, S's own Cholesky factor on T, backward substitution
            y = only.call(331, np.asfortranarray(rhs.copy()), perm=marks.copy())
            y[T] = lapack.dpotrs(L, y[T], lower=1)[0]
            return only.call(333, np.asfortranarray(y), perm=marks.copy())

        x = timed("frame's solve, complement only", solve)
        residual.append(float(np.abs(A @ x[:, 0] - rhs[:, 0]).max() / np.abs(rhs).max()))
        timed("frame's solve, T last", lambda: schur.call(33, rhs, perm=marks.copy()))

    def step_partial():
        if partial is None:
            times["partial solve: factorisation"] = times["partial solve: solve of e_T"] = [np.nan]
            return
        E = np.zeros((n, k), order="F")
        E[T, np.arange(k)] = 1.0
        timed("partial solve: factorisation", lambda: partial.call(22, perm=marks.copy()))
        Z["partial"] = timed("partial solve: solve of e_T", lambda: partial.call(33, E, perm=marks.copy()))[T]

    steps = [step_plain, step_schur, step_only, step_partial]
    for r in range(reps):
        for step in steps[r % 4:] + steps[:r % 4]:
            step()
    for h in (plain, schur, only, partial):
        if h is not None:
            h.close()
    diff = float(np.abs(Z["partial"] - Z["Schur"]).max() / np.abs(Z["Schur"]).max()) if partial else np.nan
    info["residual"] = max(residual)
    return {name: float(np.median(ts)) for name, ts in times.items()}, info, diff




def report(scene, frame, rows):
    tot = {s: sum(r[0][s] for r in rows) for s in STEPS}
    f0 = tot["plain factorisation"]
    info = [r[1] for r in rows]
    sizes = sorted(i["k"] for i in info)
    print(f"{scene}, frame {frame}: {len(rows)} bodies, n_b {sorted(i['n'] for i in info)}, "
          f"|T_b| {sizes}, rows of J {sum(i['m'] for i in info)}; the frame's solve in the complement-only mode: "
          f"residual {max(i['residual'] for i in info):.1e}; the worst Z of the partial solve against "
          f"S^-1: {max(r[2] for r in rows):.1e}")
    mf0, mfs = sum(i["plain_mflops"] for i in info), sum(i["schur_mflops"] for i in info)
    dense = sum(i["k"] ** 3 for i in info) / 1e6
    print(f"Pardiso's flops (MFlop): plain {mf0}, with T last {mfs} ({mfs / max(mf0, 1):.2f}x); factor entries "
          f"{sum(i['plain_nnz'] for i in info)} / {sum(i['schur_nnz'] for i in info)}; "
          f"sum |T_b|^3 / 3 = {dense / 3:.0f} MFlop (potrf), 2 sum |T_b|^3 / 3 = {2 * dense / 3:.0f} (potri), "
          f"sum m_b |T_b|^2 = {sum(i['m'] * i['k'] ** 2 for i in info) / 1e6:.0f} (trsm)")
    print(f"| step | ms | multiples of the plain factorisation ({1e3 * f0:.0f} ms) |")
    print("|---|---|---|")
    for s in STEPS:
        print(f"| {s} | {1e3 * tot[s]:.0f} | {tot[s] / f0:.2f} |")
    inverse = tot["potrf"] + tot["potri"] + tot["fill"]
    solves = tot["potrf"] + tot["trsm"] + tot["syrk"]
    extra = min(tot["factorisation with T last"], tot["the same, complement only"]) - f0
    partial = (tot["partial solve: factorisation"] - f0 + tot["partial solve: solve of e_T"]) / f0
    print(f"W from S: potrf + potri + fill {inverse / f0:.2f}, potrf + trsm + syrk {solves / f0:.2f}; on top of "
          f"the plain factorisation, at least {(extra + min(inverse, solves)) / f0:.2f} (the cheaper factorisation "
          f"with T last {extra / f0:.2f} more); the partial solve "
          + ("not timed (its dense right-hand sides too large)" if np.isnan(partial) else f"{partial:.2f} + the fill"))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("mesh_dir", nargs="?", default=None, help="the paper's meshes (wheel, octopus, pills)")
    ap.add_argument("--scene", choices=["wheel", "octopus", "pills", "pile"] + list(contact_phases.LAB_SCENES),
                    required=True)
    ap.add_argument("--cells", type=int, default=4, help="as contact_phases.py's --cells")
    ap.add_argument("--frame", type=int, default=0, help="the first frame with contacts from this one on")
    ap.add_argument("--resume", default=None, metavar="CHECKPOINT", help="a full-space checkpoint to start from")
    ap.add_argument("--reps", type=int, default=3)
    args = ap.parse_args(argv)
    blocks, frame = frame_blocks(args.mesh_dir, args.scene, args.cells, args.frame, args.resume)
    rows = [body(A, T, Jt, args.reps) for A, T, Jt in blocks]
    report(args.scene, frame, rows)
    return rows, frame


if __name__ == "__main__":
    main()
