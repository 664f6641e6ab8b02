"""The affinification paper's Table 1, reproduced: each scene three ways, the paper's numbers beside ours.

Runs every scene of the paper's Table 1 that we have a mesh for (the paper's own meshes,
read from MESH_DIR: docs/bodies.md says where to get them), plus procedural stand-ins where the
paper's mesh is not public (marked "stand-in"). Each scene is simulated in full space,
with affinification and with rigidification, stepped frame by frame in turn in one
process (interleaved, so that load from elsewhere on a shared machine slows every
method alike). The table has the paper's columns: wall time of each method (s), the
speedup of each over full, elements, vertices; plus the max distance error (largest
vertex distance to the full solve over all frames, over the scene's size) and the
DOF ratio. The paper's numbers stand beside ours. docs/paper_table1.md describes
the settings of each row.

Usage::

    python benchmarks/paper_table1.py MESH_DIR                    # the paper's frame counts
    python benchmarks/paper_table1.py MESH_DIR --frames 20 --scenes beam_neo wheel
    python benchmarks/paper_table1.py MESH_DIR --scenes wheel --checkpoint RUNS   # resumable, RUNS/wheel/report.md

Each scene is also reported over its rest phase (``--rest-from F``, else from the full solve's
kinetic energy) with per-phase means (factorisation, Delassus, PGS, detection, other): see
``benchmarks/resumable.py``.
"""
import argparse
import json
import os
import sys

import numpy as np

# measure the checkout this script sits in, not whatever skfem_affine is installed
sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
import skfem_affine as sa  # noqa: E402
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import resumable  # noqa: E402
from skfem_affine.integrators.problem import PHASES  # noqa: E402

# The paper's Table 1: affinification, rigidification, full wall time (s), frames, h,
# speedups, elements, vertices, nu, E, energy, tau_e, tau_a.
PAPER = {
    "Pills coarse": (80.37, 128.30, 206.18, 4000, 0.01, 2.57, 1.61, 8760, 2896, "0.34 0.36", "1e3 5e4", "Neo",
                     1e-4, 1e-5),
    "Pills medium": (113.36, 211.18, 391.65, 4000, 0.01, 3.45, 1.85, 14024, 3800, "0.34 0.36", "1e3 5e4", "Neo",
                     1e-4, 1e-5),
    "Pills HD": (187.33, 577.17, 1256.00, 4000, 0.01, 6.71, 2.18, 26688, 7872, "0.35 0.36", "1.1e3 5e4", "Neo",
                 1e-4, 1e-5),
    "Pills UHD": (277.01, 1089.70, 1844.60, 4000, 0.01, 10.49, 5.23, 41800, 9960, "0.35 0.36", "1.1e3 5e4", "Neo",
                  1e-4, 1e-5),
    "Octopus": (455.75, 560.06, 1157.70, 2500, 0.01, 2.54, 2.10, 34820, 10000, "0.34", "4e3", "Neo", 7e-5, 3e-5),
    "Explorer": (99.39, 133.36, 298.87, 2500, 0.005, 3.01, 2.24, 13204, 3810, "0.4 0.35", "2e4 5e2", "Neo",
                 1e-3, 1e-4),
    "Wheel": (19.65, 49.99, 332.44, 1000, 0.005, 16.92, 6.65, 17450, 5868, "0.34 0.4", "1.4e3 5e5", "Neo",
              1e-4, 1e-5),
    "Beam StVK": (8.88, 11.42, 16.72, 370, 0.01, 1.88, 1.46, 5516, 1264, "0.35", "1e5", "StVK", 2e-4, 1e-4),
    "Beam Neo": (8.87, 11.51, 16.45, 370, 0.01, 1.85, 1.42, 5516, 1264, "0.35", "1e5", "Neo", 2e-4, 1e-4),
    "Beam Corot": (3.47, 9.12, 15.90, 370, 0.01, 4.58, 1.74, 5516, 1264, "0.35", "1e5", "Corot", 2e-4, 1e-4),
    "Toothbrush": (11.95, 16.16, 46.01, 600, 0.01, 3.85, 2.85, 11574, 4325, "0.38 0.38", "5e5 2e2", "Neo",
                   1e-4, 95e-6),
    "Armadillo Res. Limited": (38.96, 34.66, 111.57, 1400, 0.005, 2.86, 3.21, 10785, 3193, "0.35", "1.2e2", "Neo",
                               6e-12, 4e-13),
    "Twisting beam": (2463.60, 3224.60, 4764.60, 1350, 0.01, 1.93, 1.48, 642400, 16106, "0.38", "5e3", "Neo",
                      11e-4, 10e-4),
}
# The paper gives no densities, damping or placement; where a row has none of its own below,
# we take those of the same scene in the rigidification code the paper was built on.
DENSITY = 100.0
DAMPING = sa.Rayleigh(alpha=0.03, beta=0.02)


def paper_beam(mesh_dir, material):
    """beam1264.mesh (2 x 2 x 6.85, long axis z): the z-min end pinned, gravity -9.8 along y."""
    mesh = sa.io.load_mesh(os.path.join(mesh_dir, "beam1264.mesh"))
    z = mesh.p[2]
    fixed = np.flatnonzero(z < z.min() + 1e-6 * np.ptp(z))

    def build(reducer):
        body = sa.ElasticBody(mesh, material, density=DENSITY, fixed=fixed)
        return sa.Simulation(body, dt=0.01, gravity=(0.0, -9.8, 0.0), damping=DAMPING, reducer=reducer)
    return build


def pills(mesh_dir):
    """Eight copies of Pill.mesh (39808 tets, the size of "Pills UHD") into our bowl, the paper's two materials."""
    path = os.path.join(mesh_dir, "Pill.mesh")
    mats = (sa.NeoHookean(E=1.1e3, nu=0.35), sa.NeoHookean(E=5e4, nu=0.36))
    return lambda reducer: sa.scenes.pills(mesh=path, materials=mats, density=DENSITY, dt=0.01, reducer=reducer)


def wheel(mesh_dir):
    """wheelFatHD.mesh in its own units (radius 1.03), dropped from 0.1 above a plane.

    Hub: the elements within 0.5 of the axle (as the rigidification code splits this mesh),
    E = 5e5, nu = 0.4, density 10; tyre: E = 1.4e3, nu = 0.34, density 3; Rayleigh as that
    code's tyre (alpha = 1e-5, beta = 0.05).
    """
    path = os.path.join(mesh_dir, "wheelFatHD.mesh")
    return lambda reducer: sa.scenes.wheel(mesh=path, hub_fraction=0.5 / 1.033,
                                           hub_material=sa.NeoHookean(E=5e5, nu=0.4),
                                           tyre_material=sa.NeoHookean(E=1.4e3, nu=0.34), density=(10.0, 3.0),
                                           damping=sa.Rayleigh(1e-5, 0.05), dt=0.005, reducer=reducer)


def octopus(mesh_dir, frames):
    """octopus.mesh scaled by 10 (y up, 10 m across) into a bowl of radius 8, a tentacle tugged mid-run.

    E = 4e3, nu = 0.34; density 10, Rayleigh alpha = 1e-4, beta = 0.1 and friction 0.5 as the
    rigidification code's octopus in a bowl (its bowl is a mesh; our analytic bowl's radius is ours);
    the tug is a tenth of the body's weight.
    """
    path = os.path.join(mesh_dir, "octopus.mesh")
    return lambda reducer: sa.scenes.octopus(mesh=path, up=1, size=10.0, bowl_radius=8.0, height=2.5,
                                             material=sa.NeoHookean(E=4e3, nu=0.34), density=10.0,
                                             damping=sa.Rayleigh(1e-4, 0.1), contact=sa.PGS(friction=0.5),
                                             tug=0.1, dt=0.01, frames=frames, reducer=reducer)


def toothbrush(mesh_dir):
    """Stand-in: the procedural toothbrush at resolution 2 (8832 tets), the scene's own materials."""
    return lambda reducer: sa.scenes.toothbrush(resolution=2, dt=0.01, reducer=reducer)


def armadillo(mesh_dir):
    """Stand-in: the procedural lumpy body at resolution 3 (4096 tets), the scene's own material."""
    return lambda reducer: sa.scenes.armadillo(resolution=3, dt=0.005, reducer=reducer)


def twisting_beam(mesh_dir):
    """Stand-in: the procedural sa.scenes.twisting_beam at resolution 3 (648 tets), the paper's E 5e3, nu 0.38."""
    return lambda reducer: sa.scenes.twisting_beam(resolution=3, dt=0.01, reducer=reducer)


# name: (paper row, needs a mesh file, factory(mesh_dir, frames) -> build(reducer), min affine fraction)
SCENES = {
    "beam_stvk": ("Beam StVK", "beam1264.mesh", lambda d, f: paper_beam(d, sa.StVK(E=1e5, nu=0.35)), 0.0),
    "beam_neo": ("Beam Neo", "beam1264.mesh", lambda d, f: paper_beam(d, sa.NeoHookean(E=1e5, nu=0.35)), 0.0),
    "beam_corot": ("Beam Corot", "beam1264.mesh", lambda d, f: paper_beam(d, sa.Corotational(E=1e5, nu=0.35)), 0.0),
    "pills": ("Pills UHD", "Pill.mesh", lambda d, f: pills(d), 0.0),
    "wheel": ("Wheel", "wheelFatHD.mesh", lambda d, f: wheel(d), 0.0),
    "octopus": ("Octopus", "octopus.mesh", octopus, 0.0),
    "toothbrush": ("Toothbrush", None, lambda d, f: toothbrush(d), 0.0),
    "armadillo": ("Armadillo Res. Limited", None, lambda d, f: armadillo(d), 1 / 3),
    "twisting_beam": ("Twisting beam", None, lambda d, f: twisting_beam(d), 0.0),
}
NOT_RUN = {"Explorer": "no mesh", "Pills coarse": "no mesh of that size", "Pills medium": "no mesh of that size",
           "Pills HD": "no mesh of that size"}


def reducers(row, fraction):
    """Affinification and rigidification at the paper's thresholds of the row (rigidification: tau_r = tau_a)."""
    tau_e, tau_a = PAPER[row][12], PAPER[row][13]
    return [sa.Affinification(tau_a=tau_a, tau_e=tau_e, min_fraction=fraction),
            sa.Rigidification(tau_r=tau_a, tau_e=tau_e, min_fraction=fraction)]


def run_interleaved(build, reducer_list, frames, **kwargs):
    """Step full space and every reducer frame by frame, in turn, in one process (:func:`resumable.run`).

    Returns the full simulation, one dict per method (full first): wall time (s), DOFs, max
    distance error over the scene size, the frame it diverged at (or None), and the seconds of
    each timed phase (contact, assembly, factorization, ...) summed over the run; and the
    per-frame records. ``kwargs`` go to :func:`resumable.run` (checkpoint folder, ...).
    """
    sims, progress = resumable.run(build, reducer_list, frames, **kwargs)
    totals = []
    for i, recs in enumerate(progress["records"]):
        errs = [e for e in progress["errors"][i] if e is not None]
        totals.append({"wall": float(sum(r["wall"] for r in recs)), "dofs": float(sum(r["dofs"] for r in recs)),
                       "err": max(errs, default=0.0), "diverged": progress["diverged"][i],
                       "phases": {key: float(sum(r[key] for r in recs)) for key in PHASES}})
    return sims[0], totals, progress


def measure(name, mesh_dir, frames=None, checkpoint=None, every=25, stop_at=None, rest_from=None, rest_ke=0.01,
            command=None):
    """One row of the table: our numbers for scene ``name`` beside the paper's, over the run and its rest phase.

    With ``checkpoint`` (a folder), the run is saved in ``checkpoint/name`` every ``every`` frames with
    a report of the frames done so far, and continued from there when started again.
    """
    row, mesh_file, factory, fraction = SCENES[name]
    paper = PAPER[row]
    frames = paper[3] if frames is None else int(frames)
    build = factory(mesh_dir, frames)
    folder = os.path.join(checkpoint, name) if checkpoint else None
    title, speedups = report_title(name, frames)
    meta = {"scene": name, "paper row": row, "command": command or "-", "machine": machine(),
            "thresholds": f"tau_e {paper[12]:g}, tau_a (= tau_r) {paper[13]:g}"}

    def report(progress):
        resumable.write_report(folder, title, progress, rest_from, rest_ke, speedups)
    sim, (full, aff, rig), progress = run_interleaved(build, reducers(row, fraction), frames, checkpoint=folder,
                                                      every=every, stop_at=stop_at, meta=meta, on_save=report)
    split = resumable.phases(progress, rest_from, rest_ke)
    return {"scene": name, "paper_row": row, "stand_in": mesh_file is None, "frames": frames,
            "frames_done": progress["done"], "h": sim.dt,
            "elements": sim.system.m, "vertices": sim.system.n,
            "affinification_s": aff["wall"], "rigidification_s": rig["wall"], "full_s": full["wall"],
            "speedup_affinification": full["wall"] / aff["wall"] if aff["wall"] else None,
            "speedup_rigidification": full["wall"] / rig["wall"] if rig["wall"] else None,
            "max_distance_error_affinification": aff["err"], "max_distance_error_rigidification": rig["err"],
            "dof_ratio_affinification": aff["dofs"] / full["dofs"] if full["dofs"] else None,
            "dof_ratio_rigidification": rig["dofs"] / full["dofs"] if full["dofs"] else None,
            "phases_s": {k: r["phases"] for k, r in zip(("full", "affinification", "rigidification"), (full, aff, rig))},
            "diverged": {k: r["diverged"] for k, r in zip(("full", "affinification", "rigidification"),
                                                          (full, aff, rig)) if r["diverged"] is not None},
            "run": split["run"], "rest": split["rest"], "rest_rule": split["rest_rule"],
            "paper": {"affinification_s": paper[0], "rigidification_s": paper[1], "full_s": paper[2],
                      "frames": paper[3], "h": paper[4], "speedup_affinification": paper[5],
                      "speedup_rigidification": paper[6], "elements": paper[7], "vertices": paper[8]}}


def report_title(name, frames):
    """The title of a scene's report and the paper's speedups of its row."""
    row = SCENES[name][0]
    return (f"{row}: {name}, {frames} frames, full / affinification / rigidification",
            {"affinification": PAPER[row][5], "rigidification": PAPER[row][6]})


def report_only(checkpoint, names, rest_from=None, rest_ke=0.01):
    """Rewrite the reports of runs saved in ``checkpoint`` (e.g. with another rest phase) without stepping."""
    for name in names:
        folder = os.path.join(checkpoint, name)
        path = os.path.join(folder, resumable.PROGRESS)
        if not os.path.isfile(path):
            print(f"{name}: no run saved in {folder}")
            continue
        with open(path) as fh:
            progress = json.load(fh)
        title, speedups = report_title(name, progress["frames_total"])
        resumable.write_report(folder, title, progress, rest_from, rest_ke, speedups)
        print(open(os.path.join(folder, "report.md")).read())


def machine():
    """Cores, load average and BLAS/MKL/numba thread settings, for the report."""
    env = ", ".join(f"{v}={os.environ[v]}" for v in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS",
                                                     "NUMBA_NUM_THREADS") if v in os.environ)
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    return f"{os.cpu_count()} cores, load average {load:.1f} at the start" + (f", {env}" if env else "")


def _f(x, fmt):
    return "-" if x is None else format(x, fmt)


def _done(row):
    done = row.get("frames_done", row["frames"])
    return f"{row['frames']}" if done == row["frames"] else f"{done} of {row['frames']}"


def markdown(rows):
    """The table as Markdown: ours and the paper's (p.) side by side."""
    head = ("| scene | frames | h | elements (p.) | vertices (p.) | affin. s (p.) | rigid. s (p.) | full s (p.) "
            "| speedup affin. (p.) | speedup rigid. (p.) | max dist. err. affin. / rigid. |")
    lines = [head, "|" + "---|" * (head.count("|") - 1)]
    for r in rows:
        p = r["paper"]
        label = f"{r['paper_row']}" + (" (stand-in)" if r["stand_in"] else "") + \
            ("" if not r["diverged"] else f" diverged {r['diverged']}")
        lines.append(
            f"| {label} | {_done(r)} ({p['frames']}) | {r['h']:g} ({p['h']:g}) | {r['elements']} ({p['elements']}) "
            f"| {r['vertices']} ({p['vertices']}) | {r['affinification_s']:.2f} ({p['affinification_s']:.2f}) "
            f"| {r['rigidification_s']:.2f} ({p['rigidification_s']:.2f}) | {r['full_s']:.2f} ({p['full_s']:.2f}) "
            f"| {_f(r['speedup_affinification'], '.2f')} ({p['speedup_affinification']:.2f}) "
            f"| {_f(r['speedup_rigidification'], '.2f')} ({p['speedup_rigidification']:.2f}) "
            f"| {r['max_distance_error_affinification']:.1e} / {r['max_distance_error_rigidification']:.1e} |")
    for row, why in NOT_RUN.items():
        if row in {r["paper_row"] for r in rows}:
            continue
        p = PAPER[row]
        lines.append(f"| {row}: not run, {why} | - ({p[3]}) | - ({p[4]:g}) | - ({p[7]}) | - ({p[8]}) | - ({p[0]:.2f}) "
                     f"| - ({p[1]:.2f}) | - ({p[2]:.2f}) | - ({p[5]:.2f}) | - ({p[6]:.2f}) | - |")
    return "\n".join(lines) + "\n"


def phase_tables(row):
    """Run and rest rows of one scene with their per-phase means (Markdown)."""
    split = {"run": row["run"], "rest": row["rest"], "rest_rule": row["rest_rule"]}
    paper = {"affinification": row["paper"]["speedup_affinification"],
             "rigidification": row["paper"]["speedup_rigidification"]}
    return f"## {row['paper_row']}: the run and its rest phase\n\n" + resumable.tables(split, paper=paper)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("mesh_dir", help="folder of the paper's meshes (see docs/bodies.md)")
    ap.add_argument("--scenes", nargs="+", default=list(SCENES), choices=list(SCENES))
    ap.add_argument("--frames", type=int, default=None, help="frames of every scene (default: the paper's)")
    ap.add_argument("--out", default="benchmarks/results/paper_table1", help="writes OUT.md and OUT.json")
    ap.add_argument("--checkpoint", default=None, metavar="DIR",
                    help="save each scene's run in DIR/SCENE every --every frames with a report of the frames done "
                         "(report.md, report.json); a run started again with the same DIR continues from there")
    ap.add_argument("--every", type=int, default=25, help="frames between checkpoints (default 25)")
    ap.add_argument("--stop-at", type=int, default=None, metavar="F",
                    help="stop once F frames are done (with --checkpoint: continue later)")
    ap.add_argument("--rest-from", type=int, default=None, metavar="F",
                    help="first frame of the rest phase (default: from the full solve's kinetic energy, --rest-ke)")
    ap.add_argument("--rest-ke", type=float, default=0.01,
                    help="rest: the kinetic energy stays below this fraction of its peak (default 0.01)")
    ap.add_argument("--report-only", action="store_true",
                    help="rewrite the reports of the runs saved in --checkpoint DIR (another --rest-from) and stop")
    args = ap.parse_args(argv)
    if args.report_only:
        if not args.checkpoint:
            ap.error("--report-only reads the runs of --checkpoint DIR")
        return report_only(args.checkpoint, args.scenes, args.rest_from, args.rest_ke)
    if args.every < 1:
        ap.error(f"--every must be at least 1, got {args.every}")
    if not os.path.isdir(args.mesh_dir):
        ap.error(f"MESH_DIR {args.mesh_dir!r} is not a folder")
    missing = [n for n in args.scenes
               if SCENES[n][1] and not os.path.isfile(os.path.join(args.mesh_dir, SCENES[n][1]))]
    if missing:
        ap.error(f"no mesh in {args.mesh_dir} for: " + ", ".join(f"{n} ({SCENES[n][1]})" for n in missing))
    # compile (or load from numba's cache) every kernel before any timing
    run_interleaved(lambda r: sa.scenes.cantilever(resolution=1, reducer=r), reducers("Beam Neo", 0.0), 3)
    rows = []
    for name in args.scenes:
        rows.append(measure(name, args.mesh_dir, args.frames, checkpoint=args.checkpoint, every=args.every,
                            stop_at=args.stop_at, rest_from=args.rest_from, rest_ke=args.rest_ke,
                            command="python benchmarks/paper_table1.py " + " ".join(argv or sys.argv[1:])))
        r = rows[-1]
        print(f"{name}: {r['elements']} tets, {r['frames']} frames, full {r['full_s']:.2f} s, "
              f"affinification {r['affinification_s']:.2f} s, rigidification {r['rigidification_s']:.2f} s"
              + (f", diverged {r['diverged']}" if r["diverged"] else ""), flush=True)
    table = markdown(rows) + "".join("\n" + phase_tables(r) for r in rows)
    print(table)
    if args.out:
        os.makedirs(os.path.dirname(args.out) or ".", exist_ok=True)
        with open(args.out + ".md", "w") as fh:
            fh.write(table)
        with open(args.out + ".json", "w") as fh:
            json.dump(rows, fh, indent=1)
    return rows


if __name__ == "__main__":
    main()
