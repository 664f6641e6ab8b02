"""The trade as points: speedup against max distance error, per threshold pair or per error budget.

:func:`budget_runs` runs a reducer at several error budgets, interleaved frame by frame with the
full-space run (:func:`~skfem_affine.lab.runs.interleaved`), and measures each against it;
:func:`points_from_rows` and :func:`points_from_runs` turn sweep rows and compare runs into the
points of :func:`~skfem_affine.lab.plots.trade_plot`.
"""
import numpy as np

from skfem_affine.lab import metrics
from skfem_affine.lab.runs import interleaved, warm_up
from skfem_affine.lab.scene_spec import default_frames
from skfem_affine.reducers.affine.affinification import Affinification
from skfem_affine.reducers.affine.rigidification import Rigidification

#: The reducers :func:`budget_runs` runs at error budgets, by the name ``method`` takes.
REDUCERS = {"affinification": Affinification, "rigidification": Rigidification}


def _label(tau_a, tau_e):
    return f"{tau_a:.3g}, {tau_e:.3g}"


def points_from_rows(rows):
    """Trade points of sweep rows (one per finished cell), labelled with their thresholds."""
    return [{"error": r.get("max_distance_error"), "speedup": r.get("speedup"), "method": r.get("method"),
             "label": _label(float(r["tau_a"]), float(r["tau_e"]))}
            for r in rows if r.get("status") == "ok"]


#: The summary entry of each unit's error (``points_from_runs``).
SUMMARY_ERROR = {"size": "max_distance_error", "response": "max_response_error", "metre": "max_distance_m"}


def points_from_runs(runs, unit="size"):
    """Trade points of compare runs (the full-space reference left out), labelled with their settings;
    the error in ``unit`` ("size", "response" or "metre")."""
    out = []
    for name, run in runs.items():
        s = run.summary
        if name == "full" or s.get("status") != "ok":
            continue
        if s.get("tau_a") is not None:
            label = f"{name} {_label(float(s['tau_a']), float(s['tau_e']))}"
        else:
            target = getattr(run.sim.reducer, "target_error", None)
            label = _budget_label(target, run.sim.reducer.relative_to, name) if target is not None else name
        out.append({"error": s.get(SUMMARY_ERROR[unit]), "speedup": s.get("speedup"), "method": name,
                    "label": label.strip()})
    return out


def budget_runs(spec, budgets, frames=None, method="affinification", warm=True, progress=False, **options):
    """The reducer at each error budget, interleaved with the full-space run of ``spec``.

    Parameters
    ----------
    budgets : sequence of float
        Error budgets (``target_error``).
    method : {"affinification", "rigidification"}
    options
        Passed to the reducer (e.g. ``never_slower=False``).

    Returns
    -------
    list of dict
        Per budget: ``budget``, ``relative_to`` (its unit), ``error`` (measured max distance
        error in the budget's unit), ``error_response`` (over the full-space run's response, its
        largest displacement from rest ``response_m``), ``error_size`` (over the scene size),
        ``error_m`` (metres), ``speedup`` (interleaved
        wall-time ratio), ``dof_ratio``, ``reduced_frames`` (fraction of frames that returned the
        reduced solution), ``max_estimated_error``, ``mean_tau_a``, ``status`` ("ok", "diverged", or
        "over-budget" when ``error`` is over ``budget``).
    """
    if method not in REDUCERS:
        raise ValueError(f"method must be one of {sorted(REDUCERS)}, got {method!r}")
    budgets = [float(b) for b in budgets]
    if not budgets:
        raise ValueError("give at least one error budget")
    if warm:
        warm_up(spec, ("full",))
    sims = {"full": spec.build()}
    for b in budgets:
        sims[f"budget {b:g}"] = spec.build(reducer=REDUCERS[method](target_error=b, **options))
    frames = default_frames(sims["full"], frames)
    full, size = sims["full"], sims["full"].size
    errors = {name: 0.0 for name in sims}  # metres
    response = [metrics.response_amplitude(full.state.x, full.system.p0)]

    def on_frame(frame, running):
        if "full" not in running:
            return
        response[0] = max(response[0], metrics.response_amplitude(full.state.x, full.system.p0))
        for name, sim in running.items():
            if name != "full":
                errors[name] = max(errors[name], metrics.distance_m(sim.state.x, full.state.x))

    runs = interleaved(sims, frames, on_frame=on_frame, progress=progress)
    rows = []
    for b in budgets:
        run = runs[f"budget {b:g}"]
        recs = run.records
        unit = run.sim.reducer.relative_to
        err = errors[f"budget {b:g}"]
        by_unit = {"response": metrics.relative(err, response[0]), "size": err / size, "metre": err}
        status = run.summary["status"]
        if status == "ok" and by_unit[unit] > b:
            status = "over-budget"
        rows.append({"scene": spec.label, "method": method, "budget": b, "relative_to": unit, "error": by_unit[unit],
                     "error_response": by_unit["response"], "error_size": by_unit["size"], "error_m": err,
                     "response_m": response[0], "size_m": size,
                     "speedup": run.summary.get("speedup"), "dof_ratio": run.summary.get("dof_ratio"),
                     "reduced_frames": float(np.mean([bool(r.get("reduced")) for r in recs])) if recs else 0.0,
                     "max_estimated_error": float(max((r.get("estimated_error", 0.0) for r in recs), default=0.0)),
                     "mean_tau_a": float(np.mean([r.get("tau_a", np.nan) for r in recs])) if recs else None,
                     "frames": len(recs), "elements": int(full.system.m), "status": status,
                     "timing": "interleaved"})
    return rows


def budget_points(rows):
    """Trade points of :func:`budget_runs` rows, each with its budget marked beside it."""
    return [{"error": r["error"], "speedup": r["speedup"], "method": r["method"], "budget": r["budget"],
             "label": _budget_label(r["budget"], r.get("relative_to", "size"))}
            for r in rows if r["status"] in ("ok", "over-budget")]


def _budget_label(budget, unit, name=""):
    """``name, budget 1 %`` (of the response or the size), ``budget 0.002 m`` for a budget in metres."""
    text = f"budget {budget:g} m" if unit == "metre" else f"budget {100 * budget:g} %"
    return f"{name}, {text}" if name else text
