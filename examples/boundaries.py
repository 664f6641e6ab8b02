r"""Fixed boundaries
================

Vertices listed in ``fixed`` are held in place: their velocity is zero and they
are eliminated from every solve (a homogeneous Dirichlet condition on the
velocity, so they stay where the mesh put them). ``fixed`` takes vertex indices
or a boolean mask of length ``n``; scikit-fem's ``mesh.nodes_satisfying`` gives
the vertices where a predicate on the coordinates holds, and
``mesh.boundary_nodes()`` the surface vertices.

This tutorial holds the same 4 m rubber beam three ways: clamped at one end (a
cantilever), clamped at both ends (a bridge), and held only along the bottom edge
of one end (a hinge-like support, from a boolean mask). It prints how far the
middle and the tip sag, and checks that the fixed vertices did not move.

A fixed vertex never moves; vertices driven along a given path are
``sa.Prescribed`` (the next tutorial, ``rotating_clamp.py``). Elements touching
fixed vertices stay elastic under affinification, as in the paper, unless
``sa.Affinification(pinned_bodies=True)``.
"""
import numpy as np
import skfem

import skfem_affine as sa

mesh = skfem.MeshTet.init_tensor(np.linspace(0, 4, 13), np.linspace(0, 1, 4), np.linspace(0, 1, 4))
material = sa.NeoHookean(E=2e7, nu=0.35)   # a stiff rubber

# %%
# Three supports
# --------------
# Indices from ``nodes_satisfying``, or a boolean mask built from the coordinates.
x, z = mesh.p[0], mesh.p[2]
supports = {
    "cantilever": mesh.nodes_satisfying(lambda p: p[0] < 1e-9),
    "bridge": mesh.nodes_satisfying(lambda p: (p[0] < 1e-9) | (p[0] > 4 - 1e-9)),
    "hinge": (x < 1e-9) & (z < 1e-9),                      # a boolean mask of length n
}
middle = np.flatnonzero(np.abs(x - 2.0) < 1e-9)
tip = np.flatnonzero(x > 4 - 1e-9)

results = {}
for name, fixed in supports.items():
    body = sa.ElasticBody(mesh, material=material, density=1000.0, fixed=fixed)
    sim = sa.Simulation(body, dt=0.01, gravity=(0.0, 0.0, -9.81), damping=sa.Rayleigh(alpha=1.0, beta=0.01))
    start = sim.state.x.copy()
    lowest = {"middle": 0.0, "tip": 0.0}
    for state in sim.run(100):
        d = state.x - start
        lowest["middle"] = min(lowest["middle"], d[middle, 2].mean())
        lowest["tip"] = min(lowest["tip"], d[tip, 2].mean())
    results[name] = {"sim": sim, **lowest,
                     "fixed_moved": float(np.abs(sim.state.x - start)[body.fixed].max(initial=0.0)),
                     "n_fixed": int(body.fixed.sum())}
    print(f"{name:>10}: {results[name]['n_fixed']:3d} fixed vertices, lowest middle {lowest['middle']:+.3f} m, "
          f"lowest tip {lowest['tip']:+.3f} m, fixed vertices moved {results[name]['fixed_moved']:.1e} m")

# %%
# The bridge sags least; the cantilever's tip falls furthest, and the hinge, held
# only along one edge, rotates about it and falls further still.
if __name__ == "__main__":
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(3, 1, figsize=(7, 6), sharex=True)
    for ax, (name, r) in zip(axes, results.items()):
        p = r["sim"].state.x
        held = r["sim"].system.fixed
        ax.scatter(p[~held, 0], p[~held, 2], s=3, color="tab:gray", label="free")
        ax.scatter(p[held, 0], p[held, 2], s=12, color="tab:red", label="fixed")
        ax.set_aspect("equal")
        ax.set_ylabel("z (m)")
        ax.set_title(f"{name}, t = 1 s", fontsize=9)
    axes[0].legend(loc="lower left", fontsize=8)
    axes[-1].set_xlabel("x (m)")
    fig.tight_layout()
