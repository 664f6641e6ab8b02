"""Contact iterations compared offline on saved frames of a contact scene: sweeps to the tolerance.

A frame of the paper's pills costs seconds (mostly the Delassus operator), its contact solve a
fraction of that; so the problems are saved once and the iterations compared on them:

``dump`` steps the pills as ``benchmarks/paper_table1.py`` builds them (the paper's Pill.mesh from
MESH_DIR, full space, plain Gauss-Seidel sweeps) and saves the contact problem of the chosen
frames (W, u0, the friction, the warm start, the tolerance and its floor, each contact's
bodies and height) as ``.npz``. ``compare`` solves each saved problem from its warm start with
every iteration below, to the frame's tolerance (``contact_residual`` at most ``tolerance``
times ``velocity_scale``) or a cap, and prints, per iteration, the share of frames that reach the
tolerance within 50, 100 and the cap, the median and 90th percentile of the cost to reach it,
and the median residual (over the scale) after a cost of 50. The cost is counted in passes over
W (entries of W read, over its size): one Gauss-Seidel sweep is one pass, one product W x is one.

Iterations: Gauss-Seidel sweeps in the detection's order, reversed, by height (lowest contact
first, highest first), by body pair, in a random order per sweep, forward and backward in turn
(symmetric), over-relaxed (SOR, 1.3 and 1.6); block Gauss-Seidel per body pair (up to 5 or 20
inner sweeps on the pair's own block, then the other contacts' velocities updated); accelerated
projected gradient (APGD: Nesterov's extrapolation, adaptive step, gradient restart, on the
same projection, its step scaled per contact by the diagonal or not, with and without restarts;
its largest eigenvalue estimated by 10 power iterations, counted); and the library's
Anderson-accelerated sweeps (depth 5 and 10; the extrapolation's own work, O(depth) vectors, is
not counted). Usage::

    MESH_DIR=... python benchmarks/contact_solvers.py dump /tmp/frames --frames 44:71:2 80:151:10
    python benchmarks/contact_solvers.py compare /tmp/frames --cap 300
"""
import argparse
import glob
import os
import sys
import time

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import numpy as np  # noqa: E402
from numba import njit  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))
sys.path.insert(1, HERE)
import skfem_affine as sa  # noqa: E402
from skfem_affine.contact import pgs  # noqa: E402
from skfem_affine.contact.pgs import _contact_error, _contact_step, _disk, _tangent_step, _worst  # noqa: E402


# ----------------------------------------------------------------------------- saving the frames
def dump(out, frames, mesh_dir):
    import paper_table1
    os.makedirs(out, exist_ok=True)
    mats = (sa.NeoHookean(E=1.1e3, nu=0.35), sa.NeoHookean(E=5e4, nu=0.36))
    sim = sa.scenes.pills(mesh=os.path.join(mesh_dir, "Pill.mesh"), materials=mats, density=paper_table1.DENSITY,
                          dt=0.01, contact=sa.PGS(friction=0.3, solver="gauss-seidel"))
    contact, system = sim.contact, sim.system
    body_of = np.repeat(np.arange(len(system.bodies)), np.diff(system.vertex_offsets))
    plain = pgs.SOLVERS["gauss-seidel"]
    now = {"frame": -1}

    def saving(W, u0, lam, mu, iterations, tolerance, max_iterations=0, loose=0.0, floor=0.0):
        if now["frame"] in frames:
            cs = contact.current
            own = body_of[cs.vertex]
            other = np.full(cs.size, -1)
            for j in range(3):
                b = body_of[cs.others[:, j]]
                pick = (cs.weights[:, j] != 0) & (b != own) & (other < 0)
                other[pick] = b[pick]
            np.savez(os.path.join(out, f"frame{now['frame']:04d}.npz"), W=W, u0=u0, lam0=lam, mu=mu,
                     tolerance=tolerance, floor=floor, body=own, other=other, z=sim.state.x[cs.vertex, 2])
        return plain(W, u0, lam, mu, iterations, tolerance, max_iterations, loose, floor)

    pgs.SOLVERS["gauss-seidel"] = saving
    try:
        for frame in range(max(frames) + 1):
            now["frame"] = frame
            sim.step()
            print(f"frame {frame}: {sim.stats[-1].get('n_contacts', 0)} contacts", file=sys.stderr, flush=True)
    finally:
        pgs.SOLVERS["gauss-seidel"] = plain


# ----------------------------------------------------------------------------- the iterations
@njit(cache=True)
def ordered(W, u0, lam, mu, goal, cap, order, mode, omega):
    """Sweeps in ``order`` (mode 0), a random order per sweep (1), or forward and backward in turn (2).
    Returns (passes to the goal or -1, the residual after each pass)."""
    u = u0 + W @ lam
    hist = np.full(cap + 1, np.nan)
    hist[0] = _worst(W, u, lam, mu)
    if hist[0] <= goal:
        return 0, hist
    np.random.seed(0)
    for s in range(cap):
        perm = order
        if mode == 1:
            perm = np.random.permutation(order.size)
        elif mode == 2 and s % 2 == 1:
            perm = order[::-1].copy()
        for c in perm:
            _contact_step(W, u, lam, mu, 3 * c, omega)
        hist[s + 1] = _worst(W, u, lam, mu)
        if hist[s + 1] <= goal:
            return s + 1, hist
    return -1, hist


@njit(cache=True)
def block(W, u0, lam, mu, goal, cap, ptr, members, inner):
    """Block Gauss-Seidel per group (``members[ptr[g]:ptr[g + 1]]``): up to ``inner`` sweeps on the
    group's block with its own velocities only (9 |g|^2 entries each), then u updated (3 |g| m)."""
    m = lam.size
    u = u0 + W @ lam
    hist = np.full(cap + 1, np.nan)
    hist[0] = _worst(W, u, lam, mu)
    if hist[0] <= goal:
        return 0.0, hist
    cost, mark, full = 0.0, 1, float(m) * m
    while cost < cap * full:
        for g in range(ptr.size - 1):
            cs = members[ptr[g]:ptr[g + 1]]
            rows = (3 * np.repeat(cs, 3) + np.array([0, 1, 2] * cs.size)).astype(np.int64)
            Wg = np.empty((rows.size, rows.size))
            for a in range(rows.size):
                for b in range(rows.size):
                    Wg[a, b] = W[rows[a], rows[b]]
            lg, ug = lam[rows].copy(), u[rows].copy()
            before = lg.copy()
            for _ in range(inner):
                for i in range(cs.size):
                    _contact_step(Wg, ug, lg, mu, 3 * i, 1.0)
                cost += float(rows.size) ** 2
                if _worst(Wg, ug, lg, mu) <= 0.1 * goal:
                    break
            for a in range(rows.size):
                d = lg[a] - before[a]
                if d != 0.0:
                    lam[rows[a]] = lg[a]
                    for j in range(m):
                        u[j] += W[rows[a], j] * d
            cost += float(rows.size) * m
        r = _worst(W, u, lam, mu)
        while mark <= cap and cost >= mark * full:
            hist[mark] = r
            mark += 1
        if r <= goal:
            return cost / full, hist
    return -1.0, hist


@njit(cache=True)
def _project(lam, mu):
    for r in range(0, lam.size, 3):
        lam[r] = max(lam[r], 0.0)
        lam[r + 1], lam[r + 2] = _disk(lam[r + 1], lam[r + 2], mu * lam[r])


@njit(cache=True)
def apgd(W, u0, lam, mu, goal, cap, scaled, restart):
    """Accelerated projected gradient on lam = P(lam - D^-1 (u0 + W lam)) (the fixed points of the
    sweeps): Nesterov's extrapolation, a step 1/L with L adapted (doubled until the quadratic's
    sufficient decrease holds, else 0.9 L), restart when the gradient opposes the step."""
    m = lam.size
    d = np.ones(m)
    if scaled:
        for r in range(0, m, 3):
            d[r] = W[r, r] if W[r, r] > 0 else 1.0
            s = _tangent_step(W, r)
            d[r + 1] = d[r + 2] = s if s > 0 else 1.0
    dinv, sq = 1.0 / d, np.sqrt(1.0 / d)
    hist = np.full(cap + 1, np.nan)
    np.random.seed(0)
    v = np.random.rand(m)
    L = 1.0
    passes = 0
    for _ in range(10):
        w = sq * (W @ (sq * v))
        passes += 1
        L = np.linalg.norm(w) / np.linalg.norm(v)
        v = w / np.linalg.norm(w)
    x = lam.copy()
    _project(x, mu)
    Wx = W @ x
    passes += 1
    best = _worst(W, u0 + Wx, x, mu)
    hist[:passes + 1] = best
    if best <= goal:
        return passes, hist
    y, Wy, theta = x.copy(), Wx.copy(), 1.0
    while passes < cap:
        g = u0 + Wy
        fy = 0.5 * y @ Wy + u0 @ y
        while True:
            xn = y - dinv * g / L
            _project(xn, mu)
            Wxn = W @ xn
            passes += 1
            dx = xn - y
            if 0.5 * xn @ Wxn + u0 @ xn <= fy + g @ dx + 0.5 * L * (dx * d) @ dx or passes >= cap:
                break
            L *= 2.0
        r = _worst(W, u0 + Wxn, xn, mu)
        best = min(best, r)
        hist[min(passes, cap)] = best
        if r <= goal:
            return passes, hist
        nxt = 0.5 * (-theta * theta + theta * np.sqrt(theta * theta + 4.0))
        beta = theta * (1.0 - theta) / (theta * theta + nxt)
        if restart and g @ (xn - x) > 0.0:
            y, Wy, nxt = xn.copy(), Wxn.copy(), 1.0
        else:
            y, Wy = xn + beta * (xn - x), Wxn + beta * (Wxn - Wx)
        x, Wx, theta = xn, Wxn, nxt
        L *= 0.9
    return -1, hist


def anderson(W, u0, lam, mu, goal, cap, scale, depth):
    """The library's Anderson-accelerated sweeps, restarted from lam for each cap to get the history."""
    tol = goal / scale
    hist = np.full(cap + 1, np.nan)
    hist[0] = _worst(W, u0 + W @ lam, lam, mu)
    x = lam.copy()
    n = pgs.anderson_gauss_seidel(W, u0, x, mu, cap, tol, 0, 0.0, 0.0, depth)
    r = _worst(W, u0 + W @ x, x, mu)
    reached = n < cap or r <= goal
    for p in (50, 100):   # the residual after p sweeps (a run capped there)
        if p <= cap:
            y = lam.copy()
            pgs.anderson_gauss_seidel(W, u0, y, mu, p, tol, 0, 0.0, 0.0, depth)
            hist[p] = _worst(W, u0 + W @ y, y, mu)
    hist[cap] = r
    return (n if reached else -1), hist


def variants(problem, cap):
    W, u0, lam0, mu = problem["W"], problem["u0"], problem["lam0"], float(problem["mu"])
    k = u0.size // 3
    scale = max(float(pgs.velocity_scale(u0)), float(problem["floor"]))
    goal = float(problem["tolerance"]) * scale
    natural = np.arange(k)
    pairs = np.lexsort((problem["other"], problem["body"])).astype(np.int64)
    key = (problem["body"] * (k + 1) + problem["other"] + 1)[pairs]
    ptr = np.append(np.flatnonzero(np.r_[True, key[1:] != key[:-1]]), k).astype(np.int64)
    height = np.argsort(problem["z"], kind="stable")
    run = {
        "Gauss-Seidel (detection order)": lambda x: ordered(W, u0, x, mu, goal, cap, natural, 0, 1.0),
        "reversed": lambda x: ordered(W, u0, x, mu, goal, cap, natural[::-1].copy(), 0, 1.0),
        "by height, lowest first": lambda x: ordered(W, u0, x, mu, goal, cap, height, 0, 1.0),
        "by height, highest first": lambda x: ordered(W, u0, x, mu, goal, cap, height[::-1].copy(), 0, 1.0),
        "by body pair": lambda x: ordered(W, u0, x, mu, goal, cap, pairs, 0, 1.0),
        "random order per sweep": lambda x: ordered(W, u0, x, mu, goal, cap, natural, 1, 1.0),
        "symmetric (forward, backward)": lambda x: ordered(W, u0, x, mu, goal, cap, natural, 2, 1.0),
        "SOR 1.3": lambda x: ordered(W, u0, x, mu, goal, cap, natural, 0, 1.3),
        "SOR 1.6": lambda x: ordered(W, u0, x, mu, goal, cap, natural, 0, 1.6),
        "block per body pair, 5 inner": lambda x: block(W, u0, x, mu, goal, cap, ptr, pairs, 5),
        "block per body pair, 20 inner": lambda x: block(W, u0, x, mu, goal, cap, ptr, pairs, 20),
        "APGD": lambda x: apgd(W, u0, x, mu, goal, cap, False, True),
        "APGD, diagonal scaling": lambda x: apgd(W, u0, x, mu, goal, cap, True, True),
        "APGD, diagonal scaling, no restart": lambda x: apgd(W, u0, x, mu, goal, cap, True, False),
        "Anderson, depth 5 (solver='anderson')": lambda x: anderson(W, u0, x, mu, goal, cap, scale, 5),
        "Anderson, depth 10": lambda x: anderson(W, u0, x, mu, goal, cap, scale, 10),
    }
    out = {}
    for name, fun in run.items():
        cost, hist = fun(lam0.copy())
        out[name] = (float(cost) if cost >= 0 else np.inf, float(np.nanmin(hist[:51])) / scale)
    return k, out


def compare(folder, cap):
    files = sorted(glob.glob(os.path.join(folder, "frame*.npz")))
    if not files:
        raise SystemExit(f"no frame*.npz in {folder}")
    table = {}
    for path in files:
        t = time.perf_counter()
        k, out = variants(np.load(path), cap)
        print(f"{os.path.basename(path)}: {k} contacts, " + ", ".join(f"{n} {c:.0f}" for n, (c, _) in out.items())
              + f" ({time.perf_counter() - t:.0f} s)", file=sys.stderr, flush=True)
        for name, v in out.items():
            table.setdefault(name, []).append(v)
    print(f"{len(files)} frames; cost in passes over W, cap {cap}\n")
    print(f"| iteration | <= 50 | <= 100 | <= {cap} | median | 90th pct. | median residual after 50 |")
    print("|---|---|---|---|---|---|---|")
    for name, rows in table.items():
        cost = np.array([c for c, _ in rows])
        res = np.array([r for _, r in rows])
        share = [f"{100 * np.mean(cost <= p):.0f} %" for p in (50, 100, cap)]
        med, p90 = (np.percentile(cost, q, method="inverted_cdf") for q in (50, 90))
        print(f"| {name} | " + " | ".join(share) + f" | {med:.0f} | {p90:.0f} | {np.median(res):.1e} |".replace("inf", f"> {cap}"))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="what", required=True)
    d = sub.add_parser("dump")
    d.add_argument("folder")
    d.add_argument("--frames", nargs="+", required=True, help="start:stop:step ranges of frames to save")
    c = sub.add_parser("compare")
    c.add_argument("folder")
    c.add_argument("--cap", type=int, default=300)
    args = ap.parse_args(argv)
    if args.what == "dump":
        mesh_dir = os.environ.get("MESH_DIR") or os.environ.get("SKFEM_AFFINE_MESHES")
        if not mesh_dir:
            raise SystemExit("set MESH_DIR (or SKFEM_AFFINE_MESHES) to the folder of the paper's meshes")
        frames = set()
        for r in args.frames:
            frames.update(range(*(int(v) for v in r.split(":"))))
        dump(args.folder, frames, mesh_dir)
    else:
        compare(args.folder, args.cap)


if __name__ == "__main__":
    main()
