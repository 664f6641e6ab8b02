"""Where a contact frame's time goes: per-phase means over a window of frames, full / affinification /
rigidification stepped in turn in one process, on the paper's contact scenes.

The scenes are those of ``benchmarks/paper_table1.py`` (the paper's meshes, read from MESH_DIR, and
its thresholds), and, with no MESH_DIR, at the thresholds tau_a = 1e-4, tau_e = 2e-4: ``pile``, the four
soft boxes of ``benchmarks/budget.py`` (``--cells`` per box edge) coming to rest on the ground;
``stacked_beams``, ``sa.scenes.stacked_beams`` (three beams, ``--cells`` across a beam's width); and
``bowling``, ``sa.scenes.bowling`` (three stiff balls onto a soft mattress, resolution ``--cells``).
Every method runs from frame 0; the frames ``--start`` to ``--end`` are recorded: the frame's wall
time, the factorisation, the Delassus operator and the columns it solved, the PGS solve (with the
velocity and position corrections), detection (the rest of contact), the contacts and the DOFs
solved, and the CPU time (all threads) of the frame and of its contact (detection and resolve), which a
loaded machine inflates less than wall time (``cpu``, ``contact_cpu``, ``contact share of the CPU``).
The order of the methods rotates from frame to frame. With ``--rows`` each frame's
Delassus operator is also built per row of J (3 solves per contact on the whole system:
``Resolvent(touched=False)``) on the same factorisation, before or after the frame's own in turn
(``delassus_rows``, ``rows_columns``); with ``--columns`` instead from solves of the unit columns of
the unknowns the contacts touch (no Schur complement; the bodies' columns side by side), so that
the frame's own (``delassus``, from the Schur complement where it is taken: ``delassus_schur``
unknowns) is compared with it. With ``--profile METHOD`` that method's frames in the window also
run under cProfile, and the contact functions outside the Delassus operator (detection, the
Jacobian, warm start, prediction impulses, the PGS sweeps and the split-impulse correction) are
listed by their time per frame. With ``--frame-schur`` the methods are instead two full-space runs
stepped in turn: the frame factorised plainly (the Schur complement on a handle of its own) and the
frame factorised with the contacts' unknowns last, its complement giving the Delassus operator
(``SchurInverse.frame``); ``--frame-schur affinification`` (or ``rigidification``) compares the same two
routes of that reducer's frames (A_r factorised with the reduced unknowns the contacts touch last).
With ``--blocks`` the methods are two full-space runs stepped in turn whose frames' contacts touch
several bodies: factorised plainly, each large body's complement on a handle of its own
(``SchurInverse.blocks`` off), and factorised body by body with each body's touched unknowns last;
With ``--lookahead K`` the methods are two full-space runs whose frames are factorised with the
contacts' unknowns last: on the touched unknowns (no prediction), and on the vertices a collider reaches
within K more frames at their approach speed when a new analysis is needed (``Detector.lookahead``,
at most ``--spread`` times the touched unknowns, ``SchurInverse.spread``); ``analyses`` counts the new
analyses per frame.
``--resume CHECKPOINT`` (a full-space checkpoint of the scene, e.g. from ``paper_table1.py
--checkpoint``, or ``Simulation.save``) starts both runs of ``--blocks``, ``--frame-schur`` or
``--lookahead`` from it instead of frame 0, so that ``--start`` and ``--end`` count on from its frame;
without those, ``--resume`` names each method's checkpoint with ``{method}`` (``full``,
``affinification``, ``rigidification``), and ``--methods`` steps only some of the three.
``--plain-blocks METHOD`` also steps a second run of that reducer whose reduced frames of several bodies
are factorised plainly, each body's Z then solved from its unit columns (``SchurInverse.blocks`` off),
beside the one factorising each body's block with its touched unknowns last.
Usage::

    python benchmarks/contact_phases.py MESH_DIR --scene wheel --start 145 --end 160 --rows
    python benchmarks/contact_phases.py --scene pile --cells 4 --start 100 --end 130 --rows
    python benchmarks/contact_phases.py --scene pile --cells 4 --start 100 --end 119 --profile affinification
    python benchmarks/contact_phases.py MESH_DIR --scene wheel --start 145 --end 151 --frame-schur
    python benchmarks/contact_phases.py MESH_DIR --scene wheel --start 145 --end 151 --frame-schur affinification
    python benchmarks/contact_phases.py MESH_DIR --scene pills --start 50 --end 56 --blocks
    python benchmarks/contact_phases.py MESH_DIR --scene pills --start 277 --end 287 --blocks --resume RUNS/pills/full-000275.npz
    python benchmarks/contact_phases.py MESH_DIR --scene octopus --start 66 --end 82 --lookahead 2 --resume RUN.npz
    python benchmarks/contact_phases.py MESH_DIR --scene pills --start 2900 --end 2910 --methods full affinification \
        --resume 'RUNS/pills/{method}-002900.npz' --plain-blocks affinification
    python benchmarks/contact_phases.py --scene stacked_beams --cells 6 --start 8 --end 14 --frame-schur
    python benchmarks/contact_phases.py --scene bowling --cells 3 --start 20 --end 26 --frame-schur
"""
import argparse
import cProfile
import dataclasses
import io
import json
import os
import pstats
import re
import sys
import time

# one BLAS/MKL thread for every method (read before numpy loads them)
THREADS = sys.argv[sys.argv.index("--threads") + 1] if "--threads" in sys.argv else "1"
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, THREADS)

import numpy as np  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))  # measure the checkout this script sits in
sys.path.insert(0, HERE)
import paper_table1  # noqa: E402
import skfem_affine as sa  # noqa: E402
from skfem_affine.contact import delassus  # noqa: E402

METHODS = ("full", "affinification", "rigidification")
FRAME_METHODS = ("full, own handle", "full, frame's Schur")  # --frame-schur
BLOCK_METHODS = ("full, plain + own complements", "full, body by body")  # --blocks
LOOKAHEAD_METHODS = ("full, touched unknowns", "full, predicted superset")  # --lookahead
# The scenes of sa.scenes run without MESH_DIR (--cells: their resolution) and their settings.
LAB_SCENES = {"stacked_beams": dict(n=3), "bowling": dict(n=3)}
COLUMNS = ("wall", "factorization", "delassus", "delassus_columns", "delassus_schur", "delassus_dense",
           "frame_schur", "pgs", "detection", "contact", "cpu", "contact_cpu", "other", "assembly", "prediction",
           "clustering", "map_assembly", "reduced_assembly", "solve", "checks",
           "n_contacts",
           "pgs_iterations", "dofs", "analyses")
ROWS = ("delassus_rows", "rows_columns")


def record(rec):
    """The columns of one frame's record (times in ms)."""
    out = {k: 1e3 * float(rec.get(k, 0.0)) for k in ("wall", "factorization", "delassus", "pgs", "contact",
                                                      "delassus_rows", "assembly", "prediction", "clustering",
                                                      "map_assembly", "reduced_assembly", "solve", "checks")}
    out["detection"] = out["contact"] - out["delassus"] - out["pgs"]
    out["wall"] -= out["delassus_rows"]  # the frame without the extra per-row Delassus operator
    out["other"] = out["wall"] - out["factorization"] - out["contact"]
    out.update({k: float(rec.get(k, 0)) for k in ("n_contacts", "pgs_iterations", "dofs", "delassus_columns",
                                                  "delassus_schur", "delassus_dense", "frame_schur", "rows_columns")})
    return out


def per_row(sim, columns=False):
    """Also build each frame's Delassus operator per row of J (``columns``: from solves of the unit
    columns of the touched unknowns, the bodies' side by side, no Schur complement) on the frame's
    factorisation, timed, before the frame's own on even frames and after it on odd ones
    (``delassus_rows``, s)."""
    original, cache = sim.contact.resolve, {}

    def resolve(problem, result, rec):
        cs = sim.contact.current
        if cs is None or result.operator is None:
            return original(problem, result, rec)

        def rows():
            t0 = time.perf_counter()
            res = delassus.Resolvent(result.operator, block=sim.contact.settings.block, cache=cache,
                                     touched=columns, bodies=sim.contact.bodies if columns else None)
            res.delassus(cs.J)
            rec.update(delassus_rows=time.perf_counter() - t0, rows_columns=res.columns_solved)

        if problem.frame % 2 == 0:
            rows()
        out = original(problem, result, rec)
        if problem.frame % 2:
            rows()
        return out

    sim.contact.resolve = resolve


def contact_clock(sim):
    """Count the CPU time (``time.process_time``, s) of the simulation's contact detection and resolve:
    returns a one-entry list that the two add to."""
    spent, contact = [0.0], sim.contact

    def timed(fn):
        def call(*args, **kwargs):
            t0 = time.process_time()
            try:
                return fn(*args, **kwargs)
            finally:
                spent[0] += time.process_time() - t0
        return call

    contact.detect, contact.resolve = timed(contact.detect), timed(contact.resolve)
    return spent


# The contact functions outside the Delassus operator that --profile lists (file, function).
PROFILED = (("pgs.py", "detect"), ("geometry.py", "find"), ("geometry.py", "_body_contacts"),
            ("geometry.py", "_edge_contacts"), ("geometry.py", "frames"), ("delassus.py", "jacobian"),
            ("pgs.py", "_warm_start"), ("pgs.py", "_predicted_impulses"), ("pgs.py", "_impacts"),
            ("pgs.py", "resolve"), ("delassus.py", "delassus"), ("delassus.py", "apply"),
            ("pgs.py", "projected_gauss_seidel"), ("pgs.py", "anderson_gauss_seidel"),
            ("pgs.py", "contact_residual"), ("pgs.py", "_rigid_motions"),
            ("pgs.py", "projected_gauss_seidel_lowrank"), ("dense.py", "parts"))


def profile_table(profile, frames):
    """The :data:`PROFILED` functions' calls per frame and cumulative ms per frame (cProfile's
    cumulative time: a function's callees included), largest first."""
    stats = pstats.Stats(profile, stream=io.StringIO()).stats
    rows = []
    for (path, _, name), (_, calls, _, cumulative, _) in stats.items():
        if (os.path.basename(path), name) in PROFILED and os.path.basename(os.path.dirname(path)) == "contact":
            rows.append((1e3 * cumulative / frames, calls / frames, f"{os.path.basename(path)}:{name}"))
    lines = ["| function | calls per frame | ms per frame (with callees) |", "|---|---|---|"]
    lines += [f"| {name} | {calls:.1f} | {ms:.2f} |" for ms, calls, name in sorted(rows, reverse=True)]
    return "\n".join(lines) + "\n"


def load_checkpoint(sim, path):
    """``sim.load_state(path)``; a checkpoint written before the Schur inverse saved the pattern of the
    last frame it factorised (``contact.schur_seen``) is loaded from a copy with that entry empty (the
    value of a run that has not factorised yet: its first frame then may decline a small complement
    that the uninterrupted run would have taken). A checkpoint of a run with other PGS sweeps (e.g. the
    plain ones, ``PGS(solver="gauss-seidel")``) resumes with its own sweeps."""
    import tempfile
    try:
        return sim.load_state(path)
    except ValueError as err:
        saved = re.search(r"contact_settings: file \"PGS\([^\"]*solver='([\w-]+)'", str(err))
        if saved is not None and sim.contact is not None and sim.contact.settings.solver != saved.group(1):
            sim.contact.settings = dataclasses.replace(sim.contact.settings, solver=saved.group(1))
            sim._settings["contact_settings"] = repr(sim.contact.settings)
            return load_checkpoint(sim, path)
        if "contact.schur_seen is missing" not in str(err):
            raise
    with np.load(path, allow_pickle=False) as data:
        arrays = {k: data[k] for k in data.files}
    arrays["contact.schur_seen"] = np.zeros(0, np.int64)
    with tempfile.TemporaryDirectory() as tmp:
        patched = os.path.join(tmp, os.path.basename(path))
        np.savez(patched, **arrays)
        return sim.load_state(patched)


def builders(mesh_dir, scene, end, cells, frame_schur=False):
    """full space, affinification, rigidification of the scene (at the paper's thresholds); with
    ``frame_schur`` (True or "full", or a reducer's name) two runs of that method, the second
    factorising with the contacts' unknowns last."""
    which = METHODS.index("full" if frame_schur is True else frame_schur) if frame_schur else 0
    if scene == "pile" or scene in LAB_SCENES:
        if scene == "pile":
            from budget import pile
        else:
            def pile(k, reducer=None):
                return sa.scenes.SCENES[scene](resolution=k, reducer=reducer, **LAB_SCENES[scene])
        if frame_schur:
            pair = [None, None] if which == 0 else [
                (sa.Affinification(tau_a=1e-4, tau_e=2e-4) if which == 1 else sa.Rigidification(tau_r=1e-4, tau_e=2e-4))
                for _ in range(2)]
            sims = [pile(cells, r) for r in pair]
        else:
            return [pile(cells), pile(cells, sa.Affinification(tau_a=1e-4, tau_e=2e-4)),
                    pile(cells, sa.Rigidification(tau_r=1e-4, tau_e=2e-4))]
    else:
        if mesh_dir is None:
            raise ValueError(f"--scene {scene} needs MESH_DIR (the paper's meshes)")
        row, _, factory, fraction = paper_table1.SCENES[scene]
        build = factory(mesh_dir, end)
        if not frame_schur:
            return [build(None)] + [build(r) for r in paper_table1.reducers(row, fraction)]
        sims = [build(None if which == 0 else paper_table1.reducers(row, fraction)[which - 1]) for _ in range(2)]
    sims[0].contact.schur.frame = False
    return sims


def run(mesh_dir, scene, start, end, cells=4, compare_rows=False, compare_columns=False, profile=None,
        frame_schur=False, blocks=False, resume=None, lookahead=None, spread=2.0, only=None, profile_out=None,
        plain_blocks=None):
    """The per-phase means of each method over the frames ``start`` to ``end - 1``; with ``profile``
    (a method), also that method's :func:`profile_table` over them (else None)."""
    sims = builders(mesh_dir, scene, end, cells, frame_schur or blocks or lookahead is not None)
    methods = METHODS
    if blocks:
        sims[0].contact.schur.frame = True
        sims[0].contact.schur.blocks = False
        methods, frame_schur = BLOCK_METHODS, False
    if lookahead is not None:
        sims[0].contact.schur.frame = True
        sims[1].contact.detector.lookahead = lookahead
        sims[1].contact.schur.spread = spread
        methods, frame_schur, blocks = LOOKAHEAD_METHODS, False, True
    if plain_blocks is not None:  # the method again, its frames of several bodies factorised plainly
        if blocks or frame_schur or lookahead is not None:
            raise ValueError("--plain-blocks goes with the three methods, not --blocks, --frame-schur or --lookahead")
        i = METHODS.index(plain_blocks)
        sims.append(builders(mesh_dir, scene, end, cells)[i])
        sims[-1].contact.schur.blocks = False
        methods = METHODS + (f"{plain_blocks}, plain blocks",)
    if only is not None:  # step only these of the three methods
        if blocks or frame_schur:
            raise ValueError("--methods goes with the three methods, not --blocks, --frame-schur or --lookahead")
        keep = [i for i, m in enumerate(methods) if m.split(",")[0] in only]
        sims, methods = [sims[i] for i in keep], tuple(methods[i] for i in keep)
    first = 0
    if resume is not None:
        per_method = not (blocks or frame_schur)
        if per_method and "{method}" not in resume:
            raise ValueError("--resume of the three methods names each method's checkpoint: give a path with "
                             "{method}, e.g. RUNS/pills/{method}-002800.npz")
        if not per_method and not (blocks or frame_schur is True or frame_schur == "full"):
            raise ValueError("--resume of --frame-schur takes a full-space checkpoint: use it with full space")
        for method, sim in zip(methods, sims):
            load_checkpoint(sim, resume.format(method=method.split(",")[0]) if per_method else resume)
        first = sims[0].state.frame
    if frame_schur:
        name = "full" if frame_schur is True else frame_schur
        methods = FRAME_METHODS if name == "full" else (f"{name}, own handle", f"{name}, frame's Schur")
    profiler = cProfile.Profile() if profile else None
    if compare_rows or compare_columns:
        for sim in sims:
            per_row(sim, columns=compare_columns)
    rows = {m: [] for m in methods}
    clocks = [contact_clock(sim) for sim in sims]
    t0 = time.perf_counter()
    for frame in range(first, end):
        turn = [(frame + i) % len(sims) for i in range(len(sims))]  # rotate who steps first
        for i in turn:
            timed = profiler is not None and frame >= start and methods[i] == profile
            if timed:
                profiler.enable()
            analyses = sims[i].contact.schur.analyses
            spent, cpu = clocks[i][0], time.process_time()
            sims[i].step()
            cpu, spent = time.process_time() - cpu, clocks[i][0] - spent
            if timed:
                profiler.disable()
            if frame >= start:
                rows[methods[i]].append(record(sims[i].stats[-1]))
                rows[methods[i]][-1].update(cpu=1e3 * cpu, contact_cpu=1e3 * spent)
                rows[methods[i]][-1]["analyses"] = float(sims[i].contact.schur.analyses - analyses)
        if frame % 10 == 0:
            print(f"{scene} frame {frame}/{end} ({time.perf_counter() - t0:.0f} s)", file=sys.stderr, flush=True)
    means = {m: {c: float(np.mean([r[c] for r in rs])) for c in COLUMNS + ROWS} for m, rs in rows.items()}
    if profiler is not None and profile_out:
        profiler.dump_stats(profile_out)
    return means, (profile_table(profiler, end - start) if profiler is not None else None)


def markdown(scene, means):
    methods = list(means)
    lines = [f"| {scene} | " + " | ".join(methods) + " |", "|---" * (len(methods) + 1) + "|"]
    for c in COLUMNS + (ROWS if any(means[m]["rows_columns"] for m in methods) else ()):
        lines.append(f"| {c} | " + " | ".join(f"{means[m][c]:.2f}" if c == "analyses" else f"{means[m][c]:.0f}"
                                                for m in methods) + " |")
    share = [means[m]["contact"] / max(means[m]["wall"], 1e-300) for m in methods]
    lines.append("| contact share of the frame | " + " | ".join(f"{100 * s:.0f} %" for s in share) + " |")
    share = [means[m]["contact_cpu"] / max(means[m]["cpu"], 1e-300) for m in methods]
    lines.append("| contact share of the CPU | " + " | ".join(f"{100 * s:.0f} %" for s in share) + " |")
    return "\n".join(lines) + "\n"


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("mesh_dir", nargs="?", default=None, help="the paper's meshes (not for --scene pile)")
    ap.add_argument("--scene", choices=["wheel", "octopus", "pills", "pile"] + list(LAB_SCENES), required=True)
    ap.add_argument("--cells", type=int, default=4,
                    help="cells per box edge of the pile; the resolution of stacked_beams and bowling")
    ap.add_argument("--rows", action="store_true", help="also time the Delassus operator built per row of J")
    ap.add_argument("--columns", action="store_true",
                    help="also time it built from solves of the touched unknowns' columns (no Schur complement)")
    ap.add_argument("--frame-schur", nargs="?", const="full", default=None, choices=METHODS,
                    help="compare two runs of a method (default full): the Schur complement on its own handle, "
                         "and the frame's own")
    ap.add_argument("--blocks", action="store_true",
                    help="compare two full-space runs: plain frames with each body's own complement, and frames "
                         "factorised body by body")
    ap.add_argument("--lookahead", type=float, default=None, metavar="K",
                    help="compare two full-space runs: the frame's complement on the touched unknowns, and on "
                         "those predicted K frames ahead")
    ap.add_argument("--spread", type=float, default=2.0,
                    help="with --lookahead: the largest predicted set, in multiples of the touched unknowns")
    ap.add_argument("--resume", default=None, metavar="CHECKPOINT",
                    help="start the two full-space runs of --blocks, --frame-schur or --lookahead from this "
                         "checkpoint; the three methods each from their own (a path with {method})")
    ap.add_argument("--methods", nargs="+", choices=METHODS, default=None,
                    help="step only these of the three methods")
    ap.add_argument("--plain-blocks", choices=METHODS[1:], default=None, metavar="METHOD",
                    help="also step METHOD with its frames of several bodies factorised plainly, each body's "
                         "Z from column solves (SchurInverse.blocks off)")
    ap.add_argument("--start", type=int, required=True)
    ap.add_argument("--end", type=int, required=True)
    ap.add_argument("--threads", default="1", help="BLAS/MKL threads (read before numpy is imported)")
    ap.add_argument("--json", default=None, help="also write the means here")
    ap.add_argument("--profile", choices=METHODS, default=None,
                    help="also profile this method's frames: its contact functions' ms per frame")
    ap.add_argument("--profile-out", default=None, metavar="FILE",
                    help="with --profile: also write the whole profile here (for pstats or snakeviz)")
    args = ap.parse_args(argv)
    means, profiled = run(args.mesh_dir, args.scene, args.start, args.end, args.cells, args.rows, args.columns,
                          args.profile, args.frame_schur, args.blocks, args.resume, args.lookahead, args.spread,
                          args.methods, args.profile_out, args.plain_blocks)
    print(f"frames {args.start}-{args.end - 1}, ms per frame (means)")
    print(markdown(args.scene, means))
    if profiled:
        print(f"{args.profile}, under cProfile (its overhead included):")
        print(profiled)
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"scene": args.scene, "start": args.start, "end": args.end, "means": means}, f, indent=1)
    return means, profiled


if __name__ == "__main__":
    main()
