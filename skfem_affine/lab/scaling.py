"""The same scene at increasing size (paper Table 2): full and reduced wall time, speedup, error.

Sizes are values of the scene's ``resolution`` or mesh files (``meshes``, e.g. the paper's
beams for :func:`~skfem_affine.lab.scenes.paper_beam`). Several threshold pairs may run in the
same process, interleaved with the full solve; with ``target_error`` the fastest pair whose
error meets it is marked ``chosen`` at each size ("the speedup at that error").
"""
import inspect
import os

import numpy as np

from skfem_affine.checks import integer, real
from skfem_affine.integrators.problem import PHASES
from skfem_affine.lab.methods import Method, get_method
from skfem_affine.lab.runs import compare, warm_up

#: The paper's Table 2 (the cantilever beam at increasing resolution, Neo-Hookean): elements -> speedup.
PAPER_TABLE2 = {3803: 1.64, 5516: 1.84, 10416: 3.23, 25843: 4.64, 83639: 6.25, 244548: 9.08, 642400: 13.81}
#: The paper's Table 1 "Beam" (5516 tets, 370 frames): material -> speedup.
PAPER_TABLE1_BEAM = {"neohookean": 1.85, "stvk": 1.88, "corotational": 4.58}


def paper_speedup(elements, material=None, tolerance=0.02):
    """The paper's speedup at this size: ``(value, "Table 1")``, ``(value, "Table 2")`` or ``(None, None)``.

    Table 1 where it lists the material at 5516 tets; otherwise Table 2's entry whose element
    count is within ``tolerance`` (relative) of ``elements``.
    """
    elements = integer(elements, "elements", low=0)
    if elements == 5516 and material in PAPER_TABLE1_BEAM:
        return PAPER_TABLE1_BEAM[material], "Table 1"
    for m, value in PAPER_TABLE2.items():
        if abs(elements - m) <= tolerance * m:
            return value, "Table 2"
    return None, None


def _material_name(sim):
    """The name of the scene's material when all its elements share one kind ("neohookean", ...), else None."""
    names = {getattr(m, "name", None) for m in getattr(sim.system, "material_list", ())}
    return names.pop() if len(names) == 1 else None


def _pairs(method, taus):
    """One :class:`Method` per threshold pair (named ``"affinification 0.1,0.2"`` when several)."""
    base = get_method(method)
    if taus is None:
        return [(base, base.taus)]
    # a missing threshold is the method's own
    pairs = [(base.taus[0] if a is None else real(a, "taus", low=0.0), base.taus[1] if e is None else real(e, "taus", low=0.0))
             for a, e in taus]
    if not pairs:
        raise ValueError("taus must hold at least one (tau_a, tau_e) pair")
    if len(pairs) == 1:
        return [(Method(base.name, base.factory, pairs[0]), pairs[0])]
    return [(Method(f"{base.name} {a:g},{e:g}", base.factory, (a, e)), (a, e)) for a, e in pairs]


def _phases_ms(summary, frames):
    """Mean milliseconds per frame of each phase the run recorded: ``{"assembly_ms": ..., ...}``."""
    return {f"{p}_ms": 1e3 * summary[f"{p}_s"] / max(frames, 1) for p in PHASES if f"{p}_s" in summary}


def _warm(spec, methods):
    """Run every method a couple of frames on the smallest version of the scene (kernels, solver libraries)."""
    params = inspect.signature(spec.factory()).parameters
    small = spec.with_kwargs(resolution=1, mesh=None) if "resolution" in params else spec
    warm_up(small, tuple(methods))


def scaling(spec, resolutions=None, frames=100, method="affinification", tau_a=None, tau_e=None, step_error=False,
            residual=False, progress=False, timing="interleaved", meshes=None, taus=None, target_error=None):
    """One row per size and threshold pair: elements, both wall times, speedup, errors, DOF ratio, bodies.

    Parameters
    ----------
    spec : SceneSpec
    resolutions : list of int, optional
        Values of the scene's ``resolution`` (one size each); or give ``meshes``.
    frames : int or list of int
        One number, or one per size (large meshes may take fewer).
    meshes : list of str, optional
        Mesh files passed as the scene's ``mesh=`` (one size each), instead of ``resolutions``.
    taus : list of (tau_a, tau_e), optional
        Threshold pairs of ``method``, all stepped in one process with the full solve at each
        size (default: ``(tau_a, tau_e)``, None for the method's own).
    target_error : float, optional
        Mark ``chosen`` at each size the fastest pair whose ``length_error`` (largest vertex
        distance to the full solve over the run / the scene's longest side) is at most this.

    Notes
    -----
    Every method at a size is timed as in :func:`compare` (``timing``: interleaved frame by
    frame by default). Rows carry ``paper`` and ``paper_table`` (:func:`paper_speedup`),
    ``max_distance_error`` (over the bounding box diagonal, the package's scene size) and
    ``length_error`` (over the longest side), ``chosen``, and the mean milliseconds per frame of
    the method's and the full solve's whole step (``wall_ms``, ``full_wall_ms``) and of each phase
    they recorded (``assembly_ms``, ..., ``full_assembly_ms``, ...).
    """
    if (resolutions is None) == (meshes is None):
        raise ValueError("give either resolutions or meshes")
    if meshes is not None:
        meshes = [os.fspath(m) for m in meshes]
        for m in meshes:
            if not os.path.isfile(m):
                raise ValueError(f"meshes: {m!r} is not a file (give the path of a mesh file, e.g. beam1264.mesh)")
        sizes = [("mesh", m) for m in meshes]
    else:
        sizes = [("resolution", integer(k, "resolutions", low=1)) for k in resolutions]
    frames = [frames] * len(sizes) if np.ndim(frames) == 0 else list(frames)
    if len(frames) != len(sizes):
        raise ValueError(f"give one frame count, or one per {sizes[0][0] if sizes else 'size'} ({len(sizes)}), "
                         f"got {len(frames)}")
    frames = [integer(f, "frames", low=1) for f in frames]
    if target_error is not None:
        target_error = real(target_error, "target_error", low=0.0, include_low=False)
    pairs = _pairs(method, taus if taus is not None else ([(tau_a, tau_e)] if (tau_a, tau_e) != (None, None)
                                                           else None))
    _warm(spec, ["full"] + [m for m, _ in pairs])
    rows = []
    for (key, value), f in zip(sizes, frames):
        s = spec.with_kwargs(**{key: value})
        ref, runs = compare(s, f, [m for m, _ in pairs], step_error=step_error, residual=residual,
                            keep_every=0, progress=progress, timing=timing, warm=False)
        full_sim = runs["full"].sim
        extent = float(np.ptp(np.asarray(full_sim.system.p0).reshape(-1, 3), axis=0).max())
        material = _material_name(full_sim)
        paper, table = paper_speedup(full_sim.system.m, material)
        full = runs["full"].summary
        at_size = []
        for m, (a, e) in pairs:
            rs = runs[m.name].summary
            err = rs["max_distance_error"]
            at_size.append({"scene": s.label, "resolution": value if key == "resolution" else None,
                            "mesh": os.path.basename(value) if key == "mesh" else None,
                            "elements": rs["elements"], "vertices": rs["vertices"], "material": material,
                            "frames": ref.frames, "method": get_method(method).name, "tau_a": rs["tau_a"],
                            "tau_e": rs["tau_e"], "time_full_s": full["wall_s"], "time_reduced_s": rs["wall_s"],
                            "speedup": rs["speedup"], "max_distance_error": err,
                            "length_error": None if err is None else err * full_sim.size / extent,
                            "dof_ratio": rs["dof_ratio"], "mean_clusters": rs["mean_clusters"],
                            "paper": paper, "paper_table": table, "status": rs["status"], "timing": rs["timing"],
                            "target_error": target_error, "chosen": False, "wall_ms": 1e3 * rs["wall_s"] / ref.frames,
                            **_phases_ms(rs, ref.frames), "full_wall_ms": 1e3 * full["wall_s"] / ref.frames,
                            **{f"full_{k}": v for k, v in _phases_ms(full, ref.frames).items()}})
        if target_error is not None:
            ok = [r for r in at_size if r["status"] == "ok" and r["length_error"] is not None
                  and r["length_error"] <= target_error and r["speedup"] is not None]
            if ok:
                max(ok, key=lambda r: r["speedup"])["chosen"] = True
        rows.extend(at_size)
    return rows
