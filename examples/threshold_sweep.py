r"""Choosing the trade: a small threshold sweep
============================================

Affinification's two thresholds are deformation rates (1/s): ``tau_a`` (an
elastic element may join an affine body) and ``tau_e`` (an affine element stays
affine). Larger values merge more, solve fewer DOFs, run faster on large meshes
and cost accuracy; the useful range depends on how fast the scene moves, so it is
chosen by measuring. This tutorial runs the full-space reference once and then
affinification at four thresholds on the diagonal ``tau_e = 2 tau_a`` (the paper
recommends ``tau_e`` above ``tau_a``, within a decade), and draws the picture to
choose from: error against DOFs solved, and speedup.

It uses the building blocks of :mod:`skfem_affine.lab.runners`:
``SceneSpec`` names a scene, ``reference_run`` runs full space once, and ``run``
measures one method against that reference. For a whole ``tau_a x tau_e`` grid,
in parallel on Dask and resumable, use ``runners.sweep`` or the command line::

    skfem-affine sweep cantilever --resolution 6 --frames 100 --grid 9 --tau-range 1e-3 1

At this tutorial's tiny size (192 tets) the reduced solve is not yet cheaper than
the full one, so the speedups stay below 1: the DOFs and the error show the
trade; speed pays off from tens of thousands of elements (see the user guide's
measured tables).
"""
import numpy as np

from skfem_affine.lab import runners

spec = runners.SceneSpec.make("cantilever", resolution=2)
frames = 60
runners.warm_up(spec, ("full", "affinification"))   # compile and load once, outside the timings
reference, full = runners.reference_run(spec, frames)

taus = [0.003, 0.01, 0.03, 0.1]
rows = []
for tau_a in taus:
    result = runners.run(spec, "affinification", frames, tau_a, 2 * tau_a, reference=reference,
                         step_error=False, residual=False)
    rows.append(result.summary)
    s = result.summary
    print(f"tau_a = {tau_a:<5g} tau_e = {2 * tau_a:<5g}: DOF ratio {s['dof_ratio']:.2f}, "
          f"bodies {s['mean_clusters']:5.1f}, max error {s['max_distance_error']:.1e}, speedup {s['speedup']:.2f}")

dof_ratio = np.array([r["dof_ratio"] for r in rows])
error = np.array([r["max_distance_error"] for r in rows])
speedup = np.array([r["speedup"] for r in rows])

# %%
# Reading the picture
# -------------------
# Pick the largest thresholds whose error you accept: the error grows and the DOFs
# fall as the thresholds grow. The error is the largest vertex distance to the
# full-space run over the scene's size; ``compare`` and the sweep also report it over
# the response (the reference's largest displacement from rest) and in metres, the
# stress error, the step error (which discounts phase drift), the residual of the
# full-space system and the strain-energy difference.
if __name__ == "__main__":
    import matplotlib.pyplot as plt

    fig, (left, right) = plt.subplots(1, 2, figsize=(9, 3.6))
    left.plot(dof_ratio, error, "o-")
    for t, d, e in zip(taus, dof_ratio, error):
        left.annotate(f"tau_a = {t:g}", (d, e), textcoords="offset points", xytext=(4, 4), fontsize=8)
    left.set_xlabel("DOF ratio (solved / full space)")
    left.set_ylabel("max distance error / size")
    left.set_yscale("log")
    right.semilogx(taus, speedup, "o-")
    right.axhline(1.0, color="gray", lw=0.8)
    right.set_xlabel("tau_a (1/s), tau_e = 2 tau_a")
    right.set_ylabel("speedup over full space")
    fig.suptitle("Cantilever, 192 tets, 60 frames")
    fig.tight_layout()

# %%
# Or state the error you accept
# -----------------------------
# Instead of thresholds, give the largest vertex distance to the full-space run you
# accept, relative to the response (the largest displacement from rest, here the tip's
# swing): ``sa.Affinification(target_error=0.01)`` (1 % of the response is also the
# default of ``sa.Affinification()``; ``relative_to="size"`` or ``"metre"`` state it over
# the scene size or in metres) chooses its thresholds and adapts them
# during the run, checking itself against an occasional full-space step, and solves a
# frame in full space where reduction would not pay. ``trade.budget_runs`` steps it
# beside the full-space run and measures what it achieved; ``skfem-affine budget SCENE
# --errors 0.003 0.01 0.03`` does the same from the command line and draws ``trade.png``.
from skfem_affine.lab import trade  # noqa: E402

budget_rows = trade.budget_runs(spec, [0.01], frames, warm=False)
for r in budget_rows:
    print(f"target_error = {r['budget']:g}: achieved {r['error']:.1e}, DOF ratio {r['dof_ratio']:.2f}, "
          f"mean tau_a {r['mean_tau_a']:.3g}, reduced frames {100 * r['reduced_frames']:.0f} %")
