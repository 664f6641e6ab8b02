"""Command line: ``skfem-affine`` / ``python -m skfem_affine`` (run ``--help`` on any subcommand).

Subcommands: ``demo``, ``run``, ``compare``, ``sweep``, ``budget``, ``scaling``, ``scenes``. A scene is a name
from :data:`skfem_affine.scenes.SCENES` or the path of a Python file defining ``scene(**kwargs)``
that returns a Simulation. With ``--json`` exactly one JSON object is printed on stdout (nothing
else); otherwise progress goes to stderr, a bar on a terminal and a line every 30 s in a log. Files
go into ``OUT/COMMAND/SCENE/`` (``OUT/demo/`` for the demo). A mistake in the command (a bad option
or number, an unknown scene, a scene file that raises or exits, a scheduler nobody answers at) is
one line on stderr and exit code 2, with no traceback; running out of memory is one line and exit
code 1; a traceback means a bug of the package.

Only the standard library is imported before the arguments are parsed (the simulation modules,
numba, SciPy and matplotlib are imported by the command that runs), so ``--help`` answers at once.
"""
import argparse
import ast
import inspect
import json
import math
import os
import socket
import sys
import time
import traceback

from skfem_affine.lab.methods import COMPARED, METHODS

SUMMARY_KEYS = ("scene", "method", "frames", "elements", "vertices", "wall_s", "speedup", "dof_ratio",
                "mean_clusters", "max_distance_error")


# ---------------------------------------------------------------- helpers
def _emit(args, summary):
    """The one JSON object (``--json``); otherwise nothing (human output is printed as we go)."""
    if args.json:
        from skfem_affine._json import jsonable  # numpy: not imported for --help
        print(json.dumps(jsonable(summary, finite=True)), flush=True)


def _say(args, *text):
    if not args.json:
        print(*text, flush=True)


def _progress(args):
    """Progress on stderr (a bar on a terminal, lines in a log), except with ``--json``."""
    return not args.json


def _parse_set(items):
    out = {}
    for item in items or ():
        key, sep, value = item.partition("=")
        if not sep or not key.isidentifier():
            raise ValueError(f"--set takes KEY=VALUE (a scene keyword), got {item!r}")
        try:
            out[key] = ast.literal_eval(value)
        except (ValueError, SyntaxError):
            out[key] = value
    return out


def _spec(args):
    from skfem_affine.lab import runners
    kwargs = _parse_set(getattr(args, "set", None))
    if getattr(args, "resolution", None) is not None:
        kwargs["resolution"] = args.resolution
    spec = runners.SceneSpec.make(args.scene, **kwargs)
    params = inspect.signature(spec.factory()).parameters
    open_kwargs = any(p.kind == p.VAR_KEYWORD for p in params.values())
    if "resolution" in kwargs and "resolution" not in params:
        raise ValueError(f"scene {args.scene!r} has no resolution parameter")
    unknown = [k for k in kwargs if k not in params and not open_kwargs]
    if unknown:
        raise ValueError(f"scene {args.scene!r} takes no parameter {', '.join(unknown)}")
    return spec


def _folder(args, spec):
    """``OUT/COMMAND/SCENE/`` (``OUT/demo/`` for the demo), created."""
    if args.command == "demo":
        out = os.path.join(args.out, "demo")
    else:
        out = os.path.join(args.out, args.command, spec.label)
    os.makedirs(out, exist_ok=True)
    return out


def _scene_text(spec):
    """``cantilever (resolution=4)``: the scene and its overrides, for headers."""
    def short(value):
        text = repr(value) if isinstance(value, str) else str(value)
        return text if len(text) <= 40 else text[:37] + "..."
    kwargs = ", ".join(f"{k}={short(v)}" for k, v in spec.kwargs)
    return f"{spec.label} ({kwargs})" if kwargs else spec.label


def _frames(frames, spec):
    """The frames to run: ``frames`` (``--frames``), else ``--set frames=``, else the scene's own default."""
    from skfem_affine.lab import runners
    if frames is not None:
        return frames
    kwargs = dict(spec.kwargs)
    if "frames" in kwargs:
        value = kwargs["frames"]
        if isinstance(value, bool) or not isinstance(value, int) or value < 1:
            raise ValueError(f"--set frames={value}: frames must be a whole number >= 1 (or use --frames N)")
        return value
    default = inspect.signature(spec.factory()).parameters.get("frames")
    if default is not None and isinstance(default.default, int) and not isinstance(default.default, bool):
        return default.default
    return runners.default_frames(spec.build())


def _method_text(method, tau_a=None, tau_e=None):
    """``affinification (tau_a=0.3, tau_e=0.6)``: a method and the thresholds (or error budget) it runs with."""
    if method.taus[0] is None:
        budget = getattr(method.reducer(), "target_error", None)
        return method.name if budget is None else f"{method.name} (error budget {budget:g}, thresholds chosen per frame)"
    a = tau_a if tau_a is not None else method.taus[0]
    e = tau_e if tau_e is not None else method.taus[1]
    return f"{method.name} (tau_a={a:g}, tau_e={e:g})"


def _check_scheduler(address, timeout=5.0):
    """Refuse, within ``timeout`` seconds, a tcp/tls ``--scheduler`` address where nothing listens."""
    scheme, sep, rest = address.partition("://")
    if not sep:
        scheme, rest = "tcp", address
    if scheme not in ("tcp", "tls"):
        return  # other transports (inproc, ucx, ...): dask itself connects
    host, _, port = rest.rpartition(":")
    host = host.strip("[]")
    if not host or not port.isdigit():
        raise ValueError(f"--scheduler takes tcp://HOST:PORT, got {address!r}")
    try:
        socket.create_connection((host, int(port)), timeout=timeout).close()
    except OSError as err:
        reason = err.strerror or type(err).__name__
        raise ValueError(f"--scheduler {address}: no dask scheduler answers there ({reason})") from None


def _fmt(value, spec=".2e"):
    """``format(value, spec)``, with "-" for a missing value, padded to the same width."""
    width = spec.split(".")[0]
    if value is None:
        return format("-", ">" + width)
    if isinstance(value, float) and not math.isfinite(value):
        return format("nan", ">" + width)
    return format(value, spec)


def _table(summaries):
    head = (f"{'method':>16} {'status':>8} {'wall s':>8} {'speedup':>8} {'DOF ratio':>9} {'bodies':>7} "
            f"{'resp err':>9} {'dist err':>9} {'dist m':>9} {'stress err':>10} {'step err':>9} {'residual':>9} "
            f"{'energy err':>10}")
    lines = [head, "-" * len(head)]
    for s in summaries:
        lines.append(f"{s['method']:>16} {s['status']:>8} {s['wall_s']:8.2f} {_fmt(s['speedup'], '8.2f')} "
                     f"{_fmt(s['dof_ratio'], '9.3f')} {s['mean_clusters']:7.1f} "
                     f"{_fmt(s.get('max_response_error'), '9.1e')} {_fmt(s['max_distance_error'], '9.1e')} "
                     f"{_fmt(s.get('max_distance_m'), '9.1e')} {_fmt(s.get('max_stress_error'), '10.1e')} "
                     f"{_fmt(s['max_step_error'], '9.1e')} {_fmt(s['max_residual'], '9.1e')} "
                     f"{_fmt(s['max_energy_error'], '10.1e')}")
    return "\n".join(lines)


def _legend(summaries):
    """What each column of :func:`_table` means, and which columns were not measured ("-")."""
    first = summaries[0] if summaries else {}
    lines = ["status: ok; diverged (the run stopped: see its message); over-budget (the error in the budget's unit "
             "above the budget)",
             "wall s: the run's wall time; speedup = full-space wall time / the method's (same frames, this machine)",
             "DOF ratio = DOFs solved / full-space DOFs, summed over frames; bodies = mean reduced bodies per frame",
             "errors, each the largest over frames of the vertex distance to the full-space run:",
             f"  resp err = over the response (the full-space run's largest displacement from rest, "
             f"{_fmt(first.get('response_m'), '.3g').strip()} m)",
             f"  dist err = over the scene size (bounding-box diagonal, {_fmt(first.get('size_m'), '.3g').strip()} m); "
             f"dist m = in metres",
             "  stress err = largest element |sigma - sigma_ref| / largest reference stress (Cauchy, Pa)",
             "  step err = dist err after one step from the full-space state (the reference re-started each frame)",
             "  residual = ||A dv - b|| / ||b|| of the full-space system",
             "  energy err = |strain energy difference| / largest strain energy of the full-space run"]
    skipped = [(name, flag) for key, name, flag in (("max_step_error", "step err", "--no-step-error"),
                                                    ("max_residual", "residual", "--no-residual"))
               if all(s.get(key) is None for s in summaries)]
    if skipped:
        lines.append(f"-: not measured ({'; '.join(f'{n}: {f}' for n, f in skipped)}; the demo skips both: each "
                     f"costs a full-space\n   solve or assembly per frame)")
    return "\n".join(lines)


def _hold_to_budget(run):
    """A run whose largest distance error is over its reducer's error budget gets ``status="over-budget"``."""
    s = run.summary
    from skfem_affine.lab import trade
    reducer = getattr(run.sim, "reducer", None)
    budget = getattr(reducer, "target_error", None)
    if budget is None:
        return
    unit = reducer.relative_to
    error = s.get(trade.SUMMARY_ERROR[unit])
    if error is not None and s.get("status") == "ok" and error > budget:
        s["status"] = "over-budget"
        s["message"] = f"largest distance error {error:.2e} ({unit} unit) over the error budget {budget:g}"


def _frames_table(runs):
    rows = []
    for name, run in runs.items():
        for r in run.records:
            rows.append({"method": name, **{k: v for k, v in r.items() if not isinstance(v, (list, dict))}})
    return rows


def _timing(args):
    return "sequential" if getattr(args, "sequential_timing", False) else "interleaved"


def _summary_json(summary, extra=None):
    out = {k: summary.get(k) for k in SUMMARY_KEYS}
    out.update(extra or {})
    return out


# ---------------------------------------------------------------- commands
def cmd_scenes(args):
    """List the built-in scenes, their parameters and defaults."""
    from skfem_affine.lab import scenes
    listing = {}
    for name, factory in scenes.SCENES.items():
        params = {p.name: (None if p.default is p.empty else repr(p.default))
                  for p in inspect.signature(factory).parameters.values() if p.kind != p.VAR_KEYWORD}
        doc = (inspect.getdoc(factory) or "").split("\n")[0]
        listing[name] = {"doc": doc, "parameters": params}
        _say(args, f"{name}: {doc}")
        _say(args, "    " + ", ".join(f"{k}={v}" if v is not None else k for k, v in params.items())
             + ", **overrides (material, dt, damping, solver, ...)")
    _emit(args, {"scenes": listing})
    return 0


def cmd_run(args):
    """One method on one scene, optionally against the full-space reference."""
    from skfem_affine.lab import io, plots, runners
    spec = _spec(args)
    if args.method is None:  # the error budget, unless thresholds are given
        args.method = "affinification" if (args.tau_a, args.tau_e) != (None, None) else RUN_METHOD
    method = runners.get_method(args.method)
    frames = _frames(args.frames, spec)
    out = _folder(args, spec)
    progress = _progress(args)
    reference = None
    with_reference = args.reference and method.name != "full"
    _say(args, f"run: {_scene_text(spec)}, {frames} frames: {_method_text(method, args.tau_a, args.tau_e)}"
               + (", against the full-space reference" if with_reference else ""))
    series = None
    every = max(1, args.every)

    def write(sim, state, last=False):
        nonlocal series
        if args.no_paraview or (state.frame % every and not last):
            return
        if series is None:
            series = io.Series(os.path.join(out, "paraview", method.name), sim)
        series.write(state)

    measure = dict(step_error=not args.no_step_error, residual=not args.no_residual, keep_every=every,
                   keep_frames=[args.frame] if args.frame is not None else (), progress=progress)
    if with_reference:
        timing = _timing(args)
        _say(args, f"reference: full space, {spec.label}; timing: {runners.TIMING[timing]}")
        reference, runs = runners.compare(spec, frames, ("full", method), {method.name: (args.tau_a, args.tau_e)},
                                          timing=timing, on_state={method.name: write}, **measure)
        result = runs[method.name]
    else:
        result = runners.run(spec, method, frames, args.tau_a, args.tau_e, on_state=write, **measure)
    _hold_to_budget(result)
    s = result.summary
    if result.records and (len(result.records) % every):
        write(result.sim, result.sim.state, last=True)
    runners.write_table(result.records, os.path.join(out, f"{method.name}_frames.csv"))
    picture = plots.clusters_picture([(method.name, result.sim, plots.pick_state(result.states, args.frame))],
                                     os.path.join(out, f"{method.name}_clusters.png"))
    gif = plots.animation(method.name, result.sim, result.states, os.path.join(out, f"{method.name}.gif")) \
        if args.gif else None
    _say(args, f"{spec.label}, {method.name}: {s['elements']} tets, {s['vertices']} vertices, {s['frames']} frames "
               f"in {s['wall_s']:.2f} s ({s['frames'] / max(s['wall_s'], 1e-300):.1f} frames/s), status {s['status']}")
    if reference is not None:
        _say(args, _table([s]))
        _say(args, _legend([s]))
        _say(args, f"timing: {runners.TIMING[s['timing']]}")
    elif method.name != "full":
        _say(args, "errors: not measured (--reference runs the full-space reference beside it)")
    _say(args, f"wrote {out}/: {method.name}_frames.csv, {os.path.basename(picture)}"
               + (f", {os.path.basename(gif)}" if gif else "")
               + (f", {os.path.relpath(series.pvd, out)} (ParaView)" if series else ""))
    _emit(args, _summary_json(s, {"status": s["status"], "timing": s["timing"] if reference is not None else None,
                                  "out": out}))
    return 0 if s["status"] == "ok" else 1


def compare_outputs(args, spec, runs, out):
    """Tables, plots, the clusters picture, ParaView series (and GIFs) of a compare run."""
    from skfem_affine.lab import io, plots, runners, trade
    summaries = [r.summary for r in runs.values()]
    runners.write_table(_frames_table(runs), os.path.join(out, "frames.csv"))
    runners.write_table(summaries, os.path.join(out, "summary.csv"))
    written = ["frames.csv", "summary.csv"]
    written += [os.path.basename(p) for p in plots.compare_plots(runs, out, frame=args.frame, stem="compare")]
    budgeted = [r.sim.reducer for r in runs.values() if getattr(r.sim.reducer, "target_error", None) is not None]
    units = {red.relative_to for red in budgeted}
    unit = units.pop() if len(units) == 1 else "size"  # the budgets' unit (one unit per picture)
    points = trade.points_from_runs(runs, unit)
    budgets = sorted({red.target_error for red in budgeted if red.relative_to == unit})
    if points:
        written.append(os.path.basename(plots.trade_plot(points, os.path.join(out, "trade.png"), budgets=budgets,
                                                         title=f"{spec.label}: speed against accuracy", unit=unit)))
    if not args.no_paraview:
        for name, run in runs.items():
            io.write_series(os.path.join(out, "paraview", name), run.sim, states=run.states)
        written.append("paraview/<method>.pvd")
    if args.gif:
        for name, run in runs.items():
            if args.gif is not True and name != args.gif:
                continue
            written.append(os.path.basename(plots.animation(name, run.sim, run.states,
                                                            os.path.join(out, f"{name}.gif"))))
    return written


def _compare_taus(args):
    from skfem_affine.lab import runners
    taus = {}
    for item in args.taus or ():
        name, sep, values = item.partition("=")
        try:
            a, e = (float(v) for v in values.split(","))
        except ValueError:
            raise ValueError(f"--taus takes METHOD=TAU_A,TAU_E, got {item!r}") from None
        if not all(math.isfinite(v) and v >= 0 for v in (a, e)):
            raise ValueError(f"--taus thresholds must be finite and >= 0, got {item!r}")
        taus[runners.get_method(name).name] = (a, e)
    main = args.methods[1] if len(args.methods) > 1 else args.methods[0]
    if args.tau_a is not None or args.tau_e is not None:
        defaults = runners.get_method(main).taus
        taus[main] = (args.tau_a if args.tau_a is not None else defaults[0],
                      args.tau_e if args.tau_e is not None else defaults[1])
    return taus


def cmd_compare(args):
    """Full space, affinification and rigidification on one scene: table, plots, picture, ParaView."""
    from skfem_affine.lab import runners
    spec = _spec(args)
    methods = tuple(dict.fromkeys(["full"] + [runners.get_method(m).name for m in args.methods]))
    args.methods = list(methods)
    taus = _compare_taus(args)
    frames = _frames(args.frames, spec)
    out = _folder(args, spec)
    t0 = time.perf_counter()
    shown = [_method_text(runners.get_method(m), *taus.get(m, (None, None))) for m in methods]
    _say(args, f"{args.command}: {_scene_text(spec)}, {frames} frames: {', '.join(shown)} "
               f"(the full-space run is the reference)")
    _, runs = runners.compare(spec, frames, methods, taus, step_error=not args.no_step_error,
                              residual=not args.no_residual, keep_every=max(1, args.every),
                              keep_frames=[args.frame] if args.frame is not None else (), progress=_progress(args),
                              timing=_timing(args))
    for run in runs.values():
        _hold_to_budget(run)
    written = compare_outputs(args, spec, runs, out)
    summaries = [r.summary for r in runs.values()]
    first = runs["full"].summary
    _say(args, f"{first['elements']} tets, {first['vertices']} vertices, {first['frames']} frames, "
               f"dt = {runs['full'].sim.dt} s")
    _say(args, _table(summaries))
    _say(args, f"timing: {runners.TIMING[first['timing']]}")
    _say(args, _legend(summaries))
    _say(args, f"wrote {out}/: {', '.join(written)}  ({time.perf_counter() - t0:.1f} s in all)")
    main = runs[methods[1]] if len(methods) > 1 else runs["full"]
    _emit(args, _summary_json(main.summary, {"timing": first["timing"], "out": out,
                                             "methods": {n: r.summary for n, r in runs.items()}}))
    return 0 if all(s["status"] == "ok" for s in summaries) else 1


def cmd_sweep(args):
    """A tau_a x tau_e grid on Dask (embedded LocalCluster or --scheduler), heatmaps of every metric."""
    from skfem_affine.lab import plots, runners, trade
    spec = _spec(args)
    method = runners.get_method(args.method)
    lo, hi = args.tau_range
    if lo > hi:
        raise ValueError(f"--tau-range takes LO HI with LO <= HI, got {lo:g} {hi:g}")
    if args.scheduler:
        _check_scheduler(args.scheduler)
    else:
        from skfem_affine.lab.sweep import local_workers
        try:
            local_workers(args.workers)
        except ValueError as err:
            raise ValueError(str(err).replace(f"workers={args.workers}", f"--workers {args.workers}")) from None
    # here, so that a scene that cannot be built, or does not run the method's reducer, is one line, not a
    # failure of every cell inside the cluster
    spec.build(reducer=method.reducer())
    frames = _frames(args.frames, spec)
    out = _folder(args, spec)
    table = args.table or os.path.join(out, f"{method.name}.{args.format}")
    t0 = time.perf_counter()
    _say(args, f"sweep: {_scene_text(spec)}, {frames} frames: {method.name} on a {args.grid} x {args.grid} grid, "
               f"tau in [{lo:g}, {hi:g}] 1/s, on {args.scheduler or 'an embedded LocalCluster'}; table {table}")
    rows = runners.sweep(spec, frames, method, args.grid, (lo, hi), table, scheduler=args.scheduler,
                         workers=args.workers, processes=not args.threads, step_error=not args.no_step_error,
                         residual=not args.no_residual, retry_failed=args.retry_failed, progress=_progress(args),
                         paired_timing=args.paired_timing, cell_timeout=args.cell_timeout)
    heatmaps = plots.sweep_heatmaps(rows, os.path.join(out, f"{method.name}_heatmaps.png"),
                                    title=f"{spec.label}: {method.name} sweep ({len(rows)} cells)")
    points = trade.points_from_rows(rows)
    trade_png = plots.trade_plot(points, os.path.join(out, "trade.png"),
                                 title=f"{spec.label}: {method.name}, one point per (tau_a, tau_e)") if points else None
    ok = [r for r in rows if r.get("status") == "ok"]
    best = max(ok, key=lambda r: r.get("speedup") or 0.0) if ok else {}
    if not args.json:
        print(f"{'tau_a':>9} {'tau_e':>9} {'status':>8} {'speedup':>8} {'DOF ratio':>9} {'bodies':>7} {'dist err':>9}")
        for r in rows:
            print(f"{r['tau_a']:9.3g} {r['tau_e']:9.3g} {r['status']:>8} {_fmt(r.get('speedup'), '8.2f')} "
                  f"{_fmt(r.get('dof_ratio'), '9.3f')} {_fmt(r.get('mean_clusters'), '7.1f')} "
                  f"{_fmt(r.get('max_distance_error'), '9.1e')}")
        for r in rows:
            if r.get("status") in ("crashed", "timeout", "error"):
                print(f"cell tau_a={r['tau_a']:.3g} tau_e={r['tau_e']:.3g} {r['status']}: {r.get('message')}")
        failed = len(rows) - len(ok)
        print("speedup = the reference's wall time / the cell's (timed alone, or against a full-space twin with "
              "--paired-timing);\nDOF ratio = DOFs solved / full-space DOFs; bodies = mean reduced bodies per frame; "
              "dist err = largest vertex\ndistance to the reference / scene size (bounding-box diagonal)")
        print(f"{len(rows)} cells, {failed} failed; wrote {table}, {heatmaps}"
              + (f" and {trade_png}" if trade_png else "") + f" ({time.perf_counter() - t0:.1f} s)")
    summary = {"scene": spec.label, "method": method.name, "frames": best.get("frames"),
               "elements": best.get("elements"), "vertices": best.get("vertices"),
               "wall_s": time.perf_counter() - t0, "speedup": best.get("speedup"), "dof_ratio": best.get("dof_ratio"),
               "mean_clusters": best.get("mean_clusters"), "max_distance_error": best.get("max_distance_error"),
               "best_tau_a": best.get("tau_a"), "best_tau_e": best.get("tau_e"), "cells": len(rows),
               "failed": len(rows) - len(ok), "table": table, "heatmaps": heatmaps, "trade": trade_png, "rows": rows}
    _emit(args, summary)
    return 0


def cmd_scaling(args):
    """The scene at increasing size: full and reduced time, speedup, error, the paper's speedup beside (Table 2)."""
    from skfem_affine.lab import io, plots, runners
    if args.scene is None:
        args.scene = "paper_beam" if args.meshes else "cantilever"
    if args.material is not None:
        args.set = list(args.set) + [f"material={args.material}"]
    spec = _spec(args)
    method = runners.get_method(args.method)
    params = inspect.signature(spec.factory()).parameters
    open_kwargs = any(p.kind == p.VAR_KEYWORD for p in params.values())
    key = "mesh" if args.meshes else "resolution"
    if key not in params and (not open_kwargs or (args.meshes and not spec.is_file)):
        raise ValueError(f"scene {args.scene!r} has no {key} parameter to scale"
                         + (" (--meshes needs a scene taking mesh=, e.g. paper_beam)" if args.meshes else ""))
    sizes = args.meshes or args.resolutions
    for m in args.meshes or ():
        if not os.path.isfile(m):
            raise ValueError(f"--meshes: {m!r} is not a file (give the path of a mesh file, e.g. "
                             f"path/to/beam1264.mesh)")
        io.load_mesh(m)  # a file that is no tetrahedral mesh is refused before any run
    if args.frames and len(args.frames) not in (1, len(sizes)):
        raise ValueError(f"--frames takes one number or one per {'mesh' if args.meshes else 'resolution'} "
                         f"({len(sizes)}), got {len(args.frames)}")
    taus = _tau_pairs(args)
    out = _folder(args, spec)
    frames = args.frames if args.frames else [_frames(None, spec)]
    frames = frames[0] if len(frames) == 1 else frames
    names = [os.path.basename(m) for m in args.meshes] if args.meshes else [str(k) for k in args.resolutions]
    if taus is None or len(taus) == 1:
        what = _method_text(method, *(taus[0] if taus else (None, None)))
    else:
        what = f"{method.name} at tau_a / tau_e " + ", ".join(f"{a:g} / {e:g}" for a, e in taus)
    _say(args, f"scaling: {_scene_text(spec)}, {'meshes' if args.meshes else 'resolutions'} {', '.join(names)}, "
               f"{frames if isinstance(frames, int) else ', '.join(map(str, frames))} frames: "
               f"{what} against full space"
               + ("" if args.target_error is None else
                  f"; at each size the fastest pair within {args.target_error:g} of the longest side (*)"))
    rows = runners.scaling(spec, None if args.meshes else args.resolutions, frames, method,
                           progress=_progress(args), meshes=args.meshes or None, taus=taus,
                           target_error=args.target_error)
    table = runners.write_table(rows, os.path.join(out, f"{method.name}.csv"))
    best = _best_per_size(rows)
    figure = plots.scaling_plot(best, os.path.join(out, f"{method.name}_scaling.png"),
                                title=f"{spec.label}: {method.name} against full space")
    if not args.json:
        print(f"{'size':>10} {'elements':>9} {'vertices':>9} {'frames':>6} {'tau_a':>6} {'tau_e':>6} {'full s':>8} "
              f"{'reduced s':>9} {'speedup':>8} {'paper':>6} {'dist err':>9} {'err/len':>8} {'DOF ratio':>9}")
        for r in rows:
            size = os.path.splitext(r["mesh"])[0] if r["mesh"] is not None else str(r["resolution"])
            print(f"{size[-10:]:>10} {r['elements']:9d} {r['vertices']:9d} {r['frames']:6d} "
                  f"{_fmt(r['tau_a'], '6.3g')} {_fmt(r['tau_e'], '6.3g')} {r['time_full_s']:8.2f} "
                  f"{r['time_reduced_s']:9.2f} {_fmt(r['speedup'], '8.2f')} {_fmt(r['paper'], '6.2f')} "
                  f"{_fmt(r['max_distance_error'], '9.1e')} {_fmt(r['length_error'], '8.1e')} "
                  f"{_fmt(r['dof_ratio'], '9.3f')}" + (" *" if r["chosen"] else ""))
            if args.phases:
                print(" " * 11 + "ms per frame, full: " + _phase_text(r, "full_")
                      + "\n" + " " * 11 + f"ms per frame, {r['method']}: " + _phase_text(r, ""))
        if args.target_error is not None:
            missed = sorted({r["elements"] for r in rows} - {r["elements"] for r in rows if r["chosen"]})
            if missed:
                print(f"no pair within {args.target_error:g} of the longest side at {', '.join(map(str, missed))} "
                      f"elements")
        print("full s, reduced s: wall time of the full-space and the reduced run; speedup = full s / reduced s; "
              "DOF ratio = DOFs solved\n/ full-space DOFs; paper: the paper's speedup at that size (Table 1 'Beam' by "
              "material at 5516 tets, else Table 2);\ndist err: max vertex distance to the full solve / bounding-box "
              "diagonal; err/len: / longest side; -: not measured or not known")
        print(f"timing: {runners.TIMING[rows[-1]['timing']]}")
        print(f"wrote {table} and {figure}")
    last = best[-1] if best else rows[-1]
    summary = {"scene": spec.label, "method": method.name, "frames": last["frames"], "elements": last["elements"],
               "vertices": last["vertices"], "wall_s": last["time_reduced_s"], "speedup": last["speedup"],
               "dof_ratio": last["dof_ratio"], "mean_clusters": last["mean_clusters"],
               "max_distance_error": last["max_distance_error"], "rows": rows, "table": table, "figure": figure}
    _emit(args, summary)
    return 0


def _phase_text(row, prefix):
    """``wall 12.3 = assembly 3.7 + ... + solve 0.5`` from a scaling row's ``{prefix}{phase}_ms`` entries."""
    from skfem_affine.lab import runners
    parts = [f"{p} {row[f'{prefix}{p}_ms']:.1f}" for p in runners.PHASES if row.get(f"{prefix}{p}_ms", 0.0) >= 0.05]
    return f"wall {row[f'{prefix}wall_ms']:.1f} = " + " + ".join(parts) + " + rest"


def _tau_pairs(args):
    """``--tau-a``/``--tau-e`` as (tau_a, tau_e) pairs (tau_e = 2 tau_a where --tau-e is not given), or None."""
    if args.tau_a is None:
        if args.tau_e is not None:
            raise ValueError("--tau-e needs --tau-a")
        return None
    tau_e = args.tau_e if args.tau_e is not None else [2.0 * a for a in args.tau_a]
    if len(tau_e) != len(args.tau_a):
        raise ValueError(f"--tau-e takes one value per --tau-a ({len(args.tau_a)}), got {len(tau_e)}")
    return list(zip(args.tau_a, tau_e))


def _best_per_size(rows):
    """Per size, the chosen row, else (no target, or none met it) the fastest."""
    out = {}
    for r in rows:
        k = (r["mesh"], r["resolution"])
        cur = out.get(k)
        if cur is None or (r["chosen"], r["speedup"] or 0.0) > (cur["chosen"], cur["speedup"] or 0.0):
            out[k] = r
    return list(out.values())


def cmd_budget(args):
    """The error-budget reducer at several budgets, interleaved with full space: achieved error, speedup, trade.png."""
    from skfem_affine.lab import plots, runners, trade
    spec = _spec(args)
    frames = _frames(args.frames, spec)
    out = _folder(args, spec)
    t0 = time.perf_counter()
    _say(args, f"budget: {_scene_text(spec)}, {frames} frames: {args.method} with target_error in "
               f"{', '.join(f'{e:g}' for e in args.errors)}, each stepped interleaved with the full-space run "
               f"(the reference)")
    options = {} if args.never_slower is None else {"never_slower": args.never_slower == "on"}
    rows = trade.budget_runs(spec, args.errors, frames, method=args.method, progress=_progress(args), **options)
    table = runners.write_table(rows, os.path.join(out, "budget.csv"))
    picture = plots.trade_plot(trade.budget_points(rows), os.path.join(out, "trade.png"), budgets=args.errors,
                               title=f"{spec.label}: {args.method} at error budgets (achieved beside each budget)",
                               unit=rows[0]["relative_to"] if rows else "size")
    if not args.json:
        print(f"{'budget':>8} {'achieved':>9} {'estimated':>9} {'resp err':>9} {'dist err':>9} {'speedup':>8} "
              f"{'DOF ratio':>9} {'reduced':>8} {'mean tau':>9} {'status':>8}")
        for r in rows:
            print(f"{r['budget']:8.3g} {r['error']:9.2e} {r['max_estimated_error']:9.2e} "
                  f"{_fmt(r['error_response'], '9.2e')} {r['error_size']:9.2e} {_fmt(r['speedup'], '8.2f')} "
                  f"{_fmt(r['dof_ratio'], '9.3f')} {100 * r['reduced_frames']:7.0f}% {_fmt(r['mean_tau_a'], '9.3g')} "
                  f"{r['status']:>8}")
        first = rows[0] if rows else {}
        print(f"timing: {runners.TIMING['interleaved']}; achieved and estimated = max vertex distance to the "
              f"full-space run\nin the budget's unit ({first.get('relative_to')}); resp err = the same over the "
              f"full-space run's response\n(largest displacement from rest, {_fmt(first.get('response_m'), '.3g').strip()}"
              f" m), dist err = over the scene size ({first.get('size_m', 0.0):.3g} m);"
              f"\nreduced = frames that returned the reduced solution (the others: shadow, impact or fall-back "
              f"frames in full space);\nstatus: ok, diverged, or over-budget (achieved above the budget)")
        print(f"wrote {table} and {picture} ({time.perf_counter() - t0:.1f} s)")
    _emit(args, {"scene": spec.label, "method": args.method, "rows": rows, "table": table, "trade": picture})
    return 0 if all(r["status"] == "ok" for r in rows) else 1


#: The reducers ``budget`` runs (those of :data:`skfem_affine.lab.trade.REDUCERS`; listed here so that
#: ``--help`` imports no reducer).
BUDGET_METHODS = ("affinification", "rigidification")

#: The method ``run`` runs without --method or thresholds: affinification at its default error budget.
RUN_METHOD = "affinification-budget"

#: The demo's scene size: where affinification pays on two cores (docs/affinification.md, docs/budget.md).
DEMO_RESOLUTION = 10


def cmd_demo(args):
    """The product in one command: a 24k-tet cantilever in full space and with affinification at its
    default 1 % error budget, interleaved: the measured speedup and error, plots, a picture."""
    args.scene, args.set, args.methods, args.taus = "cantilever", [], ["full", "affinification-budget"], []
    args.tau_a = args.tau_e = None
    args.no_step_error, args.no_residual = True, True  # each costs a full-space solve or assembly per frame
    args.no_paraview, args.gif = True, False
    _say(args, f"demo: a cantilever beam ({24 * args.resolution ** 3} tets) pinned at x = 0 swings down under "
               "gravity, simulated in full space and\nwith affinification (elements with alike deformation rates "
               "merge into 12-DOF affine bodies) at its default\nerror budget, 1 % of the beam's response; the "
               "full-space run is the reference for speed and error, both stepped\nframe by frame in turn. "
               "(`skfem-affine compare --help`: any scene and method; `skfem-affine budget`: several budgets.)")
    code = cmd_compare(args)
    _say(args, "The default budget, 1 % of the response, is strict: on this beam it keeps almost every DOF elastic\n"
               "and runs about as fast as full space; on this beam a looser one buys little, since its errors keep\n"
               "drifting with the swing. `skfem-affine budget cantilever --resolution 10 --errors 0.01 0.05 0.1` measures the trade. Below a\n"
               "few thousand tets the full solve is about as fast as the reduced one, and the default reducer then\n"
               "solves in full space by itself (docs/budget.md).")
    return code


# ---------------------------------------------------------------- parser
class _Parser(argparse.ArgumentParser):
    """argparse with one-line errors (exit code 2) and no abbreviated options (one spelling each)."""

    def __init__(self, *args, **kwargs):
        kwargs.setdefault("allow_abbrev", False)
        super().__init__(*args, **kwargs)

    def error(self, message):
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def _whole(lowest):
    """An argparse type: a whole number >= ``lowest``."""
    def parse(text):
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"must be a whole number, got {text!r}") from None
        if value < lowest:
            raise argparse.ArgumentTypeError(f"must be >= {lowest}, got {value}")
        return value
    parse.__name__ = f"whole number >= {lowest}"
    return parse


def _real(lowest=0.0, strict=False):
    """An argparse type: a finite number >= ``lowest`` (> with ``strict``)."""
    def parse(text):
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"must be a number, got {text!r}") from None
        if not math.isfinite(value) or value < lowest or (strict and value == lowest):
            raise argparse.ArgumentTypeError(f"must be a finite number {'>' if strict else '>='} {lowest:g}, "
                                             f"got {text}")
        return value
    parse.__name__ = "number"
    return parse


class _Refuse(argparse.Action):
    """An option that exists only to say which option to use instead."""

    def __init__(self, option_strings, dest, instead, **kwargs):
        self.instead = instead
        super().__init__(option_strings, argparse.SUPPRESS, nargs="*", help=argparse.SUPPRESS)

    def __call__(self, parser, namespace, values, option_string=None):
        parser.error(f"{option_string} is not an option here; use {self.instead}")


def _common(p, frames_help="frames to simulate (default: the scene's own)", frames=True, resolution=True):
    p.add_argument("scene", nargs="?", default="cantilever",
                   help="a scene name (see `skfem-affine scenes`) or a .py file defining scene(**kwargs) "
                        "that returns a Simulation and accepts reducer=; default cantilever")
    if resolution:
        p.add_argument("--resolution", type=_whole(1), default=None, help="the scene's resolution parameter "
                       "(cantilever: k cells across, 24 k^3 tets)")
    if frames:
        p.add_argument("--frames", type=_whole(1), default=None, help=frames_help)
    p.add_argument("--set", action="append", metavar="KEY=VALUE", default=[],
                   help="a scene keyword override, e.g. --set dt=0.005 --set solver=superlu "
                        "(repeatable; values are Python literals, else strings)")
    p.add_argument("--out", default="out", help="output folder (default ./out); each command writes into "
                   "OUT/COMMAND/SCENE/")
    p.add_argument("--json", action="store_true", help="print exactly one JSON summary object on stdout, nothing else")


def _taus(p, what="the method's"):
    p.add_argument("--tau-a", type=_real(), default=None, help=f"threshold to become reduced, 1/s ({what} default)")
    p.add_argument("--tau-e", type=_real(), default=None, help=f"threshold to stay reduced, 1/s ({what} default)")


def _measure(p):
    p.add_argument("--no-step-error", action="store_true",
                   help="skip the step distance error (a full-space step per frame; halves the cost)")
    p.add_argument("--no-residual", action="store_true", help="skip the full-space residual (an assembly per frame)")


def _sequential(p):
    p.add_argument("--sequential-timing", action="store_true",
                   help="time each method alone, one after the other (default: all methods interleaved frame "
                        "by frame in one process, so that machine load hits all alike)")


def _pictures(p, every=10):
    p.add_argument("--every", type=_whole(1), default=every, help=f"keep/write every N-th frame (default {every})")
    p.add_argument("--frame", type=_whole(0), default=None,
                   help="frame of the clusters picture (default: where the most elements are reduced)")
    p.add_argument("--gif", action="store_true", help="also write an animated GIF per method")
    p.add_argument("--no-paraview", action="store_true", help="skip the ParaView (.pvd + .vtu) output")


def parser():
    methods = ", ".join(f"{m.name} (default taus {m.taus[0]}, {m.taus[1]})" if m.taus[0] is not None else m.name
                        for m in METHODS.values())
    top = _Parser(prog="skfem-affine", description="Fast adaptive elastodynamics for scikit-fem: "
                  "simulate scenes and measure the speed/accuracy trade of affinification.",
                  epilog="Run `skfem-affine COMMAND --help` for each command's options.")
    sub = top.add_subparsers(dest="command", metavar="COMMAND")

    p = sub.add_parser("demo", help="a 24k-tet cantilever in full space and with affinification at its error "
                                    "budget: speedup, error, plots, trade.png, a picture of the clusters",
                       description=cmd_demo.__doc__)
    p.add_argument("--resolution", type=_whole(1), default=DEMO_RESOLUTION,
                   help=f"cells across the beam, 24 k^3 tets (default {DEMO_RESOLUTION}: 24000 tets)")
    p.add_argument("--frames", type=_whole(1), default=60, help="frames (default 60, 0.6 s of simulated time)")
    p.add_argument("--out", default="out", help="output folder (default ./out); the demo writes into OUT/demo/")
    p.add_argument("--json", action="store_true", help="print exactly one JSON summary object on stdout")
    p.add_argument("--every", type=_whole(1), default=5, help="keep/write every N-th frame (default 5)")
    p.add_argument("--frame", type=_whole(0), default=None, help="frame of the clusters picture")
    p.set_defaults(func=cmd_demo)

    p = sub.add_parser("run", help="one method on one scene (default: affinification at its error budget)",
                       description=cmd_run.__doc__ + f" Methods: {methods}.")
    _common(p)
    p.add_argument("--method", default=None, help=f"one of: {', '.join(METHODS)} (default: {RUN_METHOD}, affinification "
                   "with thresholds chosen per frame to hold its default error budget, 1 %% of the scene size; "
                   "with --tau-a / --tau-e: affinification at those thresholds)")
    _taus(p)
    p.add_argument("--reference", action="store_true",
                   help="also run the full-space reference, for speedup and errors")
    _sequential(p)
    _measure(p)
    _pictures(p)
    p.set_defaults(func=cmd_run)

    p = sub.add_parser("compare", help="full vs affinification vs rigidification: table, plots, picture, ParaView",
                       description=cmd_compare.__doc__ + f" Methods: {methods}.")
    _common(p)
    p.add_argument("--methods", nargs="+", default=list(COMPARED[1:]),
                   help="methods besides full space (default: affinification rigidification)")
    _taus(p, "for the first method; affinification's")
    p.add_argument("--taus", action="append", metavar="METHOD=A,E", default=[],
                   help="thresholds of any method, e.g. --taus rigidification=0.01,0.02 (repeatable)")
    _sequential(p)
    _measure(p)
    _pictures(p)
    p.set_defaults(func=cmd_compare)

    p = sub.add_parser("sweep", help="tau_a x tau_e grid on Dask, heatmaps of every metric (paper Fig. 6)",
                       description=cmd_sweep.__doc__ + " Finished cells in the table are not recomputed.")
    _common(p)
    p.add_argument("--method", default="affinification", help=f"one of: {', '.join(METHODS)}")
    p.add_argument("--grid", type=_whole(1), default=9, help="N for an N x N grid (default 9; the paper uses 41)")
    p.add_argument("--tau-range", type=_real(0.0, strict=True), nargs=2, default=(1e-3, 1.0), metavar=("LO", "HI"),
                   help="log-spaced thresholds from LO to HI, 1/s (default 1e-3 1)")
    p.add_argument("--scheduler", default=None, help="address of a running dask scheduler, e.g. tcp://host:8786 "
                   "(default: an embedded LocalCluster)")
    p.add_argument("--workers", type=_whole(1), default=None,
                   help="LocalCluster worker processes, at most the CPU count (default: the CPU count)")
    p.add_argument("--threads", action="store_true", help="LocalCluster workers as threads of this process")
    p.add_argument("--table", default=None, help="results table (.csv or .parquet; default OUT/sweep/SCENE/METHOD.csv)")
    p.add_argument("--format", choices=("csv", "parquet"), default="csv", help="default table format (csv)")
    p.add_argument("--retry-failed", action="store_true", help="recompute cells recorded as failed")
    p.add_argument("--paired-timing", action="store_true",
                   help="time a full-space twin in lockstep in every cell (speedups robust to shared, busy cores; "
                        "one more full run per cell)")
    p.add_argument("--cell-timeout", type=float, default=None, metavar="SECONDS",
                   help="a cell still running after this is killed and recorded as timed out (default: 10 x the "
                        "reference's wall time, at least 300 s)")
    _measure(p)
    p.set_defaults(func=cmd_sweep)

    p = sub.add_parser("budget", help="the error-budget reducer at several budgets against full space: "
                                      "achieved error, speedup, trade.png", description=cmd_budget.__doc__)
    _common(p)
    p.add_argument("--errors", type=_real(0.0, strict=True), nargs="+", default=[0.001, 0.01, 0.05],
                   help="error budgets (max vertex distance to the full-space run / the response, its largest "
                        "displacement from rest), default 0.001 0.01 0.05")
    p.add_argument("--method", choices=BUDGET_METHODS, default="affinification")
    p.add_argument("--never-slower", choices=("on", "off"), default=None,
                   help="the fall-back to full space when reduction does not pay (default: on)")
    p.set_defaults(func=cmd_budget)

    p = sub.add_parser("scaling", help="speedup and error against size, the paper's beside (paper Table 2)",
                       description=cmd_scaling.__doc__)
    _common(p, frames=False, resolution=False)
    p.set_defaults(scene=None)
    p.add_argument("--resolutions", type=_whole(1), nargs="+", default=[4, 6, 8, 10],
                   help="values of the scene's resolution parameter (default 4 6 8 10)")
    p.add_argument("--resolution", action=_Refuse, instead="--resolutions R [R ...] (one or more values)")
    p.add_argument("--meshes", nargs="+", default=None, metavar="PATH",
                   help="mesh files, one size each, instead of --resolutions (e.g. the paper's beam*.mesh; the "
                        "scene defaults to paper_beam: E 1e5, nu 0.35, density 100, Rayleigh 0.03 / 0.02, h 0.01, "
                        "z-min end pinned, gravity along -y)")
    p.add_argument("--material", default=None, choices=["neohookean", "stvk", "corotational"],
                   help="the scene's material (paper_beam, cantilever), built with its E and nu")
    p.add_argument("--frames", type=_whole(1), nargs="+", default=None,
                   help="frames: one number, or one per size (default: the scene's own)")
    p.add_argument("--method", default="affinification", help=f"one of: {', '.join(METHODS)}")
    p.add_argument("--tau-a", type=_real(), nargs="+", default=None,
                   help="threshold(s) to become reduced, 1/s; several run in one process (default: the method's)")
    p.add_argument("--tau-e", type=_real(), nargs="+", default=None,
                   help="threshold(s) to stay reduced, one per --tau-a (default: 2 tau_a)")
    p.add_argument("--phases", action="store_true", help="also print the mean ms per frame of each phase, full "
                   "solve and method, of every row")
    p.add_argument("--target-error", type=_real(0.0, strict=True), default=None,
                   help="mark at each size the fastest pair whose max vertex distance to the full solve is at most "
                        "this fraction of the scene's longest side (e.g. 0.01)")
    p.set_defaults(func=cmd_scaling)

    p = sub.add_parser("scenes", help="list the built-in scenes and their parameters", description=cmd_scenes.__doc__)
    p.add_argument("--json", action="store_true", help="print the listing as one JSON object")
    p.set_defaults(func=cmd_scenes)
    return top


def _one_line(text):
    return " ".join(str(text).split()) or "(no message)"


def _scene_file_error(err, args):
    """``scene file drop.py, line 3: ZeroDivisionError: ...`` when ``err`` came from the user's scene file."""
    scene = getattr(args, "scene", None)
    if not scene or not str(scene).endswith(".py"):
        return None
    path = os.path.abspath(scene)
    if isinstance(err, SyntaxError) and err.filename and os.path.abspath(err.filename) == path:
        line = err.lineno
    else:
        lines = [f.lineno for f in traceback.extract_tb(err.__traceback__) if os.path.abspath(f.filename) == path]
        if not lines:
            return None
        line = lines[-1]
    if isinstance(err, SystemExit):
        return (f"scene file {scene}, line {line}: called sys.exit({err.code!r}) instead of returning a Simulation "
                f"(scene(**kwargs) must return one)")
    text = err.msg if isinstance(err, SyntaxError) else err
    return f"scene file {scene}, line {line}: {type(err).__name__}: {_one_line(text)}"


def main(argv=None):
    """Run the command line on ``argv`` (default ``sys.argv[1:]``); returns the exit code.

    0 success, 1 a run that failed or diverged, 2 a mistake in the command (one line on stderr),
    130 interrupted.
    """
    argv = list(sys.argv[1:] if argv is None else argv)
    top = parser()
    if not argv or argv[0].startswith("-") and argv[0] not in ("-h", "--help"):
        argv = ["demo"] + argv
    try:
        args = top.parse_args(argv)
    except SystemExit as done:  # --help (0) or a one-line usage error (2), already printed
        return done.code
    name = f"skfem-affine {args.command}"
    try:
        if os.path.exists(getattr(args, "out", "")) and not os.path.isdir(args.out):
            raise ValueError(f"--out {args.out} is a file; give a folder")
        return args.func(args)
    except KeyboardInterrupt:
        print(f"{name}: interrupted", file=sys.stderr)
        return 130
    except SystemExit as err:  # sys.exit inside a command (a scene file's, or a library's): never a success
        message = _scene_file_error(err, args)
        if message is None:
            traceback.print_exc()
            return 1
        print(f"{name}: error: {message}", file=sys.stderr)
        return 2
    except MemoryError as err:
        print(f"{name}: error: out of memory ({_one_line(err)}) running `skfem-affine {' '.join(argv)}`: "
              f"try a smaller scene (--resolution, --set, --meshes)", file=sys.stderr)
        return 1
    except Exception as err:  # noqa: BLE001 (a mistake of the user's gets one line; a bug its traceback)
        from skfem_affine.simulation import SimulationDiverged
        if isinstance(err, SimulationDiverged):
            print(f"{name}: {_one_line(err)}", file=sys.stderr)
            return 1
        message = _scene_file_error(err, args)
        if message is None and isinstance(err, (ValueError, TypeError, ImportError, OSError)):
            message = _one_line(err)
        if message is None:
            raise
        print(f"{name}: error: {message}", file=sys.stderr)
        return 2
