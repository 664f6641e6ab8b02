"""The same scene at increasing resolution (paper Table 2): full and reduced wall time, speedup, error."""
import numpy as np

from skfem_affine.checks import integer
from skfem_affine.lab.methods import get_method
from skfem_affine.lab.runs import compare


def scaling(spec, resolutions, frames, method="affinification", tau_a=None, tau_e=None, step_error=False,
            residual=False, progress=False, timing="interleaved"):
    """One row per ``resolution``: elements, both wall times, speedup, error, DOF ratio, bodies.

    ``frames`` is one number or one per resolution (large meshes may take fewer). At each
    resolution the full-space reference and the method are timed as in :func:`compare`
    (``timing``: interleaved frame by frame by default).
    """
    resolutions = [integer(k, "resolutions", low=1) for k in resolutions]
    frames = [frames] * len(resolutions) if np.ndim(frames) == 0 else list(frames)
    if len(frames) != len(resolutions):
        raise ValueError(f"give one frame count, or one per resolution ({len(resolutions)}), got {len(frames)}")
    name = get_method(method).name
    rows = []
    for i, (k, f) in enumerate(zip(resolutions, frames)):
        s = spec.with_kwargs(resolution=k)
        ref, runs = compare(s, f, ("full", method), {name: (tau_a, tau_e)}, step_error=step_error,
                            residual=residual, keep_every=0, progress=progress, timing=timing, warm=i == 0)
        full, rs = runs["full"].summary, runs[name].summary
        rows.append({"scene": s.label, "resolution": k, "elements": rs["elements"], "vertices": rs["vertices"],
                     "frames": ref.frames, "method": rs["method"], "tau_a": rs["tau_a"], "tau_e": rs["tau_e"],
                     "time_full_s": full["wall_s"], "time_reduced_s": rs["wall_s"],
                     "speedup": rs["speedup"], "max_distance_error": rs["max_distance_error"],
                     "dof_ratio": rs["dof_ratio"], "mean_clusters": rs["mean_clusters"], "status": rs["status"],
                     "timing": rs["timing"]})
    return rows
