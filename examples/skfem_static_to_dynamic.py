r"""From a scikit-fem static model to a dynamic one
===============================================

A scikit-fem user has a linear-elastic static model: a mesh with named boundaries, a
``Basis(mesh, ElementVector(ElementTetP1()))``, a clamp from ``basis.get_dofs("left")`` and a
traction on ``"right"`` assembled on a ``FacetBasis``. This tutorial turns that model into a
dynamic one with skfem-affine, reusing scikit-fem's own objects:

* the clamp: ``fixed=basis.get_dofs("left")`` (a ``DofsView``; a boundary name
  ``fixed="left"`` works too, :mod:`skfem_affine.vertex_sets`);
* the load: scikit-fem's assembled load vector, read per vertex through ``basis.nodal_dofs``,
  applied by a :class:`~skfem_affine.VertexForce` ramped up in time;
* the result: ``state.dofs(basis)``, a scikit-fem DOF vector, so ``basis.probes`` and
  ``basis.interpolate`` work on it (and ``sa.State.from_dofs(basis, u)`` goes the other way).

Three comparisons on one mesh (both codes use the same linear tetrahedra, so the mesh's own
stiffness in bending cancels out):

1. **static deflection**: a damped dynamic run (Neo-Hookean, small strain) comes to rest at
   scikit-fem's linear static solution, to the size of the geometric nonlinearity;
2. **stress**: the Cauchy stress of :meth:`~skfem_affine.Simulation.stress` against the linear
   stress :math:`\sigma = \lambda\, \mathrm{tr}\,\varepsilon\, I + 2 \mu \varepsilon` of
   scikit-fem's solution, at the root;
3. **first frequency**: started from the static solution (``State.from_dofs``) with the load
   removed, the bar vibrates as scikit-fem's modal solution of
   :math:`M \ddot u + K u = 0` says, up to backward Euler's damping of each mode (by about
   :math:`(\omega h)^2/2` per step).
"""
import os

import numpy as np
import scipy.linalg
import skfem
from skfem import Basis, BilinearForm, ElementTetP1, ElementVector, FacetBasis, LinearForm, asm, condense, solve
from skfem.helpers import dot
from skfem.models.elasticity import lame_parameters, linear_elasticity

import skfem_affine as sa

L, a, E, nu, rho = 1.0, 0.1, 1e7, 0.3, 1000.0
load = 2.0  # N, downwards on the free end

# %%
# The scikit-fem static model
# ---------------------------
mesh = skfem.MeshTet.init_tensor(np.linspace(0, L, 21), np.linspace(0, a, 3), np.linspace(0, a, 3))
mesh = mesh.with_boundaries({"left": lambda x: x[0] < 1e-9, "right": lambda x: x[0] > L - 1e-9})
basis = Basis(mesh, ElementVector(ElementTetP1()))
lam, mu = lame_parameters(E, nu)
K = asm(linear_elasticity(lam, mu), basis)


@LinearForm
def traction(v, w):
    return dot(np.array([0.0, 0.0, -load / a ** 2])[:, None, None], v)


f = asm(traction, FacetBasis(mesh, basis.elem, facets="right"))
clamp = basis.get_dofs("left")
u_static = solve(*condense(K, f, D=clamp))
tip = np.array([[L], [a / 2], [a / 2]])  # the centre of the free end
probe = basis.probes(tip)
deflection_static = float((probe @ u_static).reshape(3)[2])

# %%
# The same model, dynamic
# -----------------------
# scikit-fem's load vector holds the consistent nodal forces of the traction; per vertex
# they are ``f[basis.nodal_dofs].T``. The load is ramped up in 60 steps of 5 ms (a force is
# evaluated at the start of each step: step k carries k/60 of it) and mass-proportional damping
# (which leaves the static solution unchanged) brings the bar to rest.
nodal_forces = f[basis.nodal_dofs].T
right = sa.vertices_of(mesh, "right")


def ramped(t, x, v):
    return min((t + 0.005) / 0.3, 1.0) * nodal_forces[right]


material = sa.NeoHookean(E=E, nu=nu)
body = sa.ElasticBody(mesh, material, density=rho, fixed=clamp)
sim = sa.Simulation(body, dt=0.005, damping=sa.Rayleigh(alpha=25.0), forces=[sa.VertexForce("right", ramped)])
deflection = [float((probe @ s.dofs(basis)).reshape(3)[2]) for s in sim.run(200)]
times = sim.dt * np.arange(1, len(deflection) + 1)
deflection_error = abs(deflection[-1] / deflection_static - 1)
print(f"tip deflection: scikit-fem static {1e3 * deflection_static:.3f} mm, dynamic at rest "
      f"{1e3 * deflection[-1]:.3f} mm ({100 * deflection_error:.2f} % apart)")
out = os.path.join("out", "skfem_static_to_dynamic")
pvd = sa.io.write_series(os.path.join(out, "bar"), sim, states=[sim.state])  # with strains and stresses

# %%
# Stress at the root
# ------------------
# scikit-fem's linear stress from the gradient of its solution (constant per element), against
# the Cauchy stress of the dynamic run at rest, on the elements next to the clamp.
G = np.moveaxis(Basis(mesh, basis.elem, intorder=1).interpolate(u_static).grad[:, :, :, 0], 2, 0)
eps = 0.5 * (G + G.transpose(0, 2, 1))
sigma_linear = lam * np.trace(eps, axis1=1, axis2=2)[:, None, None] * np.eye(3) + 2 * mu * eps
root = mesh.p[0, mesh.t].mean(axis=0) < L / 20
stresses = sim.stress()
sxx, sxx_linear = stresses.cauchy[root, 0, 0], sigma_linear[root, 0, 0]
stress_error = np.abs(sxx - sxx_linear).max() / np.abs(sxx_linear).max()
print(f"root stress: largest |sigma_xx| {np.abs(sxx_linear).max() / 1e3:.2f} kPa (scikit-fem), "
      f"{np.abs(sxx).max() / 1e3:.2f} kPa (dynamic at rest), largest difference {100 * stress_error:.2f} %")

# %%
# Released from the static solution
# ---------------------------------
# ``State.from_dofs`` turns scikit-fem's solution into the start state of a run without load
# and without damping: the bar vibrates about its rest shape. scikit-fem's modes give the exact
# linear motion, :math:`u(t) = \sum_k \phi_k \cos(\omega_k t)\, \phi_k^T M u_0` with
# :math:`K \phi_k = \omega_k^2 M \phi_k`, with the same (consistent) mass matrix. On this mesh
# the bending modes in y and z mix (2.09 and 2.48 Hz), so the tip beats: the whole trajectory is
# compared, over one period.


@BilinearForm
def mass(u, v, w):
    return rho * dot(u, v)


M = asm(mass, basis)
free = basis.complement_dofs(clamp)
omega2, modes = scipy.linalg.eigh(K[free][:, free].toarray(), M[free][:, free].toarray())
amplitude = (probe.toarray()[2, free] @ modes) * (modes.T @ (M[free][:, free] @ u_static[free]))

released = sa.Simulation(sa.ElasticBody(mesh, material, density=rho, fixed="left"), dt=0.002, mass="consistent")
released.state = sa.State.from_dofs(basis, u_static)
tip_released = np.array([float((probe @ s.dofs(basis)).reshape(3)[2]) for s in released.run(240)])
t_released = released.dt * np.arange(1, tip_released.size + 1)
tip_modal = np.cos(np.sqrt(omega2)[None, :] * t_released[:, None]) @ amplitude
trajectory_error = np.abs(tip_released - tip_modal).max() / np.abs(tip_modal).max()

# %%
# The difference is backward Euler's damping, strongest on the faster modes: the same modes
# stepped by backward Euler (q' = p, p' = -omega^2 q, implicit in both) follow the run closely.
h, q, p = released.dt, np.ones_like(omega2), np.zeros_like(omega2)
tip_stepped = []
for _ in range(tip_released.size):
    p = (p - h * omega2 * q) / (1 + h * h * omega2)
    q = q + h * p
    tip_stepped.append(q @ amplitude)
stepped_error = np.abs(tip_released - np.array(tip_stepped)).max() / np.abs(tip_modal).max()
print(f"released bar: first frequency {np.sqrt(omega2[0]) / (2 * np.pi):.3f} Hz; tip trajectory within "
      f"{100 * trajectory_error:.1f} % of scikit-fem's modal solution, {100 * stepped_error:.2f} % of its modes "
      f"stepped by backward Euler (of the largest deflection)")

if __name__ == "__main__":
    import matplotlib.pyplot as plt

    fig, (ax, bx) = plt.subplots(1, 2, figsize=(9, 3.2))
    ax.plot(times, 1e3 * np.array(deflection), label="skfem-affine, damped, ramped load")
    ax.axhline(1e3 * deflection_static, color="tab:red", ls="--", label="scikit-fem static")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("tip deflection (mm)")
    ax.legend(fontsize=8)
    bx.plot(t_released, 1e3 * tip_modal, color="tab:red", ls="--", label="scikit-fem modes")
    bx.plot(t_released, 1e3 * tip_released, label="skfem-affine, released")
    bx.set_xlabel("time (s)")
    bx.legend(fontsize=8)
    fig.tight_layout()
    plt.show()
