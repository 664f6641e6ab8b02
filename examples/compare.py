r"""Measuring the trade: speedup, error and a picture
=================================================

One scene three ways, with speedup, error and a picture.

Affinification trades accuracy for speed through two thresholds on deformation
rates (1/s): tau_a, below which elastic elements merge into affine bodies, and
tau_e, below which affine elements stay affine. This tutorial measures that
trade on the cantilever the way the paper's evaluation does (sec. 4.1):

1. a *scene* is named by :class:`~skfem_affine.lab.runners.SceneSpec` (a name in
   ``sa.scenes.SCENES`` with keyword overrides, or a user's ``.py`` file);
2. :func:`~skfem_affine.lab.runners.compare` runs the full-space reference and
   each *method* (a name and a reducer factory, ``runners.METHODS``) from the
   same initial state, frame by frame in turn in one process, so that load from
   elsewhere on the machine slows every method alike;
3. every frame is measured (:mod:`skfem_affine.lab.metrics`): the largest vertex
   distance to the reference over the response (the reference's largest
   displacement from rest), over the scene size and in metres, the largest
   element stress difference over the largest stress, the distance after re-starting
   the reference from the reduced state (step error, which discounts phase
   drift), the full-space residual :math:`\|A\Delta v - b\|/\|b\|` of eq. 1-2,
   the strain-energy difference, DOFs, bodies and the wall time of each phase;
4. the summary gives speedup = full wall time / method wall time and the DOF
   ratio = DOFs solved / full space's, over the same frames.

At this tiny size the reduced solve is not yet cheaper than the full one: the
speedup grows with the number of elements (``skfem-affine scaling``). The same
run from the shell, with plots, a picture of the clusters and ParaView output::

    skfem-affine compare cantilever --resolution 2 --frames 60 --tau-a 0.3 --tau-e 0.6
"""
import skfem_affine as sa
from skfem_affine.lab import runners

# 192 tets; the soft, undamped beam (E = 1e5) the thresholds below were chosen on
spec = runners.SceneSpec.make("cantilever", resolution=2, E=1e5, damping=sa.Rayleigh())
reference, runs = runners.compare(spec, frames=60, taus={"affinification": (0.3, 0.6)}, keep_every=10)
summary = {name: run.summary for name, run in runs.items()}

if __name__ == "__main__":
    import os

    from skfem_affine.lab import plots

    print(f"{'method':>15} {'speedup':>8} {'DOF ratio':>9} {'bodies':>7} {'max error':>9} {'step error':>10}")
    for name, s in summary.items():
        step = "-" if s["max_step_error"] is None else f"{s['max_step_error']:.1e}"
        print(f"{name:>15} {s['speedup']:8.2f} {s['dof_ratio']:9.2f} {s['mean_clusters']:7.1f} "
              f"{s['max_distance_error']:9.1e} {step:>10}")
    paths = plots.compare_plots(runs, os.path.join("out", "compare", "cantilever"))
    for path in paths:
        print("wrote", path)  # where `skfem-affine compare cantilever` writes its plots too

    import matplotlib.pyplot as plt

    for path in paths[:1] + paths[-1:]:          # the speedup per frame and the clusters picture
        image = plt.imread(path)
        fig, ax = plt.subplots(figsize=(image.shape[1] / 120, image.shape[0] / 120))
        ax.imshow(image)
