"""Measured runs: one method (:func:`run`), the full-space :func:`reference_run`, several methods
stepped in turn (:func:`interleaved`) and :func:`compare`.

Every reduced run is measured against a full-space :class:`Reference` of the same scene from
the same initial state (:mod:`skfem_affine.lab.metrics`). Wall times are those of
``Simulation.step`` alone; the metrics are computed between steps or after the loop.

Speedups are ratios of wall times, so both times must be taken under the same machine load.
By default :func:`compare` steps every method *interleaved*: frame 1 of each method in turn,
then frame 2, ..., in one process, so that a burst of load from elsewhere slows every
method's frame alike and two runs of one command agree on the speedup. ``timing="sequential"``
runs each method alone, one after the other.
"""
import os
from dataclasses import dataclass, field

import numpy as np

from skfem_affine.checks import integer
from skfem_affine.lab import metrics
from skfem_affine.lab.methods import COMPARED, get_method
from skfem_affine.lab.progress import bar as progress_bar
from skfem_affine.lab.scene_spec import default_frames
from skfem_affine.lab.tables import FileFormatError
from skfem_affine.simulation import SimulationDiverged

#: How a run's speedup was timed (the ``timing`` entry of a summary), in words.
TIMING = {"interleaved": "interleaved frame by frame in one process",
          "sequential": "each method alone, one after the other, in one process",
          "paired": "against a full-space twin stepped in lockstep in the same process",
          "reference": "against a full-space reference timed in another run"}


@dataclass
class Reference:
    """The full-space run: positions per frame (frames + 1, n, 3), strain energy, wall and DOFs per
    frame, the scene size, the response (largest displacement from rest over the run, m) and the
    largest element stress per frame (Pa; None when not measured)."""

    x: np.ndarray
    strain: np.ndarray
    wall: np.ndarray
    dofs: np.ndarray
    size: float
    amplitude: float = 0.0
    stress: np.ndarray = None

    @property
    def frames(self):
        return self.wall.size

    def save(self, path):
        """Write a ``.npz`` atomically (a temporary file renamed into place): never half a file."""
        path = os.fspath(path)
        tmp = f"{path}.tmp{os.getpid()}.npz"
        try:
            extra = {} if self.stress is None else {"stress": self.stress}
            np.savez(tmp, x=self.x, strain=self.strain, wall=self.wall, dofs=self.dofs, size=self.size,
                     amplitude=self.amplitude, **extra)
            os.replace(tmp, path)
        finally:
            if os.path.exists(tmp):
                os.remove(tmp)
        return path

    @classmethod
    def load(cls, path):
        """Read a reference written by :meth:`save`; :class:`FileFormatError` names a damaged file."""
        path = os.fspath(path)
        try:
            with np.load(path) as d:
                # (a file without the response: the largest displacement from the first frame)
                amplitude = float(d["amplitude"]) if "amplitude" in d else metrics.response_amplitude(d["x"], d["x"][0])
                ref = cls(d["x"], d["strain"], d["wall"], d["dofs"], float(d["size"]), amplitude,
                          d["stress"] if "stress" in d else None)
        except FileNotFoundError:
            raise
        except Exception as err:  # zipfile.BadZipFile, EOFError, ValueError, KeyError, OSError, ...
            raise FileFormatError(f"reference {path} cannot be read ({type(err).__name__}: {err}); it is "
                                  f"truncated or corrupt: delete it to recompute it") from None
        if ref.x.shape[0] != ref.frames + 1 or ref.strain.shape[0] != ref.frames + 1:
            raise FileFormatError(f"reference {path} is inconsistent: {ref.x.shape[0]} positions for "
                                  f"{ref.frames} frames; delete it to recompute it")
        return ref


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


class _Stepped:
    """One simulation stepped by the runners: its records, kept states and trajectory.

    ``ref_x`` (positions per frame, possibly growing while the reference steps) and ``size``
    give the distance error per frame (and, with ``strain``, the largest stress difference); ``trajectory=True`` keeps every state for the
    measurements made after the loop (step error, residual); ``positions`` (a list)
    receives every state's positions.
    """

    def __init__(self, name, sim, ref_x=None, size=None, trajectory=False, keep_every=0, keep_frames=(),
                 frames=None, on_state=None, strain=True, positions=None, required=False):
        self.name, self.sim, self.ref_x, self.size = name, sim, ref_x, size
        self.keep_every, self.keep, self.frames = keep_every, {integer(f, "keep_frames", low=0) for f in keep_frames}, frames
        self.on_state, self.strain, self.positions, self.required = on_state, strain, positions, required
        self.records, self.kept, self.status, self.message = [], [], "ok", ""
        first = sim.state.copy()
        self.trajectory = [first] if trajectory else None
        if keep_every or self.keep:
            self.kept.append(first)
        self._seen(first)

    def _seen(self, state):
        if self.positions is not None:
            self.positions.append(state.x)
        if self.on_state is not None:
            self.on_state(self.sim, state)

    def _want(self, state):
        every = self.keep_every and (state.frame % self.keep_every == 0 or state.frame == self.frames)
        return every or state.frame in self.keep

    def step(self):
        """One timed ``sim.step()``, then its record (untimed)."""
        self.advance()
        self.record()

    def advance(self):
        """``sim.step()`` alone (its wall time is in the simulation's stats)."""
        self._state = self.sim.step().copy()

    def record(self):
        """The record of the frame :meth:`advance` stepped (distances read the reference's positions)."""
        state = self._state
        rec = _record(self.sim.stats[-1])
        rec["time"] = state.time
        system = self.sim.system
        if self.strain:
            rec["strain_energy"] = system.strain_energy(state.x)
            sigma = metrics.cauchy_stress(system, state.x)
            rec["max_stress"] = metrics.largest_stress(sigma)
        rec.setdefault("n_clusters", 0)
        rec.setdefault("elastic_dofs", rec.get("dofs", 0))
        if self.ref_x is not None:
            x_ref = self.ref_x[state.frame]
            rec["distance_m"] = metrics.distance_m(state.x, x_ref)
            rec["distance_error"] = rec["distance_m"] / self.size
            if self.strain:  # in Pa here; relative to the reference's largest stress after the run
                rec["stress_difference"] = metrics.stress_error(sigma, metrics.cauchy_stress(system, x_ref), 0.0)
        self.records.append(rec)
        if self.trajectory is not None:
            self.trajectory.append(state)
        if self._want(state):
            self.kept.append(state)
        self._seen(state)


def _step_in_turn(stepped, frames, bar=None, on_frame=None):
    """Step each simulation one frame, in turn, ``frames`` times, in this process.

    The order of the steps rotates from frame to frame, and the records are made after, in the
    given order: a simulation stepped right after another finds the caches holding the other's
    data, so a fixed order biases a ratio (docs/measuring.md). A simulation that diverges is left
    out of the following frames (its status says so); if a ``required`` one diverges (a
    reference), all stop.
    """
    alive = list(stepped)
    for frame in range(1, frames + 1):
        k = frame % len(alive)
        stop = False
        for s in alive[k:] + alive[:k]:
            try:
                s.advance()
            except SimulationDiverged as err:
                s.status, s.message = "diverged", str(err)
                alive.remove(s)
                if s.required:
                    stop = True
                    break
        if stop:
            return
        for s in alive:  # in the given order: a run's distances read the reference's positions of this frame
            s.record()
        if on_frame is not None:
            on_frame(frame, {s.name: s.sim for s in alive})
        if bar is not None:
            bar.update(1)
        if not alive:
            return


def _measure_after(s, reference, evaluator, step_error, residual):
    """The metrics that need the whole reference (energy, response, stress) or a full-space solve
    (step error, residual)."""
    if reference is None:
        return
    scale = float(np.max(reference.strain))
    stress = None if reference.stress is None else float(np.max(reference.stress))
    for rec in s.records:
        if "strain_energy" in rec:
            frame = int(rec["frame"])
            rec["energy_error"] = float(metrics.energy_error(rec["strain_energy"], reference.strain[frame], scale))
        if "distance_m" in rec:
            rec["response_error"] = metrics.relative(rec["distance_m"], reference.amplitude)
        if "stress_difference" in rec and stress is not None:
            rec["stress_error"] = metrics.relative(rec["stress_difference"], stress)
    if evaluator is None or s.trajectory is None:
        return
    for rec, before, after in zip(s.records, s.trajectory[:-1], s.trajectory[1:]):
        if residual:
            rec["residual"] = metrics.full_space_residual(evaluator, before, after)
        if step_error:
            restarted = metrics.reference_step(evaluator, before)
            rec["step_error"] = metrics.distance_error(after.x, restarted.x, reference.size)
    s.trajectory = None


def _summary(spec, method, tau_a, tau_e, s, reference, timing):
    sim = s.sim
    return {"scene": spec.label, "method": method.name,
            "tau_a": tau_a if sim.reducer is not None else None,
            "tau_e": tau_e if sim.reducer is not None else None,
            "elements": int(sim.system.m), "vertices": int(sim.system.n),
            "size_m": float(sim.size), "response_m": None if reference is None else float(reference.amplitude),
            **metrics.summarise(s.records, reference), "setup_s": float(getattr(sim.reducer, "setup_time", 0.0)),
            "timing": timing, "status": s.status, "message": s.message}


def _taus(method, tau_a, tau_e):
    return (method.taus[0] if tau_a is None else tau_a, method.taus[1] if tau_e is None else tau_e)


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
        Progress on stderr: a tqdm bar on a terminal, else a line every 30 s
        (:mod:`~skfem_affine.lab.progress`).
    on_state : callable(sim, state), optional
        Called with the initial state and after every frame (e.g. a ParaView writer).

    Notes
    -----
    A :class:`~skfem_affine.SimulationDiverged` ends the run early: the summary
    then has ``status="diverged"`` and the frames done so far are kept.
    """
    method = get_method(method)
    tau_a, tau_e = _taus(method, tau_a, tau_e)
    sim = spec.build(reducer=method.reducer(tau_a, tau_e))
    frames = default_frames(sim, frames)
    if reference is not None and reference.frames < frames:
        raise ValueError(f"the reference has {reference.frames} frames, fewer than the {frames} asked for")
    measure = reference is not None and sim.reducer is not None and (step_error or residual)
    evaluator = spec.build() if measure else None
    main = _Stepped(method.name, sim, reference.x if reference is not None else None,
                    reference.size if reference is not None else None, trajectory=measure,
                    keep_every=keep_every, keep_frames=keep_frames, frames=frames, on_state=on_state)
    stepped = [main]
    twin = _Stepped("full twin", spec.build(), strain=False, required=True) if paired_timing else None
    if twin is not None:
        stepped.append(twin)
    bar = _bar(frames, f"{spec.label} {method.name}", progress)
    try:
        _step_in_turn(stepped, frames, bar)
    finally:
        bar.close()
    if twin is not None and twin.status != "ok":
        main.status, main.message = "diverged", f"the full-space twin diverged ({twin.message})"
    _measure_after(main, reference, evaluator, step_error, residual)
    summary = _summary(spec, method, tau_a, tau_e, main, reference, "reference")
    if twin is not None and main.records:
        for rec, full in zip(main.records, twin.records):
            rec["full_wall"] = full["wall"]
        n = min(len(main.records), len(twin.records))
        summary.update(speedup=metrics.speedup(metrics.column(twin.records[:n], "wall").sum(),
                                               metrics.column(main.records[:n], "wall").sum()),
                       timing="paired")
    return Run(method.name, summary, main.records, main.kept, sim)


def _as_reference(s):
    """The :class:`Reference` of a finished full-space run (its positions were collected)."""
    if s.status != "ok":
        raise SimulationDiverged(len(s.records) + 1, f"the full-space reference diverged ({s.message})")
    sim, records = s.sim, s.records
    strain0 = sim.system.strain_energy(s.positions[0])
    stress0 = metrics.largest_stress(metrics.cauchy_stress(sim.system, s.positions[0]))
    x = np.array(s.positions)
    ref = Reference(x, np.concatenate([[strain0], metrics.column(records, "strain_energy")]),
                    metrics.column(records, "wall"), metrics.column(records, "dofs"), sim.size,
                    metrics.response_amplitude(x, sim.system.p0),
                    np.concatenate([[stress0], metrics.column(records, "max_stress")]))
    for rec in records:  # the reference measured against itself
        rec.update(distance_error=0.0, distance_m=0.0, response_error=0.0, energy_error=0.0, stress_error=0.0)
    return ref


def reference_run(spec, frames=None, progress=False, keep_every=0, keep_frames=(), on_state=None):
    """The full-space run of ``spec``: its :class:`Reference` and its measured :class:`Run`.

    Raises :class:`~skfem_affine.SimulationDiverged` if the reference itself diverges.
    """
    sim = spec.build()
    frames = default_frames(sim, frames)
    s = _Stepped("full", sim, keep_every=keep_every, keep_frames=keep_frames, frames=frames, positions=[],
                 on_state=on_state, required=True)
    bar = _bar(frames, f"{spec.label} full", progress)
    try:
        _step_in_turn([s], frames, bar)
    finally:
        bar.close()
    ref = _as_reference(s)
    summary = _summary(spec, get_method("full"), None, None, s, ref, "reference")
    return ref, Run("full", summary, s.records, s.kept, sim)


def interleaved(sims, frames, on_frame=None, progress=False):
    """Step several simulations frame by frame in turn, in this process; a :class:`Run` each.

    The way to measure ratios of wall times (speedups): frame 1 of every simulation, then
    frame 2, ..., so that load from elsewhere on a shared machine hits all alike.

    Parameters
    ----------
    sims : dict
        Name -> :class:`~skfem_affine.Simulation` (the first is the one the others are
        compared with: ``speedup`` and ``dof_ratio`` in the summaries are over it).
    frames : int
    on_frame : callable(frame, sims), optional
        Called after every frame with the simulations still running (name -> Simulation),
        e.g. to measure an error against the first one.

    Returns
    -------
    dict
        Name -> :class:`Run`: ``records`` holds each frame's stats (``wall`` is the time of
        ``Simulation.step``), ``summary`` the totals (``frames``, ``wall_s``, ``speedup``,
        ``dof_ratio``, ``mean_clusters``, phase times, ``status``, ``message``), ``sim`` the
        simulation. A simulation that diverges stops (``status="diverged"``); the others go on.
    """
    if not isinstance(sims, dict) or not sims:
        raise TypeError(f"sims must be a non-empty dict of name -> Simulation, got {type(sims).__name__}")
    for name, sim in sims.items():
        if not hasattr(sim, "step") or not hasattr(sim, "stats"):
            raise TypeError(f"sims[{name!r}] is {type(sim).__name__}, not a Simulation")
    frames = integer(frames, "frames", low=0)
    stepped = [_Stepped(name, sim, strain=False) for name, sim in sims.items()]
    bar = _bar(frames, "interleaved", progress)
    try:
        _step_in_turn(stepped, frames, bar, on_frame)
    finally:
        bar.close()
    first = stepped[0]
    out = {}
    for s in stepped:
        n = len(s.records)
        base = _Totals(metrics.column(first.records, "wall"), metrics.column(first.records, "dofs"))
        summary = {"method": s.name, **metrics.summarise(s.records, base if len(first.records) >= n else None),
                   "timing": "interleaved", "status": s.status, "message": s.message}
        out[s.name] = Run(s.name, summary, s.records, [], s.sim)
    return out


@dataclass
class _Totals:
    """Per-frame wall and DOFs of the run others are compared with (what ``metrics.summarise`` reads)."""

    wall: np.ndarray
    dofs: np.ndarray


def warm_up(spec, methods=("full",), frames=2):
    """Run each method a couple of frames so that one-off costs (loading compiled kernels,
    solver libraries) are not in the timed runs. Returns nothing."""
    for name in methods:
        sim = spec.build(reducer=get_method(name).reducer())
        for _ in sim.run(frames):
            pass


def compare(spec, frames=None, methods=COMPARED, taus=None, step_error=True, residual=True, keep_every=10,
            keep_frames=(), progress=False, timing="interleaved", on_state=None, warm=True):
    """Run the full-space reference and each method on one scene (paper Table 1, Fig. 1, 12).

    Parameters
    ----------
    taus : dict, optional
        Method name -> (tau_a, tau_e) (default: the method's own; None entries too).
    timing : {"interleaved", "sequential"}
        "interleaved" (default) steps the reference and every method frame by frame in
        turn in this process, so that their wall times are taken under the same load and
        two runs agree on the speedup; "sequential" runs the reference, then each method.
        Interleaved, every measured method keeps its trajectory until the end (for the step
        error and residual): memory grows with the methods.
    on_state : dict, optional
        Method name -> callable(sim, state), called with the initial state and after every
        frame of that method (e.g. a ParaView writer).
    warm : bool
        First run each method a couple of frames (:func:`warm_up`).

    Notes
    -----
    Returns ``(reference, {name: Run})``; the "full" Run is the reference.
    """
    if timing not in ("interleaved", "sequential"):
        raise ValueError(f"timing must be 'interleaved' or 'sequential', got {timing!r}")
    taus, on_state = dict(taus or {}), dict(on_state or {})
    names = list(dict.fromkeys(["full"] + [get_method(m).name for m in methods]))
    methods = {get_method(m).name: get_method(m) for m in methods}
    methods.setdefault("full", get_method("full"))
    if warm:
        warm_up(spec, tuple(methods.values()))
    if timing == "sequential":
        return _compare_sequential(spec, frames, names, methods, taus, step_error, residual, keep_every,
                                   keep_frames, progress, on_state)
    full_sim = spec.build()
    frames = default_frames(full_sim, frames)
    full = _Stepped("full", full_sim, keep_every=keep_every, keep_frames=keep_frames, frames=frames, positions=[],
                    on_state=on_state.get("full"), required=True)
    stepped, setup, evaluators = [full], {}, {}
    for name in names[1:]:
        tau_a, tau_e = _taus(methods[name], *taus.get(name, (None, None)))
        sim = spec.build(reducer=methods[name].reducer(tau_a, tau_e))
        measure = sim.reducer is not None and (step_error or residual)
        evaluators[name] = spec.build() if measure else None
        setup[name] = (tau_a, tau_e)
        stepped.append(_Stepped(name, sim, full.positions, full_sim.size, trajectory=measure, keep_every=keep_every,
                                keep_frames=keep_frames, frames=frames, on_state=on_state.get(name)))
    bar = _bar(frames, f"{spec.label} {', '.join(names)}", progress)
    try:
        _step_in_turn(stepped, frames, bar)
    finally:
        bar.close()
    ref = _as_reference(full)
    results = {"full": Run("full", _summary(spec, methods["full"], None, None, full, ref, "interleaved"),
                           full.records, full.kept, full_sim)}
    for s in stepped[1:]:
        _measure_after(s, ref, evaluators[s.name], step_error, residual)
        summary = _summary(spec, methods[s.name], *setup[s.name], s, ref, "interleaved")
        results[s.name] = Run(s.name, summary, s.records, s.kept, s.sim)
    return ref, results


def _compare_sequential(spec, frames, names, methods, taus, step_error, residual, keep_every, keep_frames,
                        progress, on_state):
    ref, full = reference_run(spec, frames, progress, keep_every, keep_frames, on_state.get("full"))
    results = {"full": full}
    for name in names[1:]:
        results[name] = run(spec, methods[name], ref.frames, *taus.get(name, (None, None)), reference=ref,
                            step_error=step_error, residual=residual, keep_every=keep_every,
                            keep_frames=keep_frames, progress=progress, on_state=on_state.get(name))
    for r in results.values():
        r.summary["timing"] = "sequential"
    return ref, results


def _bar(total, desc, enabled):
    """Progress on stderr when ``enabled`` (:func:`skfem_affine.lab.progress.bar`), in frames or cells."""
    return progress_bar(total, desc, enabled, unit="cell" if "cell" in desc else "frame")
