r"""Error and cost metrics of a reduced run against a full-space reference (paper sec. 4.1, Fig. 6).

Per frame t, with x the reduced run's vertex positions, x^ref the full-space
reference started from the same initial state, X the rest pose, L the scene's size (diagonal of
its rest bounding box), R the reference's response (its largest displacement from rest over the
run, ``max_s max_i ||x^ref_i(s) - X_i||``) and h the time step:

- distance error: ``max_i ||x_i(t) - x^ref_i(t)|| / L`` (Fig. 6, "distance error"), the same
  distance in metres (``distance_m``) and relative to the response,
  ``max_i ||x_i(t) - x^ref_i(t)|| / R`` (``response_error``: what an engineer reads as "1 %");
- step distance error: the same, with the reference re-started from the reduced
  state at t - 1 for one step, which discounts phase drift (Fig. 6, "step distance error");
- residual: ``||A dv - b|| / ||b||``, the full-space system (eq. 1-2) at the
  reduced run's state t - 1 applied to the velocity change it took (Fig. 6, "residual error");
- energy error: ``|Psi(x(t)) - Psi(x^ref(t))| / max_s Psi(x^ref(s))`` (Fig. 6, "strain energy");
- stress error: ``max_e ||sigma_e(t) - sigma^ref_e(t)|| / max_{s,e} ||sigma^ref_e(s)||``, the
  per-element Cauchy stresses (Frobenius norms), relative to the reference's largest stress;

and over a run:

- DOF ratio: ``sum_t dofs(t) / sum_t dofs^ref(t)`` (Fig. 6, "DOFs ratio");
- mean clusters: ``mean_t n_clusters(t)`` (Fig. 6);
- speedup: ``sum_t wall^ref(t) / sum_t wall(t)``; per frame ``wall^ref(t) / wall(t)`` (Fig. 1, Table 1);
- per-phase wall time, summed over frames (Fig. 12).

Each function takes plain arrays or per-frame record lists (``sim.stats``) and
is tested against a hand-computed case in ``tests/test_metrics.py``.
"""
import numpy as np

from skfem_affine import stress
from skfem_affine.reducers.budget import largest_displacement
from skfem_affine.simulation import State, Stats


def distance_error(x, x_ref, size):
    """Largest vertex distance ``||x_i - x_ref_i||`` (Euclidean, (n, 3) arrays) divided by ``size``."""
    x, x_ref = np.asarray(x, float), np.asarray(x_ref, float)
    if x.shape != x_ref.shape:
        raise ValueError(f"positions of shape {x.shape} cannot be compared with a reference of shape {x_ref.shape}")
    if not size > 0:
        raise ValueError(f"size must be > 0, got {size}")
    return float(np.sqrt(np.max(np.einsum("ij,ij->i", x - x_ref, x - x_ref)))) / size if x.size else 0.0


def distance_m(x, x_ref):
    """Largest vertex distance ``||x_i - x_ref_i||`` in metres."""
    return distance_error(x, x_ref, 1.0)


def response_amplitude(positions, rest):
    """R: the largest displacement ``||x_i - X_i||`` from the rest pose ``rest`` (n, 3) over the
    frames of ``positions`` ((frames, n, 3) or (n, 3)), in metres (the measure the reducers' error
    budgets use online, :func:`skfem_affine.reducers.budget.largest_displacement`)."""
    return largest_displacement(positions, rest)


def relative(error_m, scale):
    """An error in metres over a scale (m); None when the scale is 0 (nothing moved)."""
    return None if error_m is None or not scale > 0 else float(error_m) / float(scale)


def cauchy_stress(system, x):
    """Per-element Cauchy stress sigma = P F^T / det F (m, 3, 3) of ``system`` at positions x (n, 3)
    (:func:`skfem_affine.stress.evaluate`; NaN on inverted elements)."""
    return stress.evaluate(system, np.asarray(x, float)).cauchy


def stress_error(sigma, sigma_ref, scale):
    """``max_e ||sigma_e - sigma_ref_e|| / scale`` of per-element stresses (m, 3, 3) (Frobenius
    norms); ``scale`` is the reference's largest stress norm (0: the error in Pa)."""
    d = np.asarray(sigma, float) - np.asarray(sigma_ref, float)
    worst = float(np.sqrt(np.nanmax(np.einsum("eij,eij->e", d, d)))) if d.size else 0.0
    return worst / scale if scale > 0 else worst


def largest_stress(sigma):
    """max_e ||sigma_e|| (Frobenius) of per-element stresses (m, 3, 3)."""
    s = np.asarray(sigma, float)
    return float(np.sqrt(np.nanmax(np.einsum("eij,eij->e", s, s)))) if s.size else 0.0


def reference_step(evaluator, state):
    """One full-space step of ``evaluator`` (a reducer-free Simulation) re-started from ``state``.

    Returns the new :class:`~skfem_affine.State`. The step distance error of
    frame t is ``distance_error(x(t), reference_step(evaluator, state(t-1)).x, size)``.
    """
    if evaluator.reducer is not None:
        raise ValueError("the step reference must be a full-space Simulation (reducer=None)")
    evaluator.state = State(state.x.copy(), state.v.copy(), state.frame, state.time)
    return evaluator.step()


def residual_norm(A, dv, b):
    """``||A dv - b|| / ||b||`` (``||A dv||`` when b = 0): the part of the system the step did not resolve."""
    r = A @ dv - b
    nb = float(np.linalg.norm(b))
    return float(np.linalg.norm(r)) / nb if nb > 0 else float(np.linalg.norm(r))


def full_space_residual(evaluator, before, after):
    """Residual (eq. 1-2 in full space) of the step that took ``before`` to ``after``.

    A and b are assembled by the reducer-free ``evaluator`` at ``before``; the
    step's velocity change is taken on the free DOFs. A full-space step gives
    the linear solver's tolerance; a reduced step gives what its subspace
    (affine or rigid bodies) cannot represent.
    """
    A, b, _ = evaluator.linear_system(before.x, before.v)
    free = evaluator.system.free
    dv = (after.v - before.v).reshape(-1)[free]
    return residual_norm(A, dv, b)


def energy_error(strain, strain_ref, scale):
    """``|Psi - Psi_ref| / scale`` per frame; ``scale`` is the reference's largest strain energy."""
    strain, strain_ref = np.asarray(strain, float), np.asarray(strain_ref, float)
    if not scale > 0:
        return np.abs(strain - strain_ref)
    return np.abs(strain - strain_ref) / scale


def dof_ratio(dofs, dofs_ref):
    """DOFs solved summed over frames, over the reference's (1 for full space)."""
    return float(np.sum(dofs)) / float(np.sum(dofs_ref))


def mean_clusters(records):
    """Mean number of reduced bodies per frame (0 for full space)."""
    return float(np.mean([r.get("n_clusters", 0) for r in records])) if len(records) else 0.0


def speedup(wall_ref, wall):
    """Reference wall time over reduced wall time (scalars or per-frame arrays)."""
    return np.asarray(wall_ref, float) / np.asarray(wall, float) if np.ndim(wall) else float(wall_ref) / float(wall)


def phase_times(records):
    """Wall time (s) of each phase of :class:`~skfem_affine.Stats`, summed over frames."""
    return Stats(records).phase_totals()


def column(records, key, default=np.nan):
    """One per-frame value of every record as an array (``default`` where missing)."""
    return np.array([r.get(key, default) for r in records], dtype=float)


def _max(values):
    values = np.asarray(values, float)
    values = values[np.isfinite(values)]
    return float(values.max()) if values.size else None


def summarise(records, reference=None):
    """Run summary from per-frame records (``sim.stats`` plus the metric columns).

    With a :class:`~skfem_affine.runners.Reference` (or anything with ``wall``
    and ``dofs`` per frame), speedup and DOF ratio are over the same frames.
    Missing metrics are None.
    """
    n = len(records)
    wall = column(records, "wall")
    out = {"frames": n, "wall_s": float(wall.sum()),
           "speedup": None, "dof_ratio": None, "mean_clusters": mean_clusters(records),
           "max_distance_error": _max(column(records, "distance_error")),
           "max_response_error": _max(column(records, "response_error")),
           "max_distance_m": _max(column(records, "distance_m")),
           "max_stress_error": _max(column(records, "stress_error")),
           "max_step_error": _max(column(records, "step_error")),
           "max_residual": _max(column(records, "residual")),
           "max_energy_error": _max(column(records, "energy_error"))}
    if reference is not None and n:
        out["speedup"] = speedup(float(np.sum(reference.wall[:n])), out["wall_s"])
        out["dof_ratio"] = dof_ratio(column(records, "dofs"), reference.dofs[:n])
    out.update({f"{k}_s": v for k, v in phase_times(records).items()})
    return out
