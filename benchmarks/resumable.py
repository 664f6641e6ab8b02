"""Methods stepped in turn, frame by frame, in one process: a run that checkpoints, resumes and reports
its whole length and its rest phase (used by ``benchmarks/paper_table1.py``).

Every method (full space first, then each reducer) is built from the same ``build(reducer)`` and
stepped once per frame, the order rotating from frame to frame so that load from elsewhere slows
every method alike. Each frame keeps, per method: the wall time measured around ``sim.step()``,
the timed phases of the frame's record (s), the contacts, PGS sweeps and DOFs solved; per reducer
the largest vertex distance to the full solve over the scene's size; and the full solve's kinetic
energy (which finds the rest phase).

With a checkpoint folder, every ``every`` frames the simulations are saved (``sim.save``, one file
per method, named by frame) with the accumulated per-frame records (``progress.json``) and a
report (``report.md``, ``report.json``); a run started again with the same folder loads them and
continues, with the same states, errors and DOFs as an uninterrupted run (only wall times differ).

The rest phase is the frames from ``rest_from`` on, or, when not given, from the first frame
after which the full solve's kinetic energy stays below ``rest_ke`` times its peak.
"""
import datetime
import json
import os
import sys
import time

import numpy as np

from skfem_affine.integrators.problem import PHASES
from skfem_affine.simulation import SimulationDiverged

METHODS = ("full", "affinification", "rigidification")
#: Per-phase means of the report (ms per frame): the frame, then its parts.
PHASE_COLUMNS = ("wall", "factorization", "delassus", "pgs", "detection", "other")
COUNT_COLUMNS = ("n_contacts", "pgs_iterations", "dofs")
PROGRESS = "progress.json"


def frame_record(rec, wall):
    """One method's frame: the wall time (s) around its step, its timed phases (s), contacts, sweeps, DOFs."""
    out = {"wall": float(wall)}
    for key in PHASES + ("delassus", "pgs"):
        out[key] = float(rec.get(key, 0.0))
    for key in COUNT_COLUMNS:
        out[key] = int(rec.get(key, 0))
    return out


def kinetic_energy(sim):
    """0.5 v^T M v of the simulation's current state (J)."""
    v = sim.state.v.reshape(-1)
    return 0.5 * float(v @ (sim.system.M @ v))


def _write_json(path, data):
    tmp = f"{path}.tmp{os.getpid()}"
    with open(tmp, "w") as fh:
        json.dump(data, fh, indent=1)
    os.replace(tmp, path)


def _checkpoint_path(folder, method, frame):
    return os.path.join(folder, f"{method}-{frame:06d}.npz")


def new_progress(frames, names, meta):
    """The record of a run that has not stepped yet."""
    return {"frames_total": int(frames), "done": 0, "methods": list(names), "diverged": [None] * len(names),
            "records": [[] for _ in names], "errors": [[] for _ in names], "kinetic": [], "meta": meta}


def save(folder, sims, progress):
    """Checkpoint every simulation, then the progress that points at them (so a kill leaves one whole set)."""
    done = progress["done"]
    for name, sim in zip(progress["methods"], sims):
        sim.save(_checkpoint_path(folder, name, done))
    _write_json(os.path.join(folder, PROGRESS), progress)
    for fname in os.listdir(folder):  # the previous set
        stem, ext = os.path.splitext(fname)
        if ext == ".npz" and "-" in stem and stem.rsplit("-", 1)[1].isdigit() and int(stem.rsplit("-", 1)[1]) != done:
            os.remove(os.path.join(folder, fname))


def resume(folder, sims, frames, names):
    """The progress saved in ``folder`` (None if there is none), its simulations loaded into ``sims``.

    ValueError when the folder holds a run of another length or other methods.
    """
    path = os.path.join(folder, PROGRESS)
    if not os.path.isfile(path):
        return None
    with open(path) as fh:
        progress = json.load(fh)
    if progress["frames_total"] != frames or progress["methods"] != list(names):
        raise ValueError(f"checkpoint folder {folder} holds a run of {progress['frames_total']} frames of "
                         f"{progress['methods']}, not {frames} frames of {list(names)}: use another folder")
    for name, sim in zip(names, sims):
        sim.load_state(_checkpoint_path(folder, name, progress["done"]))
    return progress


def run(build, reducer_list, frames, checkpoint=None, every=25, stop_at=None, meta=None, on_save=None,
        names=METHODS, log=sys.stderr):
    """Step full space and every reducer frame by frame, in turn; checkpoint and resume in ``checkpoint``.

    Parameters
    ----------
    build : callable
        ``build(reducer)`` -> Simulation (``None``: full space).
    reducer_list : list
        The reducers, stepped after full space.
    frames : int
        Length of the run.
    checkpoint : str, optional
        Folder of the checkpoints (created); a run saved there is continued.
    every : int
        Frames between checkpoints.
    stop_at : int, optional
        Stop (after a checkpoint) once this many frames are done, as an interrupted run would.
    meta : dict, optional
        Kept in the progress record (scene, settings, command) for the report.
    on_save : callable, optional
        ``on_save(progress)`` after each checkpoint (writes the report).

    Returns
    -------
    sims, progress
        The simulations (full first) and the per-frame records (:func:`new_progress`).
    """
    sims = [build(None)] + [build(r) for r in reducer_list]
    if len(sims) != len(names):
        raise ValueError(f"{len(sims)} methods, but {len(names)} names")
    progress = None
    if checkpoint:
        os.makedirs(checkpoint, exist_ok=True)
        progress = resume(checkpoint, sims, frames, names)
        if progress is not None:
            print(f"resumed at frame {progress['done']} of {frames} from {checkpoint}", file=log, flush=True)
            if meta:
                progress["meta"] = dict(progress.get("meta") or {}, **meta)
    if progress is None:
        progress = new_progress(frames, names, meta or {})
    end = frames if stop_at is None else min(frames, int(stop_at))
    diverged, t0 = progress["diverged"], time.perf_counter()
    while progress["done"] < end and diverged[0] is None:
        frame = progress["done"]
        for i in [(frame + k) % len(sims) for k in range(len(sims))]:  # rotate who steps first
            if diverged[i] is not None:
                continue
            t = time.perf_counter()
            try:
                sims[i].step()
            except SimulationDiverged as err:
                diverged[i] = err.frame
                continue
            progress["records"][i].append(frame_record(sims[i].stats[-1], time.perf_counter() - t))
        full = sims[0]
        for i, sim in enumerate(sims):
            ok = diverged[i] is None and diverged[0] is None
            err = float(np.abs(sim.state.x - full.state.x).max() / full.size) if (i and ok) else None
            progress["errors"][i].append(err)
        progress["kinetic"].append(kinetic_energy(full) if diverged[0] is None else None)
        progress["done"] = frame + 1
        if progress["done"] % 10 == 0:
            walls = [sum(r["wall"] for r in recs) for recs in progress["records"]]
            print(f"frame {progress['done']}/{frames} ({time.perf_counter() - t0:.0f} s): wall s "
                  + " ".join(f"{w:.1f}" for w in walls), file=log, flush=True)
        if checkpoint and (progress["done"] % every == 0 or progress["done"] == end or diverged[0] is not None):
            progress["updated"] = datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
            progress["load_average"] = os.getloadavg()[0] if hasattr(os, "getloadavg") else None
            save(checkpoint, sims, progress)
            if on_save is not None:
                on_save(progress)
    return sims, progress


def rest_start(kinetic, rest_ke=0.01):
    """Index of the first frame after which the kinetic energy stays below ``rest_ke`` times its peak (None: never)."""
    ke = np.array([np.nan if k is None else k for k in kinetic], float)
    if ke.size == 0 or not np.all(np.isfinite(ke)):
        return None
    high = np.flatnonzero(ke >= rest_ke * ke.max())
    start = int(high[-1]) + 1 if high.size else 0
    return start if start < ke.size else None


def summarize(progress, first, last):
    """Speedups, largest error, DOF ratio and per-phase means of frames ``first`` to ``last - 1`` (0-based).

    A method that diverged counts its frames up to the divergence.
    """
    names = progress["methods"]
    out = {"frames": [first + 1, last], "methods": {}}
    walls = {}
    full_dofs = sum(r["dofs"] for r in progress["records"][0][first:last])
    for i, name in enumerate(names):
        recs = progress["records"][i][first:last]
        errs = [e for e in progress["errors"][i][first:last] if e is not None]
        walls[name] = sum(r["wall"] for r in recs)
        means = {}
        for col in PHASE_COLUMNS + COUNT_COLUMNS:
            vals = [_column(r, col) for r in recs]
            scale = 1e3 if col in PHASE_COLUMNS else 1.0
            means[col] = scale * float(np.mean(vals)) if vals else None
        out["methods"][name] = {
            "frames_stepped": len(recs), "wall_s": walls[name],
            "speedup": walls[names[0]] / walls[name] if i and walls[name] else None,
            "max_distance_error": max(errs) if errs else None,
            "dof_ratio": sum(r["dofs"] for r in recs) / full_dofs if i and full_dofs else None,
            "means": means}
    return out


def _column(rec, col):
    if col == "detection":  # contact outside the Delassus build and the PGS solve
        return rec["contact"] - rec["delassus"] - rec["pgs"]
    if col == "other":
        return rec["wall"] - rec["factorization"] - rec["contact"]
    return rec[col]


def phases(progress, rest_from=None, rest_ke=0.01):
    """``{"run": summary, "rest": summary or None, "rest_rule": str}`` over the frames done so far.

    ``rest_from``: first frame (1-based) of the rest phase; default from the kinetic energy.
    """
    done = len(progress["records"][0])
    if rest_from is not None:
        start, rule = int(rest_from) - 1, f"from frame {int(rest_from)} (given)"
    else:
        start = rest_start(progress["kinetic"][:done], rest_ke)
        rule = (f"from the first frame after which the full solve's kinetic energy stays below {rest_ke:g} of "
                f"its peak so far")
    rest = summarize(progress, start, done) if start is not None and 0 <= start < done else None
    return {"run": summarize(progress, 0, done), "rest": rest, "rest_rule": rule}


def markdown(title, progress, split, paper=None):
    """A self-explanatory report of a (possibly unfinished) run: run and rest rows, per-phase means."""
    names = progress["methods"]
    meta = progress.get("meta", {})
    done, total = len(progress["records"][0]), progress["frames_total"]
    lines = [f"# {title}", "",
             f"{done} of {total} frames done (last update {progress.get('updated', '-')}, load average "
             f"{_num(progress.get('load_average'), '.1f')}); methods stepped in turn in one process, the order "
             f"rotating each frame, so only the ratios mean anything."]
    for key, val in meta.items():
        lines.append(f"- {key}: {val}")
    if any(d is not None for d in progress["diverged"]):
        lines.append("- diverged: " + ", ".join(f"{n} at frame {d}" for n, d in zip(names, progress["diverged"])
                                               if d is not None))
    ke = [k for k in progress["kinetic"][:done] if k is not None]
    if ke:
        peak = int(np.argmax(ke))
        lines.append(f"- kinetic energy of the full solve: peak {ke[peak]:.3g} J at frame {peak + 1}, "
                     f"{ke[-1]:.3g} J ({ke[-1] / max(ke[peak], 1e-300):.2g} of the peak) at frame {len(ke)}")
    return "\n".join(lines) + "\n\n" + tables(split, names, paper)


def tables(split, names=METHODS, paper=None):
    """The run and rest rows (speedup, error, DOF ratio) and their per-phase means (Markdown)."""
    rest = split["rest"]
    lines = [f"Rest phase: {split['rest_rule']}: "
             + (f"frames {rest['frames'][0]}-{rest['frames'][1]}." if rest else "not reached yet."), ""]
    head = "| window | method | wall s | speedup | max dist. err. | DOF ratio |" + (" paper speedup |" if paper else "")
    lines += [head, "|" + "---|" * (head.count("|") - 1)]
    for label, summ in (("run", split["run"]), ("rest", rest)):
        if summ is None:
            continue
        window = f"{label} {summ['frames'][0]}-{summ['frames'][1]}"
        for name in names:
            m = summ["methods"][name]
            lines.append(f"| {window} | {name} | {m['wall_s']:.1f} | {_num(m['speedup'], '.2f')} "
                         f"| {_num(m['max_distance_error'], '.1e')} | {_num(m['dof_ratio'], '.3f')} |"
                         + (f" {_num((paper or {}).get(name), '.2f')} |" if paper else ""))
    for label, summ in (("run", split["run"]), ("rest", rest)):
        if summ is None:
            continue
        lines += ["", f"Per-phase means over the {label} (frames {summ['frames'][0]}-{summ['frames'][1]}), ms per "
                  f"frame (detection: contact outside the Delassus build and PGS; other: the frame outside "
                  f"factorisation and contact; the last three rows are per-frame means of counts):", "",
                  "| | " + " | ".join(names) + " |", "|---|" + "---|" * len(names)]
        for col in PHASE_COLUMNS + COUNT_COLUMNS:
            fmt = ".0f" if col != "pgs_iterations" else ".1f"
            lines.append(f"| {col} | " + " | ".join(_num(summ["methods"][n]["means"][col], fmt) for n in names)
                         + " |")
    return "\n".join(lines) + "\n"


def _num(x, fmt):
    return "-" if x is None else format(x, fmt)


def write_report(folder, title, progress, rest_from=None, rest_ke=0.01, paper=None):
    """``report.md`` and ``report.json`` in ``folder`` for the frames done so far; returns the split."""
    split = phases(progress, rest_from, rest_ke)
    with open(os.path.join(folder, "report.md.tmp"), "w") as fh:
        fh.write(markdown(title, progress, split, paper))
    os.replace(os.path.join(folder, "report.md.tmp"), os.path.join(folder, "report.md"))
    _write_json(os.path.join(folder, "report.json"),
                dict(split, title=title, frames_done=len(progress["records"][0]), frames_total=progress["frames_total"],
                     updated=progress.get("updated"), meta=progress.get("meta", {}), paper_speedups=paper,
                     diverged=progress["diverged"]))
    return split
