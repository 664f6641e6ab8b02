r"""Verification: the first bending frequency against beam theory
=============================================================

A stiff beam (E = 100 MPa, nu = 0, rho = 1000 kg/m^3, length L = 4 m, square
section a = 0.5 m) starts from rest under gravity and oscillates about its
static deflection. Euler-Bernoulli beam theory gives the first bending mode

.. math:: f_1 = \frac{1.8751^2}{2 \pi L^2} \sqrt{\frac{E I}{\rho A}}, \qquad I = a^4 / 12.

We measure the period from the zero crossings of the tip height about its
mean. Linear tetrahedra are too stiff in bending ("locking"): the frequency
is 33 % high with k = 2 elements across the section and 16 % high with k = 3,
an error that falls like 1/k^2. Richardson extrapolation of the two,

.. math:: f_\infty \approx \frac{k_3^2 f_3 - k_2^2 f_2}{k_3^2 - k_2^2},

lands within a few percent of the theory. Backward Euler lengthens the period
by about (omega h)^2 / 3, negligible at h = 2 ms.
"""
import numpy as np
import skfem

import skfem_affine as sa

L, a, E, rho = 4.0, 0.5, 1e8, 1000.0
f_theory = 1.8751 ** 2 / (2 * np.pi * L ** 2) * np.sqrt(E * a ** 4 / 12 / (rho * a * a))


def measured_frequency(k=2, dt=0.002, frames=400):
    """Simulate with k elements across the section; return the measured frequency (Hz)."""
    mesh = skfem.MeshTet.init_tensor(np.linspace(0, L, int(k * L / a) + 1), np.linspace(0, a, k + 1),
                                     np.linspace(0, a, k + 1))
    body = sa.ElasticBody(mesh, sa.NeoHookean(E=E, nu=0.0), density=rho,
                          fixed=mesh.nodes_satisfying(lambda p: p[0] < 1e-9))
    sim = sa.Simulation(body, dt=dt, gravity=(0, 0, -9.81))
    tip = mesh.nodes_satisfying(lambda p: p[0] > L - 1e-9)
    z = np.array([s.x[tip, 2].mean() for s in sim.run(frames)])
    z -= 0.5 * (z.max() + z.min())
    crossings = np.flatnonzero(np.diff(np.sign(z)) != 0)
    t = (crossings + z[crossings] / (z[crossings] - z[crossings + 1])) * dt  # linear interpolation
    return 1.0 / (2.0 * np.mean(np.diff(t)))


f2, f3 = measured_frequency(2), measured_frequency(3)
f_extrapolated = (9 * f3 - 4 * f2) / (9 - 4)
relative_error = f_extrapolated / f_theory - 1.0

if __name__ == "__main__":
    print(f"Euler-Bernoulli f1 = {f_theory:.3f} Hz")
    for k, f in ((2, f2), (3, f3), ("inf", f_extrapolated)):
        print(f"k = {k}: f1 = {f:.3f} Hz ({100 * (f / f_theory - 1):+.1f} %)")

    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 3.2))
    ax.bar(["k = 2", "k = 3", "extrapolated"], [f2, f3, f_extrapolated], color=["tab:gray", "tab:gray", "tab:blue"])
    ax.axhline(f_theory, color="tab:red", label="Euler-Bernoulli")
    ax.set_ylabel("first bending frequency (Hz)")
    ax.legend(fontsize=8)
    fig.tight_layout()
