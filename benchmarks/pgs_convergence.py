"""How far the PGS contact solve converges, and what more sweeps would cost and change.

Steps a contact scene in full space twice, frame by frame in turn in one process: once with
the default sweep cap and once with a larger one, no extra sweeps in either (``max_iterations``
= the cap), and with ``--default`` a third time with the default settings; prints for each the fraction of frames
whose contact residual reached the tolerance (``pgs_converged``), the sweeps, the relative
residual (``contact_residual / contact_scale``), frames with unresolved contact, the PGS kernel's
share of the frame, the deepest penetration, and the largest vertex distance between the two
runs relative to the scene size (what stopping at the cap changes).

With ``--solvers``, the contact iterations are compared instead: those of ``--compare`` (default
plain Gauss-Seidel sweeps, Anderson-accelerated sweeps and block Gauss-Seidel over groups of coupled
contacts; caps ``--solver-caps``, default 50 each, the other settings the defaults), and
``--reference`` (default block Gauss-Seidel) run to the tolerance (a cap of 2000; not with
``--no-reference``); the frames from ``--start`` on are summarised, with the contact phase's
time (detection, Delassus operator, solve, corrections) and the PGS solve's time of each
relative to the first, and each run's largest vertex distance to the run to tolerance
and its deepest penetration over the window, and its kinetic energy per frame (with its largest
difference to the first iteration's run, relative). ``--resume CHECKPOINT`` starts every run from the
positions, velocities and contact warm start of a full-space checkpoint of the scene (saved with
any PGS settings, e.g. by ``benchmarks/paper_table1.py --checkpoint``), ``--frames`` more frames.

Usage::

    python benchmarks/pgs_convergence.py --scene pills --frames 120          # 8 procedural pills
    python benchmarks/pgs_convergence.py --scene stack --frames 40 --caps 50 3000 --default   # heavy on light
    MESH_DIR=... python benchmarks/pgs_convergence.py --scene paper-pills --frames 100   # the paper's Pill.mesh
    MESH_DIR=... python benchmarks/pgs_convergence.py --scene table1-pills --solvers --start 30 --frames 90
    MESH_DIR=... python benchmarks/pgs_convergence.py --scene table1-pills --solvers --resume RUNS/pills/full-000275.npz --frames 20
    MESH_DIR=... python benchmarks/pgs_convergence.py --scene wheel --solvers --frames 200   # also octopus, pile
"""
import argparse
import dataclasses
import json
import os
import sys

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import numpy as np  # noqa: E402

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
sys.path.insert(1, os.path.dirname(os.path.abspath(__file__)))
import skfem_affine as sa  # noqa: E402
from skfem_affine import checkpoint  # noqa: E402
from skfem_affine.lab import metrics, runners  # noqa: E402
from skfem_affine.contact.pgs import SOLVERS  # noqa: E402
from skfem_affine.simulation import State  # noqa: E402


def scene(name, caps_contact, method="full"):
    """Factory of the scene with ``contact=caps_contact``; ``method`` (pile, wheel, octopus) "full", or
    "affinification" / "rigidification" at the thresholds of benchmarks/contact_phases.py."""
    if name == "pills":
        return sa.scenes.pills(n=8, resolution=1, contact=caps_contact)
    if name == "paper-pills":
        mesh_dir = os.environ.get("MESH_DIR") or os.environ.get("SKFEM_AFFINE_MESHES")
        if not mesh_dir:
            raise SystemExit("set MESH_DIR (or SKFEM_AFFINE_MESHES) to the folder of the paper's meshes")
        mats = (sa.NeoHookean(E=1.1e3, nu=0.35), sa.NeoHookean(E=5e4, nu=0.36))
        return sa.scenes.pills(mesh=os.path.join(mesh_dir, "Pill.mesh"), materials=mats, contact=caps_contact)
    if name == "table1-pills":  # as benchmarks/paper_table1.py builds it (its density and step)
        import paper_table1
        mesh_dir = os.environ.get("MESH_DIR") or os.environ.get("SKFEM_AFFINE_MESHES")
        if not mesh_dir:
            raise SystemExit("set MESH_DIR (or SKFEM_AFFINE_MESHES) to the folder of the paper's meshes")
        mats = (sa.NeoHookean(E=1.1e3, nu=0.35), sa.NeoHookean(E=5e4, nu=0.36))
        return sa.scenes.pills(mesh=os.path.join(mesh_dir, "Pill.mesh"), materials=mats,
                               density=paper_table1.DENSITY, dt=0.01, contact=caps_contact)
    if name == "stack":  # a stiff box 1e4 times denser than the soft one it lands on
        box = sa.scenes.box_mesh
        light = sa.ElasticBody(box(0.2, 2, (0, 0, 0.1)), sa.NeoHookean(E=1e6, nu=0.3), density=10.0)
        heavy = sa.ElasticBody(box(0.2, 2, (0, 0, 0.302)), sa.NeoHookean(E=1e9, nu=0.3), density=1e5)
        return sa.Simulation([light, heavy], dt=0.01, gravity=(0, 0, -9.81), colliders=[sa.Plane()],
                             contact=caps_contact)
    if name == "pile":  # four soft boxes coming to rest (benchmarks/budget.py), 4 cells per box edge
        from budget import pile
        reducer = {"full": None, "affinification": sa.Affinification(tau_a=1e-4, tau_e=2e-4),
                   "rigidification": sa.Rigidification(tau_r=1e-4, tau_e=2e-4)}[method]
        return with_contact(pile(4, reducer), caps_contact)
    if name in ("wheel", "octopus"):  # as benchmarks/paper_table1.py builds them
        import paper_table1
        mesh_dir = os.environ.get("MESH_DIR") or os.environ.get("SKFEM_AFFINE_MESHES")
        if not mesh_dir:
            raise SystemExit("set MESH_DIR (or SKFEM_AFFINE_MESHES) to the folder of the paper's meshes")
        row, _, factory, fraction = paper_table1.SCENES[name]
        reducer = None if method == "full" else paper_table1.reducers(row, fraction)[method == "rigidification"]
        return with_contact(factory(mesh_dir, 1000)(reducer), caps_contact)
    raise SystemExit(f"unknown scene {name!r}")


def with_contact(sim, settings):
    """``sim`` with the sweep settings (solver, caps, tolerance) of ``settings``, its scene's friction kept."""
    st = sim.contact.settings
    sim.contact.settings = dataclasses.replace(st, solver=settings.solver, iterations=settings.iterations,
                                               max_iterations=settings.max_iterations, tolerance=settings.tolerance)
    return sim


def summary(records, start=0):
    records = [r for r in records if r["frame"] >= start]
    rel = [r["contact_residual"] / r["contact_scale"] for r in records if r.get("contact_scale")]
    sweeps = [r["pgs_iterations"] for r in records if r.get("n_contacts")]
    walls = sum(r["wall"] for r in records)
    return {"frames_with_contact": len(sweeps),
            "converged": float(np.mean([r["pgs_converged"] for r in records if r.get("n_contacts")])) if sweeps else None,
            "median_sweeps": float(np.median(sweeps)) if sweeps else None, "max_sweeps": max(sweeps, default=0),
            "median_rel_residual": float(np.median(rel)) if rel else None, "max_rel_residual": max(rel, default=0.0),
            "unresolved_frames": int(sum(bool(r.get("contact_unresolved")) for r in records)),
            "pgs_share": sum(r.get("pgs", 0.0) for r in records) / walls if walls else None,
            "contact_s": sum(r.get("contact", 0.0) for r in records), "pgs_s": sum(r.get("pgs", 0.0) for r in records),
            "max_penetration": max(r.get("max_penetration", 0.0) for r in records), "wall_s": walls}


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--scene", default="pills",
                   choices=["pills", "paper-pills", "table1-pills", "stack", "pile", "wheel", "octopus"])
    p.add_argument("--frames", type=int, default=120)
    p.add_argument("--caps", type=int, nargs=2, default=[50, 400], help="the default and the larger sweep cap")
    p.add_argument("--default", action="store_true",
                   help="also the default settings (extra sweeps while contact is unresolved)")
    p.add_argument("--solvers", action="store_true", help="compare the contact iterations (see above)")
    p.add_argument("--start", type=int, default=0, help="summarise the frames from this one on (--solvers)")
    p.add_argument("--compare", nargs="+", default=["gauss-seidel", "anderson", "block"], choices=sorted(SOLVERS),
                   help="--solvers: the iterations compared (the first is the base of the ratios)")
    p.add_argument("--solver-caps", type=int, nargs="+", default=[50],
                   help="--solvers: the sweep caps (iterations) of the --compare iterations (one for all, or one each)")
    p.add_argument("--reference", default="block", choices=sorted(SOLVERS),
                   help="--solvers: the iteration run to the tolerance")
    p.add_argument("--method", default="full", choices=["full", "affinification", "rigidification"],
                   help="--solvers on the pile, wheel or octopus: the reducer (at contact_phases.py's / the paper's "
                        "thresholds)")
    p.add_argument("--resume", default=None, metavar="CHECKPOINT",
                   help="--solvers: start from this full-space checkpoint's state and warm start")
    p.add_argument("--no-reference", action="store_true", help="--solvers: without the run to tolerance")
    args = p.parse_args(argv)
    friction = 0.3 if "pills" in args.scene else 0.5
    if args.solvers:
        return compare_solvers(args, friction)
    sims = {f"cap {c}": scene(args.scene, sa.PGS(friction=friction, iterations=c, max_iterations=c))
            for c in args.caps}
    names = list(sims)
    if args.default:
        sims["default"] = scene(args.scene, sa.PGS(friction=friction))
    gap = [0.0]

    def on_frame(frame, running):
        if all(n in running for n in names):
            a, b = (running[n] for n in names)
            gap[0] = max(gap[0], metrics.distance_error(a.state.x, b.state.x, a.size))

    runs = runners.interleaved(sims, args.frames, on_frame=on_frame)
    out = {name: summary(runs[name].records) for name in sims}
    out["distance_between_caps"] = gap[0]
    out["scene"], out["frames"] = args.scene, args.frames
    print(json.dumps(out, indent=1))
    return out


def resume(sim, path):
    """``sim`` at the state and contact warm start of the full-space checkpoint ``path`` of its scene
    (saved with any PGS settings, so not through ``load_state``, which checks them)."""
    header, arrays = checkpoint.read(path)
    values = header["values"]
    x, v = arrays["state.x"], arrays["state.v"]
    if x.shape != sim.state.x.shape:
        raise SystemExit(f"{path} holds {x.shape[0]} vertices, the scene {sim.state.x.shape[0]}")
    sim.state = State(x.copy(), v.copy(), int(values["state.frame"]), float(values["state.time"]))
    if values.get("contact.previous"):
        sim.contact.previous = (arrays["contact.previous_keys"].copy(), arrays["contact.previous_world"].copy())


def warm_up(names):
    """Compile (or load from numba's cache) the iterations ``names`` on a small problem before any timing."""
    W = np.eye(6) + 0.6 * np.eye(6, k=3) + 0.6 * np.eye(6, k=-3)
    for name in names:
        SOLVERS[name](W, np.array([-1.0, 0.2, 0.0, -1.0, 0.0, 0.1]), np.zeros(6), 0.5, 5, 0.0, 5, 0.0, 0.0)


def compare_solvers(args, friction):
    """The iterations of ``--compare`` and the ``--reference`` to tolerance, stepped in turn (module docstring)."""
    caps = args.solver_caps * len(args.compare) if len(args.solver_caps) == 1 else args.solver_caps
    if len(caps) != len(args.compare):
        raise SystemExit("--solver-caps: one cap, or one per --compare iteration")
    settings = {f"{name}, cap {cap}": sa.PGS(friction=friction, solver=name, iterations=cap)
                for name, cap in zip(args.compare, caps)}
    if not args.no_reference:
        settings["to tolerance"] = sa.PGS(friction=friction, solver=args.reference, iterations=2000,
                                          max_iterations=2000)
    sims = {name: scene(args.scene, st, args.method) for name, st in settings.items()}
    warm_up(args.compare + [args.reference])
    if args.resume:
        for sim in sims.values():
            resume(sim, args.resume)
    gap = {name: 0.0 for name in sims}
    kinetic = {name: [] for name in sims}

    def on_frame(frame, running):
        for name, sim in running.items():
            kinetic[name].append(float(0.5 * (sim.system.lumped_mass * (sim.state.v ** 2).sum(axis=1)).sum()))
        if frame >= args.start and len(running) == len(sims) and "to tolerance" in running:
            ref = running["to tolerance"].state.x
            for name, sim in running.items():
                gap[name] = max(gap[name], metrics.distance_error(sim.state.x, ref, sim.size))

    runs = runners.interleaved(sims, args.frames, on_frame=on_frame)
    out = {name: summary(runs[name].records, args.start) for name in sims}
    first = next(iter(sims))
    base = out[first]
    for name in sims:  # the kinetic energy frame by frame against the first iteration's run
        a, b = np.array(kinetic[first]), np.array(kinetic[name])
        n = min(a.size, b.size)
        out[name]["max_kinetic_energy_difference"] = float(np.max(np.abs(b[:n] - a[:n]) / np.maximum(a[:n], 1e-300),
                                                                 initial=0.0))
        out[name]["kinetic_energy"] = b.tolist()
    for name in sims:
        out[name].update(distance_to_tolerance=gap[name] if "to tolerance" in sims else None, contact_ratio=out[name]["contact_s"] / base["contact_s"],
                         pgs_ratio=out[name]["pgs_s"] / base["pgs_s"])
    out["scene"], out["frames"], out["start"], out["method"] = args.scene, args.frames, args.start, args.method
    print(json.dumps(out, indent=1))
    return out


if __name__ == "__main__":
    main()
