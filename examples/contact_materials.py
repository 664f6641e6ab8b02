r"""Stiff against soft: bowling balls on a mattress, a toothbrush
=============================================================

Two scenes mix materials. In ``bowling``, stiff balls (E = 1e7 Pa) fall from
different heights onto a soft mattress (E = 2e4 Pa) lying on the floor; the
higher the drop, the larger the region that must stay elastic (paper Fig. 3).
With affinification, the oracle's one-iteration prediction (eq. 13) takes the
contact impulses as explicit forces: the warm-started ones, and for new
contacts a cheap bilateral estimate, so that an impact elastifies the region
around it in the very frame it happens (sec. 3.4).

In ``toothbrush``, one mesh carries a stiff handle and soft bristle tufts, and
the brush is pushed along the floor: friction bends the bristles backwards.

The script prints, per ball, the fraction of elastic mattress elements under it
at its impact, and how far the bristle tips trail the handle.
"""
import numpy as np

import skfem_affine as sa

bowling = sa.scenes.bowling(n=2, resolution=1, heights=(0.05, 0.6),
                            reducer=sa.Affinification(tau_a=0.5, tau_e=1.0))
sysm = bowling.system
mattress = sysm.body_of_element == 0
centroids = sysm.p0[sysm.t].mean(axis=0)
balls_x = [b[:, 0].mean() for b in bowling.split(sysm.p0)[1:]]
elastic_under = {i: [] for i in range(len(balls_x))}
for state in bowling.run(60):
    elastic = state.clusters < 0
    for i, x in enumerate(balls_x):
        under = mattress & (np.abs(centroids[:, 0] - x) < 0.3)
        elastic_under[i].append(elastic[under].mean())
peak_elastic = [max(v) for v in elastic_under.values()]

brush = sa.scenes.toothbrush(resolution=1, speed=0.5)
for state in brush.run(40):
    pass
mesh_z = brush.system.p0[:, 2]
tips = mesh_z < mesh_z.min() + 1e-6
top = mesh_z > mesh_z.max() - 1e-6
trail = float(brush.state.x[tips, 0].mean() - brush.state.x[top, 0].mean()
              - (brush.system.p0[tips, 0].mean() - brush.system.p0[top, 0].mean()))

if __name__ == "__main__":
    for i, frac in enumerate(peak_elastic):
        print(f"ball {i}: at most {100 * frac:.0f} % of the mattress elements under it elastic")
    print(f"toothbrush: bristle tips trail the handle by {1e3 * trail:.1f} mm after 0.4 s of brushing")

    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 3.2))
    for i, values in elastic_under.items():
        ax.plot(bowling.dt * np.arange(1, len(values) + 1), values, label=f"under ball {i}")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("elastic share of the mattress")
    ax.set_title("Bowling balls on a mattress: the impact keeps its region elastic")
    ax.legend(fontsize=8)
    fig.tight_layout()
