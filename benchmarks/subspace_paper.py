"""The adaptive-subspace paper's evaluation (Trusty et al., Tables 1 and 3), reproduced at our sizes.

Scenes of the paper's kinds, all with IPC contact (``sa.IPC``, ipctk) under the implicit Euler
Newton integrator:

* ``drop``: a soft box (E = 1e5) dropped at 2 m/s on the ground, friction 0.3 (the jello drop);
* ``stack``: three boxes, the lowest resting on the ground, the two others falling onto it,
  friction 0.5 (bodies in frictional contact, body-body CCD);
* ``hetero``: a box of two materials (lower half E = 1e5, upper half E = 1e7) dropped at 2 m/s;
* ``ramp``: the frictionless-ramp sliding cube of the paper's Fig. 5 (30 degrees; E = 5e4 for
  our 0.5 m cube, whose own weight would compress it by about its height at the paper's 5e3).

Each scene is run with full-space IPC Newton (direct solver) and with ``AdaptiveSubspace``,
stepped frame by frame in turn in one process (:func:`skfem_affine.lab.runs.interleaved`). As
Table 1 is per time step, the *hard step* is the step with the most full-space Newton
iterations (ties: the slower one). Reported per scene:

* at the hard step: Newton iterations (ours, full), step wall time (ours, full) and their ratio,
  the enriched fraction, active modes, and whether our step was reduced or fell back to full;
* over the run: total wall time of each and their ratio, the fraction of reduced steps, and the
  max vertex error (largest vertex distance to the full-space run at the same frame, over all
  frames, relative to the scene size);
* Table 3's linear solve at the start of the hard step (the full run's state): our coupled
  system (eq. 19) by the Schur-complement PCG, against the full-space Newton system at the same
  iterate by the direct solver (Pardiso when installed) and by 3 x 3 block-Jacobi CG (both
  iterative solves to relative residual 1e-5, CG capped at 10000 iterations as in the paper),
  each the fastest of ``--repeats`` solves; nonzeros and iterations.

The paper's numbers are printed beside ours (``PAPER_TABLE1``, ``PAPER_TABLE3``).

Usage::

    python benchmarks/subspace_paper.py --cells 6 --frames 20            # ~1.3k tets per box
    python benchmarks/subspace_paper.py --scenes drop stack --cells 16 --frames 30 --eps 0.5
    python benchmarks/subspace_paper.py --scenes drop --cells 16 --frames 20 --eps 0.05 0.01 --verbose
"""
import argparse
import json
import os
import sys
import time

import numpy as np

# measure the checkout this script sits in, not whatever skfem_affine is installed
sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
import skfem_affine as sa  # noqa: E402
from skfem_affine.integrators.potential import IncrementalPotential  # noqa: E402
from skfem_affine.lab import runs  # noqa: E402
from skfem_affine.reducers.subspace import linalg  # noqa: E402

#: The paper's Table 1: vertices, faces, tets, enriched/vertices, modes (active/available),
#: ours (s), IPC (s) for one hard time step.
PAPER_TABLE1 = {
    "Iceberg": (18e3, 26e3, 64e3, 0.16, "72/204", 2, 3),
    "Roller Terrain": (80e3, 72e3, 357e3, 0.049, "72/240", 18, 449),
    "Jello Soft": (149e3, 39e3, 815e3, 0.77, "120/216", 49, 259),
    "Jello Rubber": (149e3, 39e3, 815e3, 0.11, "84/216", 12, 278),
    "Jello Stiff": (149e3, 39e3, 815e3, 0.0, "84/216", 7, 1997),
    "Spiky Ball Eigenmodes": (116e3, 207e3, 329e3, 0.27, "84/204", 141, 229),
    "Spring Fist (5e-3)": (245e3, 67e3, 1314e3, 0.037, "312/384", 24, 200),
    "City": (465e3, 634e3, 1719e3, 0.028, "204/204", 431, 1665),
    "Mushroom Kingdom": (550e3, 472e3, 2516e3, 0.051, "264/576", 876, 9216),
}

#: The paper's Table 3: ours (s), IPC-LLT (s), IPC-CG (s), nnz ours, nnz IPC, our iterations, CG iterations.
PAPER_TABLE3 = {
    "Iceberg": (0.04, 0.25, 2.10, 7.6e5, 1.8e6, 59, 450),
    "Roller Terrain": (0.08, 1.71, 5.02, 8.5e5, 9.3e6, 268, 674),
    "Jello Soft": (0.53, 10.3, 7.00, 2.5e7, 1.9e7, 84, 782),
    "Jello Rubber": (0.10, 10.2, 7.63, 4.8e6, 1.9e7, 68, 846),
    "Jello Stiff": (5e-5, 10.4, 9.28, 7.1e4, 1.9e7, 0, 1035),
    "Spiky Ball Eigenmodes": (0.91, 1.57, 3.00, 6.4e6, 1.1e7, 315, 348),
    "Spring Fist (5e-3)": (0.03, 12.4, 23.0, 2.9e6, 3.1e7, 50, 2232),
    "City": (1.30, 9.64, 14.2, 1.5e7, 4.9e7, 356, 689),
    "Mushroom Kingdom": (0.52, 21.4, 36.5, 5.5e6, 6.4e7, 307, 1598),
}

#: The paper's scene nearest to each of ours in kind.
NEAREST = {"drop": "Jello Rubber", "stack": "City", "hetero": "Mushroom Kingdom", "ramp": None}

SCENES = ("drop", "stack", "hetero", "ramp")


def _box(size, cells, center, material, velocity=(0.0, 0.0, 0.0), name=None):
    mesh = sa.scenes.box_mesh((size,) * 3, (cells,) * 3, center=center)
    return sa.ElasticBody(mesh, material, density=1000.0, velocity=np.asarray(velocity, float), name=name)


def scene(kind, cells, reducer=None, solver="auto", newton_tol=1e-3, dt=0.01, linearized=False, E=1e5):
    """One of the paper's scene kinds with ``cells`` tensor cells per box side (6 cells^3 tets a box).

    ``linearized=True``: the same scene under the linearized integrator with PGS contact (the
    affinification paper's setting, for ``sa.Affinification``) instead of implicit Euler with IPC.
    ``E``: Young's modulus of the soft material (the ramp's cube is 5e4 Pa, the hetero box's
    upper half 100 E).
    """
    soft = sa.NeoHookean(E=E, nu=0.4)
    common = dict(dt=dt, gravity=(0.0, 0.0, -9.81), integrator="implicit_euler", reducer=reducer,
                  solver=solver, newton_tol=newton_tol)
    if linearized:
        common.update(integrator="linearized", newton_tol=None)

    def contact(friction):
        return sa.PGS(friction=friction) if linearized else sa.IPC(friction=friction)

    ground = [sa.Plane((0.0, 0.0, 0.0), (0.0, 0.0, 1.0))]
    s, gap = 0.5, 0.05
    if kind == "drop":
        body = _box(s, cells, (0, 0, gap + s / 2), soft, (0, 0, -2.0), "jello")
        return sa.Simulation(body, colliders=ground, contact=contact(0.3), **common)
    if kind == "stack":
        bodies = [_box(s, cells, (0, 0, 0.5e-3 + s / 2), soft, name="base"),
                  _box(s, cells, (0.1, 0.05, s + gap + s / 2), soft, (0, 0, -1.0), "middle"),
                  _box(s, cells, (-0.05, 0.1, 2 * s + 3 * gap + s / 2), soft, (0, 0, -2.0), "top")]
        return sa.Simulation(bodies, colliders=ground, contact=contact(0.5), **common)
    if kind == "hetero":
        mesh = sa.scenes.box_mesh((s,) * 3, (cells,) * 3, center=(0, 0, gap + s / 2))
        upper = mesh.p[2, mesh.t].mean(axis=0) > gap + s / 2
        material = sa.NeoHookean(E=np.where(upper, 100 * E, E), nu=0.4)
        body = sa.ElasticBody(mesh, material, density=1000.0, velocity=np.array([0.0, 0.0, -2.0]), name="two_materials")
        return sa.Simulation(body, colliders=ground, contact=contact(0.3), **common)
    if kind == "ramp":
        th = np.radians(30)
        common["gravity"] = (9.81 * np.sin(th), 0.0, -9.81 * np.cos(th))  # the ramp's frame: the plane is z = 0
        body = _box(s, cells, (0, 0, 0.5e-3 + s / 2), sa.NeoHookean(E=5e4, nu=0.4), name="sliding_cube")
        return sa.Simulation(body, colliders=ground, contact=contact(0.0), **common)
    raise ValueError(f"scene must be one of {SCENES}, got {kind!r}")


def thresholds(args):
    """(eps_nodal, eps_modal) of each run: ``--eps`` with ``--eps-modal`` (one value for all, or one each)."""
    modal = args.eps if args.eps_modal is None else args.eps_modal
    if len(modal) == 1:
        modal = modal * len(args.eps)
    if len(modal) != len(args.eps):
        raise ValueError(f"--eps-modal needs one value or one per --eps ({len(args.eps)}), got {len(modal)}")
    return list(zip(args.eps, modal))


def subspace(args, eps, eps_modal):
    return sa.AdaptiveSubspace(basis=sa.SkinningEigenmodes(n=args.modes), eps_nodal=eps, eps_modal=eps_modal,
                               subdomains=args.subdomains, fallback=_fallback(args.fallback))


def _fallback(text):
    if text in ("nnz", "none"):
        return None if text == "none" else text
    return float(text)


#: IPC entry points timed per frame by :func:`_time_contact`: the barrier (and friction) terms
#: (``ipc_eval``), the per-vertex energy shares the oracle asks for (``ipc_shares``), and continuous
#: collision detection (``ipc_ccd``: the line search's largest intersection-free step).
CONTACT_TIMERS = {"ipc_eval": ("begin_step", "energy", "gradient", "hessian", "hessian_parts", "hessian_data"),
                  "ipc_shares": ("vertex_energy",),
                  "ipc_ccd": ("max_step", "step_collision_free", "intersection_free")}


def _time_contact(sim):
    """Wrap the IPC contact object's entry points with timers; returns the running totals
    (seconds, keys of :data:`CONTACT_TIMERS`; nested calls are counted once)."""
    contact = sim.integrator.barrier
    totals = {key: 0.0 for key in CONTACT_TIMERS}
    if contact is None:
        return totals
    depth = [0]

    def wrap(name, key):
        inner = getattr(contact, name)

        def timed(*a, **kw):
            if depth[0]:
                return inner(*a, **kw)
            depth[0] += 1
            t0 = time.perf_counter()
            try:
                return inner(*a, **kw)
            finally:
                totals[key] += time.perf_counter() - t0
                depth[0] -= 1
        setattr(contact, name, timed)

    for key, names in CONTACT_TIMERS.items():
        for name in names:
            if hasattr(contact, name):
                wrap(name, key)
    return totals


def _fastest(fn, repeats):
    best, out = np.inf, None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return best, out


def linear_solves(sim, reducer, x, v, solver, repeats=3, system=None):
    """Table 3 at state (x, v): the Schur solve of our coupled system (eq. 19) against the
    full-space Newton system at x by ``solver`` (factorization + solve) and by block-Jacobi CG.

    ``system``: our coupled system ``(Hq, C, Hx, gq, gx)`` as the run built it (the last reduced
    iterate of the step); without it, the reducer (in its state after the run) builds it at x."""
    contact = sim.integrator.barrier
    ip = IncrementalPotential(sim.model, x, v, barrier=contact, tol=1e-3, max_iters=1)
    contact.begin_step(ip.x_t, ip.x_hat, ip.c)
    A = ip.hessian(ip.start.H, ip.x_t)
    g = ip.gradient(ip.x_t, ip.start.f)
    direct = sa.solvers.make_solver(solver)

    def direct_solve():
        direct.factorize(A)
        return direct.solve(-g)

    t_direct, _ = _fastest(direct_solve, repeats)
    t_cg, (_, it_cg) = _fastest(lambda: linalg.pcg(lambda p: A @ p, -g, linalg.block_jacobi(A), 1e-5, 10000), repeats)
    captured = system is not None
    if not captured:
        keep = reducer.fallback
        reducer.fallback = None  # the coupled system itself, whatever the enrichment
        try:
            reducer.solve(ip)
        finally:
            reducer.fallback = keep
        system = reducer.last_system
    Hq, C, Hx, gq, gx = system
    t_schur, (_, _, it_schur, _) = _fastest(lambda: linalg.schur_solve(Hq, C, Hx, gq, gx, 1e-5, 10000), repeats)
    return {"schur_s": t_schur, "direct_s": t_direct, "cg_s": t_cg, "schur_iters": int(it_schur),
            "cg_iters": int(it_cg), "nnz_ours": int(Hq.size + 2 * C.size + Hx.nnz), "nnz_full": int(A.nnz),
            "enriched_dofs": int(Hx.shape[0]), "modes": int(Hq.shape[0]), "direct": direct.name,
            "system": "captured" if captured else "rebuilt"}


def _frame_line(frame, running, errors, contact_s):
    parts = [f"frame {frame}"]
    for name, sim in running.items():
        r = sim.stats[-1]
        text = f"{name}: {r['wall']:.2f} s, {r.get('newton_iters', 0)} it, ipc {contact_s[name]:.2f} s"
        if name != "full":
            text += (f", enriched {r.get('enriched_ratio', 0):.3f}, cols {r.get('active_modes', 0)}, "
                     f"reduced {r.get('reduced', True)}, err {errors[name][-1]:.2e}" if errors[name] else "")
        parts.append(text)
    return " | ".join(parts)


def run_scene(kind, args):
    """Full-space IPC Newton and the adaptive subspace at each of ``args.eps``, all stepped frame
    by frame in turn in one process; a row per threshold (the hard step and Table 3)."""
    full = scene(kind, args.cells, solver=args.solver)
    reducers = {f"eps={eps:g}" + (f"/{modal:g}" if modal != eps else ""): (eps, subspace(args, eps, modal))
                for eps, modal in thresholds(args)}
    sims = {"full": full, **{name: scene(kind, args.cells, reducer=red) for name, (_, red) in reducers.items()}}
    totals = {name: _time_contact(sim) for name, sim in sims.items()}
    seen = {name: dict.fromkeys(CONTACT_TIMERS, 0.0) for name in sims}
    states = [(full.state.x.copy(), full.state.v.copy())]
    errors = {name: [] for name in reducers}
    # our coupled systems (the last reduced iterate's) at the hard step so far and at the step with
    # the most enriched DOFs, for Table 3; a step that built none (fell back) leaves None
    last = {name: None for name in reducers}
    hard_key, systems = [None], {name: {"hard": None, "enriched": None} for name in reducers}

    def capture(frame, running):
        rf = running["full"].stats[-1]
        key = (rf.get("newton_iters", 0), rf["wall"])
        harder = hard_key[0] is None or key > hard_key[0]
        if harder:
            hard_key[0] = key
        for name, (_, red) in reducers.items():
            system = red.last_system if name in running and red.last_system is not last[name] else None
            last[name] = red.last_system
            if harder:
                systems[name]["hard"] = (frame - 1, system)
            best = systems[name]["enriched"]
            size = 0 if system is None else system[2].shape[0]
            if size > 0 and (best is None or size > best[1][2].shape[0]):
                systems[name]["enriched"] = (frame - 1, system)

    def on_frame(frame, running):
        if "full" in running:
            capture(frame, running)
        contact_s = {}
        for name, sim in running.items():  # this frame's IPC time into the frame's record
            rec = sim.stats[-1]
            for key in CONTACT_TIMERS:
                rec[key] = totals[name][key] - seen[name][key]
                seen[name][key] = totals[name][key]
            contact_s[name] = sum(rec[key] for key in CONTACT_TIMERS)
        if "full" in running:
            states.append((running["full"].state.x.copy(), running["full"].state.v.copy()))
            for name in reducers:
                if name in running:
                    d = np.linalg.norm(running[name].state.x - running["full"].state.x, axis=1).max()
                    errors[name].append(float(d / full.size))
        if args.verbose:
            print(_frame_line(frame, running, errors, contact_s), flush=True)

    result = runs.interleaved(sims, args.frames, on_frame=on_frame)
    rf = result["full"].records
    rows = []
    for name, (eps, red) in reducers.items():
        ro = result[name].records
        n = min(len(rf), len(ro))
        if n == 0:
            raise RuntimeError(f"{kind}: no step finished ({result['full'].summary['message']} "
                               f"{result[name].summary['message']})")
        hard = max(range(n), key=lambda i: (rf[i].get("newton_iters", 0), rf[i]["wall"]))
        row = {"scene": kind, "eps": eps, "eps_modal": float(red.eps_modal), "tets": int(full.system.m),
               "vertices": int(full.system.n), "frames": n,
               "hard_step": hard + 1,
               "newton_ours": int(ro[hard].get("newton_iters", 0)), "newton_full": int(rf[hard].get("newton_iters", 0)),
               "step_ours_s": float(ro[hard]["wall"]), "step_full_s": float(rf[hard]["wall"]),
               "enriched": float(ro[hard].get("enriched_ratio", 0.0)), "modes": int(ro[hard].get("active_modes", 0)),
               "modes_available": int(red.basis.size), "reduced": bool(ro[hard].get("reduced", True)),
               "wall_ours_s": float(sum(r["wall"] for r in ro[:n])), "wall_full_s": float(sum(r["wall"] for r in rf[:n])),
               "reduced_steps": float(np.mean([r.get("reduced", True) for r in ro[:n]])),
               "max_error": max(errors[name][:n], default=0.0),
               "status": f"{result['full'].summary['status']}/{result[name].summary['status']}"}
        keys = sa.Stats.PHASES + tuple(CONTACT_TIMERS)
        so, sf = sims[name].stats[hard], full.stats[hard]  # the records with the IPC times added by on_frame
        row["phases_ours"] = {k: float(so[k]) for k in keys if k in so}
        row["phases_full"] = {k: float(sf[k]) for k in keys if k in sf}
        row["per_frame"] = {"wall_ours": [float(r["wall"]) for r in ro[:n]],
                            "wall_full": [float(r["wall"]) for r in rf[:n]],
                            "newton_ours": [int(r.get("newton_iters", 0)) for r in ro[:n]],
                            "newton_full": [int(r.get("newton_iters", 0)) for r in rf[:n]],
                            "enriched": [float(r.get("enriched_ratio", 0.0)) for r in ro[:n]],
                            "modes": [int(r.get("active_modes", 0)) for r in ro[:n]],
                            "reduced": [bool(r.get("reduced", True)) for r in ro[:n]], "error": errors[name][:n]}
        row["step_speedup"] = row["step_full_s"] / row["step_ours_s"]
        row["run_speedup"] = row["wall_full_s"] / row["wall_ours_s"]
        if args.repeats:
            at, system = systems[name]["hard"]
            x, v = states[at]
            row.update(linear_solves(sims[name], red, x.reshape(-1), v.reshape(-1), args.solver, args.repeats,
                                     system if at == hard else None))
            if systems[name]["enriched"] is not None:  # Table 3 where our system has enriched DOFs
                at, system = systems[name]["enriched"]
                x, v = states[at]
                solves = linear_solves(sims[name], red, x.reshape(-1), v.reshape(-1), args.solver, args.repeats, system)
                row.update({f"enr_{k}": val for k, val in solves.items()}, enr_step=at + 1)
        rows.append(row)
    return rows


def _eps(r):
    return f"{r['eps']:g}" + (f"/{r['eps_modal']:g}" if r["eps_modal"] != r["eps"] else "")


def print_table(rows, out=None):
    out = sys.stdout if out is None else out
    print(f"\n{'scene':>7} {'eps':>9} {'tets':>7} {'hard':>4} {'newton o/f':>10} {'step o (s)':>10} {'step f (s)':>10} "
          f"{'speedup':>7} {'run speedup':>11} {'enriched':>8} {'modes':>7} {'reduced':>7} {'max err':>8}", file=out)
    for r in rows:
        print(f"{r['scene']:>7} {_eps(r):>9} {r['tets']:>7} {r['hard_step']:>4} {r['newton_ours']:>4}/{r['newton_full']:<5} "
              f"{r['step_ours_s']:>10.3f} {r['step_full_s']:>10.3f} {r['step_speedup']:>7.2f} {r['run_speedup']:>11.2f} "
              f"{r['enriched']:>8.3f} {r['modes']:>3}/{r['modes_available']:<3} {r['reduced_steps']:>7.2f} "
              f"{r['max_error']:>8.1e}", file=out)
    solved = [(r, "hard") for r in rows if "schur_s" in r]
    solved += [({k[4:]: v for k, v in r.items() if k.startswith("enr_")}
                | {k: r[k] for k in ("scene", "eps", "eps_modal")}, f"step {r['enr_step']}")
               for r in rows if "enr_schur_s" in r]
    print(f"\n{'scene':>7} {'eps':>9} {'at':>8} {'schur (s)':>9} {'direct (s)':>10} {'BJ-CG (s)':>9} {'direct/schur':>12} {'CG/schur':>8} "
          f"{'schur it':>8} {'CG it':>6} {'nnz ours':>9} {'nnz full':>9} {'enr dofs':>8}", file=out)
    for r, at in solved:
        print(f"{r['scene']:>7} {_eps(r):>9} {at:>8} {r['schur_s']:>9.4f} {r['direct_s']:>10.4f} {r['cg_s']:>9.4f} "
              f"{r['direct_s'] / r['schur_s']:>12.1f} {r['cg_s'] / r['schur_s']:>8.1f} {r['schur_iters']:>8} "
              f"{r['cg_iters']:>6} {r['nnz_ours']:>9} {r['nnz_full']:>9} {r['enriched_dofs']:>8}", file=out)
    keys = [k for k in sa.Stats.PHASES + tuple(CONTACT_TIMERS)
            if any(k in r["phases_ours"] or k in r["phases_full"] for r in rows)]
    print("\nThe hard step by phase, ours / full (s; the ipc_* times are inside assembly, prediction, "
          "reduced_assembly and line_search):", file=out)
    print(f"{'scene':>7} {'eps':>9} " + " ".join(f"{k:>17}" for k in keys), file=out)
    for r in rows:
        print(f"{r['scene']:>7} {_eps(r):>9} " + " ".join(f"{r['phases_ours'].get(k, 0):>8.3f}/{r['phases_full'].get(k, 0):<8.3f}"
                                              for k in keys), file=out)
    print("\nThe paper (Table 1 step times ours/IPC in s, Table 3 solves ours/LLT/CG in s) for the nearest scene:", file=out)
    for r in {r["scene"]: r for r in rows}.values():
        name = NEAREST[r["scene"]]
        if name is None:
            print(f"{r['scene']:>7}: Fig. 5 (no timing; the paper: no enrichment while the cube slides)", file=out)
            continue
        t1, t3 = PAPER_TABLE1[name], PAPER_TABLE3[name]
        print(f"{r['scene']:>7}: {name}, {t1[2]:.0f} tets, enriched {t1[3]}, modes {t1[4]}, step {t1[5]} s vs "
              f"{t1[6]} s ({t1[6] / t1[5]:.1f}x); solve {t3[0]} / {t3[1]} / {t3[2]} s", file=out)


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scenes", nargs="+", choices=SCENES, default=list(SCENES))
    p.add_argument("--cells", type=int, default=6, help="tensor cells per box side (6 cells^3 tets per box)")
    p.add_argument("--frames", type=int, default=20)
    p.add_argument("--eps", type=float, nargs="+", default=[0.5],
                   help="eps_nodal = eps_modal (the paper's 0.5 for most scenes); several: one full-space run "
                        "serves them all, a row each")
    p.add_argument("--eps-modal", type=float, nargs="+", default=None,
                   help="eps_modal: one for every run or one per --eps (default: eps_modal = eps_nodal = --eps)")
    p.add_argument("--modes", type=int, default=16, help="Skinning Eigenmodes weights (12 columns each)")
    p.add_argument("--subdomains", type=int, default=200)
    p.add_argument("--fallback", default="nnz",
                   help="the reducer's fallback: 'nnz' (default), a fraction of the free DOFs, or 'none'")
    p.add_argument("--solver", default="pardiso" if sa.solvers.has_pardiso() else "superlu")
    p.add_argument("--repeats", type=int, default=3,
                   help="linear solves timed as the fastest of this many (0: no linear-solve comparison)")
    p.add_argument("--json", default="benchmarks/results/subspace_paper.json",
                   help="written after each scene (the scenes done so far)")
    p.add_argument("--verbose", action="store_true", help="a line per frame: wall, Newton iterations, IPC time, error")
    args = p.parse_args(argv)
    rows = []
    for kind in args.scenes:
        rows.extend(run_scene(kind, args))
        print(f"{kind}: done ({rows[-1]['tets']} tets, {rows[-1]['frames']} frames)", flush=True)
        if args.json:
            os.makedirs(os.path.dirname(os.path.abspath(args.json)), exist_ok=True)
            with open(args.json, "w") as fh:
                json.dump({"args": vars(args), "rows": rows}, fh, indent=1, default=float)
    print_table(rows)
    return rows


if __name__ == "__main__":
    main()
