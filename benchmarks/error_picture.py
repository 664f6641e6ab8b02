"""The picture of docs/budget.md: one run's error over time, relative to the response and to the scene size.

The cantilever (``--resolution``, default 3: 648 tets) with the default ``sa.Affinification()``
(1 % of the response, ``never_slower=False`` so that this small beam reduces at all), stepped in
turn with the full-space run. Per frame: the largest vertex distance to the full-space run over
the full-space run's response R (its largest displacement from rest over the run) and over the
scene size L, the reducer's own estimate (in its unit, the response so far) and the budget.

Usage::

    python benchmarks/error_picture.py                  # writes docs/error_units.png
"""
import argparse
import os
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
import skfem_affine as sa  # noqa: E402
from skfem_affine.lab import metrics  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))


def measure(resolution, frames, budget):
    full = sa.scenes.cantilever(resolution=resolution, solver="direct")
    red = sa.scenes.cantilever(resolution=resolution, solver="direct",
                               reducer=sa.Affinification(target_error=budget, never_slower=False))
    t, dist, resp, est = [], [], [], []
    for _ in range(frames):
        full.step()
        red.step()
        t.append(full.state.time)
        dist.append(metrics.distance_m(red.state.x, full.state.x))
        resp.append(metrics.response_amplitude(full.state.x, full.system.p0))
        est.append(red.stats[-1].get("estimated_error", np.nan))
    return np.array(t), np.array(dist), max(resp), full.size, np.array(est), np.array(resp)


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--resolution", type=int, default=3)
    p.add_argument("--frames", type=int, default=200)
    p.add_argument("--budget", type=float, default=0.01)
    p.add_argument("--out", default=os.path.join(HERE, "..", "docs", "error_units.png"))
    args = p.parse_args(argv)
    t, dist, response, size, est, running = measure(args.resolution, args.frames, args.budget)
    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 3.6), constrained_layout=True)
    a.plot(t, dist / response, label="achieved: distance / R")
    a.plot(t, est, "--", label="the reducer's estimate (its unit: R so far)")
    a.axhline(args.budget, color="k", lw=0.8, label=f"budget {args.budget:g}")
    a.set(xlabel="time (s)", ylabel="max vertex distance / response",
          title=f"relative to the response R = {100 * response:.1f} cm")
    a.legend(fontsize=8)
    b.plot(t, dist / size, color="C2", label="achieved: distance / L")
    b.set(xlabel="time (s)", ylabel="max vertex distance / scene size",
          title=f"relative to the scene size L = {size:.2f} m")
    b.legend(fontsize=8)
    fig.suptitle(f"cantilever, {args.frames} frames, sa.Affinification() (budget {args.budget:g} of the response)",
                 fontsize=10)
    fig.savefig(args.out, dpi=90)
    print(f"wrote {args.out}: largest distance {dist.max():.3g} m = {dist.max() / response:.2e} of the response "
          f"R = {response:.3g} m = {dist.max() / size:.2e} of the size L = {size:.3g} m; largest estimate "
          f"{np.nanmax(est):.2e}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
