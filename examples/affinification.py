r"""Affinification: the speed/accuracy knob
=======================================

The cantilever of ``cantilever.py`` is simulated

1. in full space (the reference),
2. with affinification (paper sec. 3): each frame, one PCG iteration predicts
   the velocity change (eq. 13-14), elements whose deformation rates
   :math:`\dot F = B \dot x` (eq. 4) lie within tau of their cluster's centre
   (eq. 5-6) are merged by a breadth-first search (Algorithm 2) into affine
   bodies of 12 DOFs, :math:`\dot x_i = \dot t + \dot A\, r_i` (eq. 7-8), and the
   reduced system :math:`G^T A G\,\Delta q = G^T b` is solved (eq. 10);
3. with adaptive rigidification, the baseline the paper compares against.

The thresholds tau_a (to become affine) and tau_e (to stay affine) are rates
(1/s): larger values merge more elements, solve fewer DOFs and cost accuracy.
The script prints, for each method, the DOFs solved relative to full space,
the mean number of bodies and the largest vertex distance to the reference
relative to the beam's size, and (as a script) plots elastic DOFs over time.
"""
import numpy as np

import skfem_affine as sa


def compare(resolution=3, frames=100, tau_a=0.1, tau_e=0.2):
    """Run full, affinification and rigidification; return a dict of results per method."""
    methods = {"full": None,
               "affinification": sa.Affinification(tau_a=tau_a, tau_e=tau_e),
               "rigidification": sa.Rigidification(tau_r=1e-2, tau_e=2e-2)}
    out, reference = {}, None
    for name, reducer in methods.items():
        sim = sa.scenes.cantilever(resolution=resolution, reducer=reducer, E=1e5, damping=None)
        xs = [s.x for s in sim.run(frames)]
        if reference is None:
            reference = xs
        err = max(np.abs(x - r).max() for x, r in zip(xs, reference)) / sim.size
        out[name] = {"sim": sim, "error": err,
                     "dofs": np.array([r["dofs"] for r in sim.stats]),
                     "clusters": np.mean([r.get("n_clusters", 0) for r in sim.stats]),
                     "wall": sim.stats.total("wall")}
    for r in out.values():
        r["dof_ratio"] = r["dofs"].sum() / out["full"]["dofs"].sum()
    return out


results = compare()

if __name__ == "__main__":
    import os

    import matplotlib.pyplot as plt

    for name, r in results.items():
        print(f"{name:>15}: DOF ratio {r['dof_ratio']:.2f}, mean bodies {r['clusters']:5.1f}, "
              f"max error {r['error']:.1e} of the beam size")
    print("(speed is measured by benchmarks/affinification.py; this run includes compilation)")
    for name, r in results.items():
        plt.plot(0.01 * np.arange(1, len(r["dofs"]) + 1), r["dofs"], label=name)
    plt.xlabel("time (s)")
    plt.ylabel("DOFs solved per frame")
    plt.legend()
    plt.title("Cantilever: DOFs solved per frame")
    os.makedirs(os.path.join("out", "affinification"), exist_ok=True)
    plt.savefig(os.path.join("out", "affinification", "dofs.png"), dpi=120)
    print("wrote out/affinification/dofs.png")
