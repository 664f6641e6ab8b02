r"""ParaView output and an animated GIF
====================================

Two ways to look at a run:

* :class:`skfem_affine.lab.io.Series` (``sa.io.Series``) writes each state you pass
  it, as the simulation runs, as one VTU file per frame and a ``.pvd`` index that
  ParaView opens as a time series. Each frame holds the point fields ``velocity``,
  ``displacement`` and ``fixed`` and the cell fields ``material``, ``body``,
  ``cluster`` (the element's affine body, -1 for elastic) and ``affine`` (0/1):
  colour by ``cluster`` to watch affinification at work. Strains and stresses come with them,
  per cell and averaged at the points (``cauchy_stress``, ``von_mises_stress``, ...,
  :mod:`skfem_affine.stress`).
  :func:`~skfem_affine.lab.io.write_series` (``sa.io.write_series(path, sim, states=...)``)
  writes states you already have, e.g. those a lab run kept.
* :mod:`skfem_affine.lab.plots` draws the same states with matplotlib:
  :func:`~skfem_affine.lab.plots.clusters_picture` (one PNG, a panel per state)
  and :func:`~skfem_affine.lab.plots.animation` (an animated GIF).

The command line does both for any scene:
``skfem-affine compare drop --gif`` writes ``out/compare/drop/paraview/<method>.pvd`` and
a GIF per method.

This tutorial drops a soft box on the floor with affinification and writes both
into ``out/output/``.
"""
import os

import meshio

import skfem_affine as sa
from skfem_affine.lab import plots

out = os.path.join("out", "output")


def scene():
    return sa.scenes.drop(resolution=1, shape="box", reducer=sa.Affinification(tau_a=1.0, tau_e=2.0))


# %%
# A ParaView time series
# ----------------------
# Every second frame of 60, plus the initial state, written while the box falls; every
# fourth state is also kept (copied: the simulation reuses its state) for the pictures below.
sim = scene()
series = sa.io.Series(os.path.join(out, "drop"), sim)
series.write(sim.state)
states = [sim.state.copy()]
for state in sim.run(60):
    if state.frame % 2 == 0:
        series.write(state)
    if state.frame % 4 == 0:
        states.append(state.copy())
pvd = series.pvd
first = meshio.read(os.path.join(out, "drop_00000.vtu"))
frames = sorted(f for f in os.listdir(out) if f.endswith(".vtu"))
print(f"wrote {pvd}: {len(frames)} frames; fields {sorted(first.point_data)} on points, "
      f"{sorted(first.cell_data)} on cells")

# %%
# An animated GIF and a picture of the bodies
# -------------------------------------------
# Draw the kept states: elastic elements grey, each affine body in its own colour.
gif = plots.animation("affinification", sim, states, os.path.join(out, "drop.gif"), fps=8)
landed = plots.pick_state(states)   # the kept state that shows most reduction and motion
png = plots.clusters_picture([("affinification", sim, landed)], os.path.join(out, "drop_clusters.png"),
                             title=f"Frame {landed.frame}: elastic grey, bodies coloured")
print(f"wrote {gif} ({len(states)} frames) and {png}")

# %%
# The picture, as written to disk (the GIF shows every kept frame the same way):
if __name__ == "__main__":
    import matplotlib.pyplot as plt

    image = plt.imread(png)
    fig, ax = plt.subplots(figsize=(image.shape[1] / 120, image.shape[0] / 120))
    ax.imshow(image)
    ax.axis("off")
    fig.tight_layout(pad=0)
