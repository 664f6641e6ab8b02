"""Runners that measure the speed/accuracy trade: ``compare``, ``sweep`` (on Dask) and ``scaling``.

A *scene* is a :class:`SceneSpec`: the name of a scene in
:data:`skfem_affine.scenes.SCENES` (or the path of a Python file defining
``scene(**kwargs)`` that returns a :class:`~skfem_affine.Simulation`) and its
keyword overrides. A *method* is a :class:`Method`: a name and a reducer factory
``factory(tau_a, tau_e) -> reducer or None``; adding one is one line in
:data:`METHODS` (or ``register(Method(...))``).

Every reduced run is measured against a full-space :class:`Reference` of the
same scene from the same initial state (:mod:`skfem_affine.metrics`).
"""
import hashlib
import json
import os
import runpy
import time
from dataclasses import dataclass, field

import numpy as np

from skfem_affine.lab import metrics

from skfem_affine.lab import scenes
from skfem_affine.simulation import SimulationDiverged
from skfem_affine.reducers.affine.affinification import Affinification
from skfem_affine.reducers.affine.rigidification import Rigidification
from skfem_affine.reducers.subspace.reducer import AdaptiveSubspace


# ---------------------------------------------------------------- methods
@dataclass(frozen=True)
class Method:
    """A way to run a scene: ``factory(tau_a, tau_e)`` returns a fresh reducer (None: full space).

    ``taus`` are the default thresholds, used when the caller gives none.
    """

    name: str
    factory: object
    taus: tuple = (None, None)

    def reducer(self, tau_a=None, tau_e=None):
        return self.factory(self.taus[0] if tau_a is None else tau_a, self.taus[1] if tau_e is None else tau_e)


METHODS = {m.name: m for m in [
    Method("full", lambda tau_a, tau_e: None),
    Method("affinification", lambda tau_a, tau_e: Affinification(tau_a=tau_a, tau_e=tau_e), (0.1, 0.2)),
    Method("rigidification", lambda tau_a, tau_e: Rigidification(tau_r=tau_a, tau_e=tau_e), (1e-2, 2e-2)),
    # needs a Newton integrator: run the scene with integrator="implicit_euler" (--set integrator=implicit_euler),
    # so that "full" is the full-space Newton reference it converges to; tau_a, tau_e = eps_nodal, eps_modal
    Method("subspace", lambda tau_a, tau_e: AdaptiveSubspace(eps_nodal=tau_a, eps_modal=tau_e), (1e-3, 3e-3)),
]}


def register(method):
    """Add (or replace) a method by name: ``register(Method("mine", lambda a, e: Mine(a, e), (0.1, 0.2)))``."""
    if not isinstance(method, Method):
        raise TypeError(f"register needs a runners.Method, got {type(method).__name__}")
    METHODS[method.name] = method
    return method


def get_method(method):
    if isinstance(method, Method):
        return method
    if method not in METHODS:
        raise ValueError(f"unknown method {method!r}; known: {', '.join(METHODS)}")
    return METHODS[method]


# ---------------------------------------------------------------- scenes
def load_scene_file(path):
    """The ``scene`` function of a user's Python file (it must return a Simulation and accept ``reducer=``)."""
    if not os.path.isfile(path):
        raise ValueError(f"scene file {path!r} does not exist")
    namespace = runpy.run_path(path, run_name="skfem_affine_scene")
    factory = namespace.get("scene")
    if not callable(factory):
        raise ValueError(f"{path} must define a function scene(**kwargs) returning a skfem_affine.Simulation "
                         f"(it receives reducer=... and the scene's keyword overrides)")
    return factory


@dataclass(frozen=True)
class SceneSpec:
    """A scene by name (``scenes.SCENES``) or file path, with keyword overrides (picklable, hashable)."""

    name: str
    kwargs: tuple = ()

    @classmethod
    def make(cls, name, **kwargs):
        if not (name in scenes.SCENES or str(name).endswith(".py")):
            raise ValueError(f"unknown scene {name!r}; built-in scenes: {', '.join(scenes.SCENES)} "
                             f"(or give the path of a .py file defining scene(**kwargs))")
        name = os.path.abspath(name) if str(name).endswith(".py") else name
        return cls(name, tuple(sorted((k, v) for k, v in kwargs.items() if v is not None)))

    @property
    def label(self):
        return os.path.splitext(os.path.basename(self.name))[0]

    def factory(self):
        return scenes.SCENES[self.name] if self.name in scenes.SCENES else load_scene_file(self.name)

    def build(self, reducer=None):
        """The scene's Simulation. Built-in scenes solve with the reducers' direct solver unless
        ``solver`` is given, so that every method is timed with the same solver (the reference too)."""
        kwargs = dict(self.kwargs)
        if self.name in scenes.SCENES:
            kwargs.setdefault("solver", "direct")
        sim = self.factory()(reducer=reducer, **kwargs)
        if not hasattr(sim, "stats") or not hasattr(sim, "run"):
            raise TypeError(f"scene {self.name!r} returned {type(sim).__name__}, not a Simulation")
        return sim

    def with_kwargs(self, **kwargs):
        return SceneSpec.make(self.name, **{**dict(self.kwargs), **kwargs})

    def key(self):
        """A short, stable identifier of the scene and its overrides (for caches)."""
        text = json.dumps([self.name, [[k, repr(v)] for k, v in self.kwargs]])
        return "s" + hashlib.sha1(text.encode()).hexdigest()[:12]


def default_frames(sim, frames=None):
    return int(frames) if frames is not None else int(getattr(sim, "frames", 100))


# ---------------------------------------------------------------- runs
@dataclass
class Reference:
    """The full-space run: positions per frame (frames + 1, n, 3), strain energy, wall and DOFs per frame."""

    x: np.ndarray
    strain: np.ndarray
    wall: np.ndarray
    dofs: np.ndarray
    size: float

    @property
    def frames(self):
        return self.wall.size

    def save(self, path):
        np.savez(path, x=self.x, strain=self.strain, wall=self.wall, dofs=self.dofs, size=self.size)

    @classmethod
    def load(cls, path):
        with np.load(path) as d:
            return cls(d["x"], d["strain"], d["wall"], d["dofs"], float(d["size"]))


@dataclass
class Run:
    """One measured run: per-frame records, summary, and the states kept for pictures and ParaView."""

    method: str
    summary: dict
    records: list
    states: list = field(default_factory=list)
    sim: object = None


def _record(rec):
    """A stats record without per-element arrays (those go to pictures and ParaView)."""
    return {k: v for k, v in rec.items() if not isinstance(v, np.ndarray)}


def run(spec, method="full", frames=None, tau_a=None, tau_e=None, reference=None, step_error=True,
        residual=True, keep_every=0, keep_frames=(), progress=False, on_state=None, paired_timing=False):
    """Run ``spec`` with ``method``; measure it against ``reference`` when given.

    Parameters
    ----------
    paired_timing : bool
        Step a full-space twin in lockstep, frame by frame in this process, and
        take the speedup from it (``full_wall`` per frame) rather than from the
        reference's wall time: both then run under the same machine load, as
        when sweep cells share cores. Costs one more full-space run.
    keep_every : int
        Keep every k-th state (and frame 0) in ``Run.states`` (0: none), plus ``keep_frames``.
    progress : bool
        A tqdm bar over frames (on stderr).
    on_state : callable(sim, state), optional
        Called with the initial state and after every frame (e.g. a ParaView writer).

    A :class:`~skfem_affine.SimulationDiverged` ends the run early: the summary
    then has ``status="diverged"`` and the frames done so far are kept.
    """
    method = get_method(method)
    tau_a = method.taus[0] if tau_a is None else tau_a
    tau_e = method.taus[1] if tau_e is None else tau_e
    sim = spec.build(reducer=method.reducer(tau_a, tau_e))
    frames = default_frames(sim, frames)
    if reference is not None and reference.frames < frames:
        raise ValueError(f"the reference has {reference.frames} frames, fewer than the {frames} asked for")
    measure = reference is not None and sim.reducer is not None and (step_error or residual)
    evaluator = spec.build() if measure else None
    strain_scale = float(np.max(reference.strain)) if reference is not None else 0.0
    records, kept = [], []
    keep = set(int(f) for f in keep_frames)

    def want(state):
        return (keep_every and (state.frame % keep_every == 0 or state.frame == frames)) or state.frame in keep

    first = sim.state.copy()
    if keep_every or keep:
        kept.append(first)
    if on_state:
        on_state(sim, first)
    trajectory = [first] if evaluator is not None else None
    twin = spec.build() if paired_timing else None
    status, message = "ok", ""
    bar = _bar(frames, f"{spec.label} {method.name}", progress)
    try:
        for state in sim.run(frames):
            rec = _record(sim.stats[-1])
            rec.update(time=state.time, strain_energy=sim.system.strain_energy(state.x))
            rec.setdefault("n_clusters", 0)
            rec.setdefault("elastic_dofs", rec.get("dofs", 0))
            if reference is not None:
                rec["distance_error"] = metrics.distance_error(state.x, reference.x[state.frame], reference.size)
                rec["energy_error"] = float(metrics.energy_error(rec["strain_energy"], reference.strain[state.frame],
                                                                 strain_scale))
            if twin is not None:
                twin.step()
                rec["full_wall"] = twin.stats[-1]["wall"]
            records.append(rec)
            if trajectory is not None:
                trajectory.append(state)
            if want(state):
                kept.append(state)
            if on_state:
                on_state(sim, state)
            bar.update(1)
    except SimulationDiverged as err:
        status, message = "diverged", str(err)
    finally:
        bar.close()
    if trajectory is not None:  # after the timed loop, so that measuring does not disturb the timing
        for rec, before, after in zip(records, trajectory[:-1], trajectory[1:]):
            if residual:
                rec["residual"] = metrics.full_space_residual(evaluator, before, after)
            if step_error:
                restarted = metrics.reference_step(evaluator, before)
                rec["step_error"] = metrics.distance_error(after.x, restarted.x, reference.size)
    summary = {"scene": spec.label, "method": method.name,
               "tau_a": tau_a if sim.reducer is not None else None,
               "tau_e": tau_e if sim.reducer is not None else None,
               "elements": int(sim.system.m), "vertices": int(sim.system.n),
               **metrics.summarise(records, reference), "setup_s": float(getattr(sim.reducer, "setup_time", 0.0)),
               "timing": "reference", "status": status, "message": message}
    if twin is not None and records:
        summary.update(speedup=metrics.speedup(metrics.column(records, "full_wall").sum(), summary["wall_s"]),
                       timing="paired")
    return Run(method.name, summary, records, kept, sim)


def reference_run(spec, frames=None, progress=False, keep_every=0, keep_frames=()):
    """The full-space run of ``spec``: its :class:`Reference` and its measured :class:`Run`.

    Raises :class:`~skfem_affine.SimulationDiverged` if the reference itself diverges.
    """
    positions = []
    result = run(spec, "full", frames, progress=progress, keep_every=keep_every, keep_frames=keep_frames,
                 on_state=lambda sim, state: positions.append(state.x))
    if result.summary["status"] != "ok":
        raise SimulationDiverged(len(result.records) + 1, f"the full-space reference diverged "
                                 f"({result.summary['message']})")
    sim, records = result.sim, result.records
    strain0 = sim.system.strain_energy(positions[0])
    ref = Reference(np.array(positions), np.concatenate([[strain0], metrics.column(records, "strain_energy")]),
                    metrics.column(records, "wall"), metrics.column(records, "dofs"), sim.size)
    for rec in records:  # the reference measured against itself
        rec.update(distance_error=0.0, energy_error=0.0)
    result.summary.update(metrics.summarise(records, ref))
    return ref, result


def warm_up(spec, methods=("full",), frames=2):
    """Run each method a couple of frames so that one-off costs (loading compiled kernels,
    solver libraries) are not in the timed runs. Returns nothing."""
    for name in methods:
        sim = spec.build(reducer=get_method(name).reducer())
        for _ in sim.run(frames):
            pass


def _bar(total, desc, enabled):
    """A tqdm progress bar on stderr when ``enabled``, else an object that ignores updates."""
    if enabled:
        from tqdm import tqdm
        return tqdm(total=total, desc=desc, unit="frame" if "cell" not in desc else "cell", leave=False)
    return _NoBar()


class _NoBar:
    def update(self, n=1):
        pass

    def close(self):
        pass


# ---------------------------------------------------------------- compare
COMPARED = ("full", "affinification", "rigidification")


def compare(spec, frames=None, methods=COMPARED, taus=None, step_error=True, residual=True, keep_every=10,
            keep_frames=(), progress=False):
    """Run the full-space reference and each method on one scene (paper Table 1, Fig. 1, 12).

    ``taus`` maps a method name to its (tau_a, tau_e) (default: the method's own).
    Returns ``(reference, {name: Run})``; the "full" Run is the reference.
    """
    taus = dict(taus or {})
    for name in methods:
        get_method(name)
    warm_up(spec, tuple(dict.fromkeys(("full",) + tuple(methods))))
    ref, full = reference_run(spec, frames, progress, keep_every, keep_frames)
    results = {"full": full}
    for name in methods:
        if name != "full":
            results[name] = run(spec, name, ref.frames, *taus.get(name, (None, None)), reference=ref,
                                step_error=step_error, residual=residual, keep_every=keep_every,
                                keep_frames=keep_frames, progress=progress)
    return ref, results


# ---------------------------------------------------------------- sweep
def sweep_taus(grid=9, tau_range=(1e-3, 1.0)):
    """``grid`` thresholds log-spaced over ``tau_range`` (the axes of paper Fig. 6)."""
    lo, hi = map(float, tau_range)
    if not 0 < lo <= hi:
        raise ValueError(f"tau range must satisfy 0 < lo <= hi, got {tau_range}")
    if int(grid) < 1:
        raise ValueError(f"grid must be >= 1, got {grid}")
    return np.array([float(f"{t:.6g}") for t in np.logspace(np.log10(lo), np.log10(hi), int(grid))])


def cell_key(row):
    """What identifies a sweep cell: scene and overrides, frames asked, method, thresholds, timing."""
    return (str(row["scene_key"]), int(float(row["frames_asked"])), str(row["method"]),
            f"{float(row['tau_a']):.6g}", f"{float(row['tau_e']):.6g}", str(row.get("timing_asked") or "reference"))


def sweep_cell(spec, method, frames, tau_a, tau_e, reference, step_error=True, residual=True, paired_timing=False):
    """One sweep cell: a measured run, as a flat table row. Never raises for a failed simulation."""
    base = {"scene": spec.label, "scene_key": spec.key(), "frames_asked": int(frames),
            "method": get_method(method).name, "tau_a": float(tau_a), "tau_e": float(tau_e),
            "timing_asked": "paired" if paired_timing else "reference"}
    t0 = time.perf_counter()
    try:
        result = run(spec, method, frames, tau_a, tau_e, reference=reference, step_error=step_error,
                     residual=residual, paired_timing=paired_timing)
        row = {**result.summary, **base}
    except Exception as err:  # recorded, so that one bad cell neither stops nor hides in the sweep
        row = {**base, "status": "error", "message": f"{type(err).__name__}: {err}"}
    row["cell_s"] = time.perf_counter() - t0
    return row


def connect(scheduler=None, workers=None, processes=True):
    """A dask Client on ``scheduler`` (an address), or on an embedded LocalCluster.

    Returns ``(client, cluster)``; ``cluster`` is None for an external scheduler.
    """
    import logging

    from dask.distributed import Client, LocalCluster
    if scheduler:
        return Client(scheduler), None
    cluster = LocalCluster(n_workers=int(workers or os.cpu_count() or 1), threads_per_worker=1,
                           processes=processes, dashboard_address=":0", silence_logs=logging.ERROR)
    return Client(cluster), cluster


def sweep(spec, frames=None, method="affinification", grid=9, tau_range=(1e-3, 1.0), table="out/sweep.csv",
          scheduler=None, workers=None, processes=True, step_error=True, residual=True, retry_failed=False,
          progress=False, paired_timing=False):
    """A tau_a x tau_e grid of runs against one shared reference, on Dask (paper Fig. 6).

    Rows are written to ``table`` (.csv, or .parquet with pyarrow) as cells
    finish; cells already in the table are not recomputed (failed ones neither,
    unless ``retry_failed``). The reference is cached next to the table.
    Cells share cores, so their speedups over the reference (timed alone) are
    pessimistic on a busy machine; ``paired_timing`` times a full-space twin
    in each cell instead (see :func:`run`). Returns the rows of this sweep.
    """
    method = get_method(method)
    taus = sweep_taus(grid, tau_range)
    if frames is None:
        frames = default_frames(spec.build())
    frames = int(frames)
    base = {"scene_key": spec.key(), "frames_asked": frames, "method": method.name,
            "timing_asked": "paired" if paired_timing else "reference"}
    cells = [(ta, te) for te in taus for ta in taus]
    keys = [cell_key({**base, "tau_a": ta, "tau_e": te}) for ta, te in cells]
    rows = read_table(table) if os.path.exists(table) else []
    if retry_failed:
        rows = [r for r in rows if r.get("status") == "ok" or cell_key(r) not in set(keys)]
    done = {cell_key(r) for r in rows}
    todo = [c for c, k in zip(cells, keys) if k not in done]
    if todo:
        client, cluster = connect(scheduler, workers, processes)
        try:
            client.run(warm_up, spec, ("full", method))
            ref_path = os.path.join(os.path.dirname(os.path.abspath(table)), f"reference_{spec.key()}_{frames}.npz")
            if os.path.exists(ref_path):
                reference = client.scatter(Reference.load(ref_path), broadcast=True)
            else:
                reference = client.submit(_reference_only, spec, frames, pure=False)
                Reference.save(reference.result(), ref_path)
            futures = [client.submit(sweep_cell, spec, method, frames, ta, te, reference, step_error, residual,
                                     paired_timing, pure=False) for ta, te in todo]
            from dask.distributed import as_completed
            bar = _bar(len(futures), f"{spec.label} sweep cells", progress)
            for future in as_completed(futures):
                rows.append(future.result())
                write_table(rows, table)
                bar.update(1)
            bar.close()
        finally:
            client.close()
            if cluster is not None:
                cluster.close()
    wanted = set(keys)
    mine = {cell_key(r): r for r in rows if cell_key(r) in wanted}
    return [mine[k] for k in keys if k in mine]


def _reference_only(spec, frames):
    return reference_run(spec, frames)[0]


# ---------------------------------------------------------------- tables
def _value(text):
    if text == "":
        return None
    try:
        number = float(text)
    except ValueError:
        return text
    return int(number) if number.is_integer() and "." not in text and "e" not in text.lower() else number


def write_table(rows, path):
    """Write a list of dicts as a tidy table: CSV, or Parquet (needs pyarrow) for a .parquet path."""
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    columns = list(dict.fromkeys(k for r in rows for k in r))
    tmp = path + ".tmp"
    if path.endswith(".parquet"):
        pq = _pyarrow_parquet()
        import pyarrow as pa
        pq.write_table(pa.Table.from_pylist([{c: r.get(c) for c in columns} for r in rows]), tmp)
    else:
        import csv
        with open(tmp, "w", newline="") as fh:
            writer = csv.DictWriter(fh, fieldnames=columns)
            writer.writeheader()
            for r in rows:
                writer.writerow({c: "" if r.get(c) is None else r.get(c) for c in columns})
    os.replace(tmp, path)
    return path


def read_table(path):
    """Rows (dicts) of a table written by :func:`write_table`."""
    if path.endswith(".parquet"):
        return _pyarrow_parquet().read_table(path).to_pylist()
    import csv
    with open(path, newline="") as fh:
        return [{k: _value(v) for k, v in r.items()} for r in csv.DictReader(fh)]


def _pyarrow_parquet():
    try:
        import pyarrow.parquet as pq
    except ImportError:
        raise ImportError("Parquet tables need pyarrow (pip install pyarrow); or use a .csv table") from None
    return pq


# ---------------------------------------------------------------- scaling
def scaling(spec, resolutions, frames, method="affinification", tau_a=None, tau_e=None, step_error=False,
            residual=False, progress=False):
    """The same scene at increasing ``resolution`` (paper Table 2): full and reduced wall time, speedup, error.

    ``frames`` is one number or one per resolution (large meshes may take fewer).
    """
    resolutions = [int(k) for k in resolutions]
    frames = [frames] * len(resolutions) if np.ndim(frames) == 0 else list(frames)
    if len(frames) != len(resolutions):
        raise ValueError(f"give one frame count, or one per resolution ({len(resolutions)}), got {len(frames)}")
    rows = []
    for i, (k, f) in enumerate(zip(resolutions, frames)):
        s = spec.with_kwargs(resolution=k)
        if i == 0:
            warm_up(s, ("full", method))
        ref, full = reference_run(s, f, progress)
        red = run(s, method, ref.frames, tau_a, tau_e, reference=ref, step_error=step_error, residual=residual,
                  progress=progress)
        rs = red.summary
        rows.append({"scene": s.label, "resolution": k, "elements": rs["elements"], "vertices": rs["vertices"],
                     "frames": ref.frames, "method": rs["method"], "tau_a": rs["tau_a"], "tau_e": rs["tau_e"],
                     "time_full_s": full.summary["wall_s"], "time_reduced_s": rs["wall_s"],
                     "speedup": rs["speedup"], "max_distance_error": rs["max_distance_error"],
                     "dof_ratio": rs["dof_ratio"], "mean_clusters": rs["mean_clusters"], "status": rs["status"]})
    return rows
