"""What the unit of the default budget costs on the demo's beam (docs/budget.md).

The cantilever at ``resolution`` (default 10: the demo's 24k tets), stepped interleaved with the
full-space run: ``sa.Affinification()`` (1 % of the response), 5 % of the response, and 1 % of
the scene size (the former default); the speedup over full space, the DOF ratio, and the error
over the response and over the size.

Usage::

    python benchmarks/budget_units_demo.py 10 60      # resolution, frames
"""
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
import skfem_affine as sa  # noqa: E402
from skfem_affine.lab import metrics, runners  # noqa: E402


def main(k=10, frames=60):
    def make(reducer=None):
        return sa.scenes.cantilever(resolution=k, reducer=reducer)
    sims = {"full": make(), "1 % of the response (default)": make(sa.Affinification()),
            "5 % of the response": make(sa.Affinification(target_error=0.05)),
            "1 % of the size": make(sa.Affinification(relative_to="size"))}
    runners.warm_up(runners.SceneSpec.make("cantilever", resolution=k), ("full", "affinification-budget"))
    full = sims["full"]
    worst = {name: 0.0 for name in sims if name != "full"}
    response = [0.0]

    def on_frame(frame, running):
        response[0] = max(response[0], metrics.response_amplitude(full.state.x, full.system.p0))
        for name in worst:
            worst[name] = max(worst[name], metrics.distance_m(running[name].state.x, full.state.x))

    runs = runners.interleaved(sims, frames, on_frame=on_frame)
    print(f"{full.system.m} tets, {frames} frames, response R = {response[0]:.3g} m, size L = {full.size:.3g} m")
    for name in worst:
        s = runs[name].summary
        reduced = np.mean([bool(r.get("reduced")) for r in runs[name].records])
        print(f"{name:>32}: speedup {s['speedup']:.2f}, DOF ratio {s['dof_ratio']:.3f}, error {worst[name] / response[0]:.1e}"
              f" of R, {worst[name] / full.size:.1e} of L, reduced frames {reduced:.0%}")


if __name__ == "__main__":
    main(*(int(a) for a in sys.argv[1:3]))
