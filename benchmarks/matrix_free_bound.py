"""Contact without forming W: a matrix-free contact solver through the frame's plain factor, against today's
exact W and block PGS, on two consecutive full-space contact frames of a scene.

The scene (``benchmarks/contact_phases.py``'s, with the frame factorised with the contacts' unknowns
last, today's default) runs from frame 0 to ``--frame`` or from ``--resume CHECKPOINT``, steps ``--skip``
frames (default 1: the first frame after a resume makes new analyses) and then the first two frames with
contacts. On each, today's route is timed as the frame runs: the
factorisation, the Delassus operator W (exact, dense), the PGS kernel (block Gauss-Seidel, the
default), the rest of PGS's phase (the velocity correction, the split impulse) and detection, with the
residual PGS reached (:func:`skfem_affine.contact.pgs.contact_residual`). Then, from the frame's matrix
A, its Jacobian J, free velocities u0 and warm start (the previous frame's PGS impulses, matched by
contact identity), in the same process (one MKL thread):

- the **plain factorisation** of A (Pardiso, METIS, a kept analysis; median of ``--reps``);
- **one product** W y = J (A^-1 (J^T y)) (one forward and backward solve), and the solve of a block of
  ``--block`` right-hand sides, per right-hand side;
- **W's diagonal blocks**: exact ones need Z = (A^-1)_TT on each contact's own columns, i.e. the solves
  of the unit columns of the touched unknowns T (|T| / ``--block`` blocks, the cost extrapolated from
  the block timed); the lumped-mass ones (J M^-1 J^T, free) bound them from above;
- **APGD** (:func:`skfem_affine.contact.apgd.apgd`, products through the factor, the exact diagonal
  blocks given to it for free) to PGS's residual on that frame (or the tolerance, whichever is larger),
  from the warm start and from zero; from the warm start with its steps from the lumped-mass blocks
  (``lumped``) or one step for all contacts (``scalar``, W's Rayleigh quotient), and without Nesterov's
  acceleration (projected Jacobi): its products, its wall time, and the residual with the exact W;
- **PCG with the active set known**: conjugate gradients (block Jacobi) on the contacts PGS's solution
  presses, taken as sticking, from the warm start, products counted until max |u| is within the goal
  (with the dense W: only the count is used).

The implied frame of the matrix-free route is the frame's own time outside factorisation and contact
(assembly, the step's solve), the plain factorisation, detection, the rest of PGS's phase and APGD's
time; its contact share is the last three over that sum; ``budget`` is the number of products that
would keep contact at 35 % of it. Usage::

    python benchmarks/matrix_free_bound.py MESH_DIR --scene octopus --resume RUNS/octopus/full-000325.npz \
        --saved-solver gauss-seidel
    python benchmarks/matrix_free_bound.py MESH_DIR --scene pills --resume RUNS/pills/full-004000.npz
    python benchmarks/matrix_free_bound.py --scene bowling --cells 3 --frame 120
"""
import argparse
import dataclasses
import os
import sys
import time

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"

import numpy as np  # noqa: E402
import scipy.sparse as sp  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))
sys.path.insert(0, HERE)
import contact_phases  # noqa: E402
from delassus_routes import Handle  # noqa: E402
from skfem_affine.contact import apgd, pgs  # noqa: E402

SHARE = 0.35  # the goal: contact at most this share of the frame


def capture(mesh_dir, scene, cells, frame, resume, frames=2, saved_solver=None, skip=1):
    """The first ``frames`` full-space frames with contacts from ``frame`` on (or from the checkpoint's):
    per frame a dict of A, J, W, u0, the warm start, mu, PGS's impulses, sweeps and kernel time, the
    tolerance's scale, the frame's record and the lumped inverse masses. ``saved_solver``: the PGS
    iteration the checkpoint was run with, when not the default (the frames then step the default).
    ``skip``: frames stepped first (the first frame after a resume makes new analyses)."""
    sim = contact_phases.builders(mesh_dir, scene, frame + skip + frames + 50, cells, frame_schur=True)[1]
    if resume is not None:
        default = sim.contact.settings
        if saved_solver is not None:
            sim.contact.settings = dataclasses.replace(default, solver=saved_solver)
            sim._settings["contact_settings"] = repr(sim.contact.settings)
        contact_phases.load_checkpoint(sim, resume)
        sim.contact.settings = default
        frame = sim.state.frame + 1  # the first frame it steps
    st = sim.contact.settings
    kernel = pgs.SOLVERS[st.solver]
    caught, current = [], {}

    def solver(W, u0, lam, mu, iterations, tolerance, limit, loose, floor):
        if current:  # the copies' time is taken off the frame's record
            t0 = time.perf_counter()
            current.update(W=np.array(W), u0=u0.copy(), lam0=lam.copy(), mu=mu, tolerance=tolerance,
                           scale=max(float(pgs.velocity_scale(u0)), floor))
            current["copy"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        sweeps = kernel(W, u0, lam, mu, iterations, tolerance, limit, loose, floor)
        if current:
            current.update(kernel=time.perf_counter() - t0, sweeps=int(sweeps), lam=lam.copy())
        return sweeps

    original = sim.contact.resolve

    def resolve(problem, result, rec):
        if problem.frame >= frame + skip and sim.contact.current is not None and len(caught) < frames:
            current.update(A=sp.csr_matrix(result.operator.matrix), J=sp.csr_matrix(sim.contact.current.J),
                           frame=problem.frame)
        return original(problem, result, rec)

    sim.contact.resolve = resolve
    pgs.SOLVERS[st.solver] = solver
    try:
        for _ in range(frame + skip + frames + 50 - sim.state.frame):
            if len(caught) == frames:
                break
            sim.step()
            if current:
                current.update(rec=dict(sim.stats[-1]), inv_mass=sim.contact.inv_mass)
                caught.append(dict(current))
                current.clear()
                print(f"{scene}: frame {caught[-1]['frame']} captured", file=sys.stderr, flush=True)
    finally:
        pgs.SOLVERS[st.solver] = kernel
    if len(caught) < frames:
        raise SystemExit(f"fewer than {frames} contact frames from frame {frame + skip} on")
    return caught


def median_time(f, reps):
    ts = []
    for _ in range(reps):
        t0 = time.perf_counter()
        f()
        ts.append(time.perf_counter() - t0)
    return float(np.median(ts))


def lumped_blocks(J, inv_mass):
    """The diagonal 3 x 3 blocks of J M^-1 J^T (M lumped), which bound W's from above (A >= M)."""
    Js = sp.csr_matrix(J.multiply(np.sqrt(inv_mass)[None, :]))
    G = sp.csr_matrix(Js @ Js.T)
    k = J.shape[0] // 3
    idx = 3 * np.arange(k)[:, None] + np.arange(3)
    return np.asarray(G[idx[:, :, None].repeat(3, 2).ravel(), idx[:, None, :].repeat(3, 1).ravel()]).reshape(k, 3, 3)


def active_pcg(W, u0, lam0, lam, blocks, goal, max_products):
    """Products a preconditioned CG needs on the contacts PGS's solution presses (lam_n > 0), taken as
    sticking (u = 0 on their three rows), from the warm start, block Jacobi with W's exact diagonal
    blocks: the least a CG-type scheme that knew the active set would spend (max |u| <= goal)."""
    act = np.flatnonzero(lam[0::3] > 0)
    if act.size == 0:
        return 0
    rows = (3 * act[:, None] + np.arange(3)).ravel()
    Wa, b = W[np.ix_(rows, rows)], -u0[rows]
    Binv = np.linalg.pinv(blocks[act])
    x = lam0[rows].copy()
    r = b - Wa @ x
    products = 1
    if np.abs(r).max() <= goal:
        return products
    z = np.einsum("kij,kj->ki", Binv, r.reshape(-1, 3)).ravel()
    p, rz = z.copy(), float(r @ z)
    while products < max_products:
        q = Wa @ p
        products += 1
        alpha = rz / float(p @ q)
        x += alpha * p
        r -= alpha * q
        if np.abs(r).max() <= goal:
            return products
        z = np.einsum("kij,kj->ki", Binv, r.reshape(-1, 3)).ravel()
        rz, old = float(r @ z), rz
        p = z + (rz / old) * p
    return -products  # not reached


# The APGD runs: name, start ("warm" or "cold"), steps ("exact", "lumped", "scalar"), accelerated
RUNS = (("warm", "warm", "exact", True), ("cold", "cold", "exact", True), ("lumped", "warm", "lumped", True),
        ("scalar", "warm", "scalar", True), ("jacobi", "warm", "exact", False))


def measure(cap, reps, block, max_products):
    """The matrix-free route on one captured frame (times in s)."""
    A, J = cap["A"], cap["J"]
    JT = sp.csr_matrix(J.T)
    U = sp.triu(A, format="csr")
    U.sort_indices()
    n = A.shape[0]
    h = Handle((U.data.copy(), U.indptr.astype(np.int32), U.indices.astype(np.int32), n))
    h.call(12)
    out = dict(n=n, contacts=J.shape[0] // 3, touched=int(np.count_nonzero(np.diff(sp.csc_matrix(J).indptr))))
    out["factorisation"] = median_time(lambda: h.call(22), reps)

    def product(y):
        return J @ h.call(33, np.asfortranarray((JT @ y)[:, None]))[:, 0]

    rng = np.random.default_rng(0)
    y = rng.normal(size=J.shape[0])
    out["product"] = median_time(lambda: product(y), reps)
    R = np.asfortranarray(rng.normal(size=(n, block)))
    out["block_column"] = median_time(lambda: h.call(33, R), reps) / block
    out["diag_exact"] = np.ceil(out["touched"] / block) * block * out["block_column"]
    W, u0, mu = cap["W"], cap["u0"], float(cap["mu"])
    check = np.abs(product(y) - W @ y).max() / np.abs(W @ y).max()
    blocks = apgd.diagonal_blocks(W)
    steps = dict(exact=blocks, lumped=lumped_blocks(J, cap["inv_mass"]),
                 # one number for all contacts: W's Rayleigh quotient at a random y (one product)
                 scalar=np.broadcast_to(float(y @ (W @ y)) / float(y @ y) * np.eye(3), blocks.shape))
    out["lumped_over_exact"] = float(np.median(steps["lumped"][:, 0, 0] / np.maximum(blocks[:, 0, 0], 1e-300)))
    r_pgs = max(pgs.contact_residual(W, u0, cap["lam"], mu))
    goal = max(r_pgs, cap["tolerance"] * cap["scale"])
    out.update(product_error=float(check), pgs_residual=r_pgs / cap["scale"], goal=goal / cap["scale"],
               sweeps=cap["sweeps"], kernel=cap["kernel"],
               warm_residual=max(pgs.contact_residual(W, u0, cap["lam0"], mu)) / cap["scale"],
               pressed=int(np.count_nonzero(cap["lam"][0::3] > 0)))
    for name, start, step, accelerate in RUNS:
        t0 = time.perf_counter()
        res = apgd.apgd(product, u0, cap["lam0"] if start == "warm" else np.zeros_like(u0), mu, blocks, goal,
                        max_products=max_products, steps=steps[step], accelerate=accelerate)
        out[name] = dict(time=time.perf_counter() - t0, products=res.products, converged=res.converged,
                         residual=max(pgs.contact_residual(W, u0, res.lam, mu)) / cap["scale"],
                         history=res.history)
    h.close()
    out["pcg"] = active_pcg(W, u0, cap["lam0"], cap["lam"], blocks, goal, max_products)
    rec = dict(cap["rec"])
    for key in ("wall", "contact", "pgs"):  # without the benchmark's copies of W
        rec[key] -= cap["copy"]
    out["wall"], out["frame_factorisation"] = rec["wall"], rec["factorization"]
    out["delassus"], out["pgs_phase"] = rec["delassus"], rec["pgs"]
    out["detection"] = rec["contact"] - rec["delassus"] - rec["pgs"]
    out["rest_of_pgs"] = rec["pgs"] - cap["kernel"]
    out["outside"] = rec["wall"] - rec["factorization"] - rec["contact"]
    return out


def report(scene, frames, rows):
    ms = 1e3
    print(f"\n{scene}: {rows[0]['contacts']} contacts, {rows[0]['touched']} touched unknowns of {rows[0]['n']}; "
          f"W y through the factor against the dense W: {max(r['product_error'] for r in rows):.1e}; lumped W_nn "
          f"over the exact (median) {rows[0]['lumped_over_exact']:.2f}")
    print("\nms; today: the frame as it ran (factorisation with the touched unknowns last, exact W, block PGS); "
          "matrix-free: outside + plain factorisation + detection + rest of PGS + APGD (warm, exact blocks)")
    print("| frame | today: frame / factorisation / Delassus / PGS kernel (sweeps) | today's contact share | outside "
          "| detection | rest of PGS | plain factorisation | matrix-free: frame / APGD | its contact share | "
          "products within 35 % |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for f, r in zip(frames, rows):
        today = (r["wall"], r["frame_factorisation"], r["delassus"], r["kernel"])
        contact_today = r["detection"] + r["delassus"] + r["pgs_phase"]
        fixed = r["detection"] + r["rest_of_pgs"]
        base = r["outside"] + r["factorisation"]
        contact = fixed + r["warm"]["time"]
        budget = (SHARE * base - (1 - SHARE) * fixed) / ((1 - SHARE) * r["product"])
        print(f"| {f} | {' / '.join(f'{ms * t:.0f}' for t in today)} ({r['sweeps']}) | "
              f"{100 * contact_today / r['wall']:.0f} % | {ms * r['outside']:.0f} | {ms * r['detection']:.0f} | "
              f"{ms * r['rest_of_pgs']:.0f} | {ms * r['factorisation']:.0f} | {ms * (base + contact):.0f} / "
              f"{ms * r['warm']['time']:.0f} | {100 * contact / (base + contact):.0f} % | {max(budget, 0):.0f} |")
    print("\nproducts W y to PGS's residual (goal, relative to the velocity scale); APGD: warm / cold start with the "
          "exact diagonal blocks, warm with lumped-mass or one scalar step, warm without acceleration (projected "
          "Jacobi); PCG: on the pressed contacts taken as sticking; - : not reached within the cap")
    print("| frame | goal (PGS reached) | warm start's residual | one product (ms, / plain factorisation) | per "
          "column in a block of RHS | exact diagonal blocks (ms) | APGD warm | cold | lumped | scalar | projected "
          "Jacobi | PCG, active set known (pressed contacts) |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")

    def count(run):
        return f"{run['products']}" if run["converged"] else f"- ({run['products']})"

    for f, r in zip(frames, rows):
        pcg = f"{r['pcg']}" if r["pcg"] >= 0 else f"- ({-r['pcg']})"
        print(f"| {f} | {r['goal']:.1e} ({r['pgs_residual']:.1e}) | {r['warm_residual']:.1e} | "
              f"{ms * r['product']:.1f} ({r['product'] / r['factorisation']:.3f}) | {ms * r['block_column']:.2f} | "
              f"{ms * r['diag_exact']:.0f} | " + " | ".join(count(r[name]) for name, *_ in RUNS)
              + f" | {pcg} ({r['pressed']}) |")
    for f, r in zip(frames, rows):
        for name, *_ in RUNS:
            hist = np.asarray(r[name]["history"]) / (r["goal"])
            marks = [i for i in (0, 10, 30, 100, 300, 1000, 3000) if i < hist.size]
            print(f"frame {f} {name}: residual / goal after " + ", ".join(f"{i} it {hist[i]:.2g}" for i in marks)
                  + f"; final {r[name]['residual']:.2e} of the scale")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("mesh_dir", nargs="?", default=None, help="the paper's meshes (wheel, octopus, pills)")
    ap.add_argument("--scene", choices=["wheel", "octopus", "pills", "pile"] + list(contact_phases.LAB_SCENES),
                    required=True)
    ap.add_argument("--cells", type=int, default=4, help="as contact_phases.py's --cells")
    ap.add_argument("--frame", type=int, default=0, help="the first frame with contacts from this one on")
    ap.add_argument("--skip", type=int, default=1, help="frames stepped before the two measured")
    ap.add_argument("--resume", default=None, metavar="CHECKPOINT", help="a full-space checkpoint to start from")
    ap.add_argument("--saved-solver", default=None, choices=sorted(pgs.SOLVERS),
                    help="the PGS iteration the checkpoint was run with, when not the default (the frames measured "
                         "then step the default)")
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--block", type=int, default=64, help="right-hand sides of the block solve")
    ap.add_argument("--max-products", type=int, default=1500, help="APGD's most products W y per solve")
    args = ap.parse_args(argv)
    caps = capture(args.mesh_dir, args.scene, args.cells, args.frame, args.resume, saved_solver=args.saved_solver,
                   skip=args.skip)
    frames, rows = [c["frame"] for c in caps], []
    for cap in caps:
        rows.append(measure(cap, args.reps, args.block, args.max_products))
        cap.clear()
    report(args.scene, frames, rows)
    return rows


if __name__ == "__main__":
    main()
