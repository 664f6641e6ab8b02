r"""Moving boundaries and pulling forces
=====================================

A 2 m x 0.5 m x 0.5 m Neo-Hookean beam (E = 50 kPa, nu = 0.35, rho = 100 kg/m^3) is held by two
clamps: the one at x = 0 is fixed, the one at x = 2 turns about the beam's axis at
``omega`` rad/s. A clamp that moves is an :class:`~skfem_affine.Prescribed` set of vertices,
given to the body beside ``fixed``: ``path(t, X)`` returns their positions at time t from their
rest positions X, and the simulation keeps them exactly on it. Halfway through, a user pulls
the beam's middle sideways: a :class:`~skfem_affine.VertexForce` whose ``force(t, x, v)`` is
a function of time (and could use the vertices' positions and velocities).

The same scene runs in full space and with affinification (``sa.Affinification``): elements
touching the clamps stay elastic (the paper's choice; ``pinned_bodies=True`` lets them join
affine bodies constrained by the clamp).

Run ``python examples/rotating_clamp.py`` (a few seconds). The user guide's page on bodies
and boundaries says how each integrator and reducer treats prescribed vertices.
"""
import numpy as np
import skfem

import skfem_affine as sa


def beam(resolution=2):
    k = resolution
    return skfem.MeshTet.init_tensor(np.linspace(0, 2, 4 * k + 1), np.linspace(0, 0.5, k + 1),
                                     np.linspace(0, 0.5, k + 1))


def simulate(reducer=None, frames=60, dt=0.01, omega=2.0, pull=20.0):
    mesh = beam()
    fixed = mesh.nodes_satisfying(lambda p: p[0] < 1e-9)
    turning = mesh.nodes_satisfying(lambda p: p[0] > 2 - 1e-9)
    middle = mesh.nodes_satisfying(lambda p: np.abs(p[0] - 1.0) < 1e-9)
    axis = np.array([0.0, 0.25, 0.25])

    def turn(t, X):
        """The clamp's positions at time t: rotated about the beam's axis by omega t."""
        c, s = np.cos(omega * t), np.sin(omega * t)
        R = np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])
        return (X - axis) @ R.T + axis

    def sideways(t, x, v):
        """A pull along +y on the middle section, switched on halfway (newtons per vertex)."""
        return np.array([0.0, pull if t >= 0.5 * frames * dt else 0.0, 0.0])

    body = sa.ElasticBody(mesh, sa.NeoHookean(E=5e4, nu=0.35), density=100.0, fixed=fixed,
                          prescribed=sa.Prescribed(turning, turn))
    sim = sa.Simulation(body, dt=dt, damping=sa.Rayleigh(0.03, 0.02), reducer=reducer,
                        forces=[sa.VertexForce(middle, sideways)])
    X = mesh.p.T
    clamp_error, states = 0.0, []
    for state in sim.run(frames):
        clamp_error = max(clamp_error, np.abs(state.x[turning] - turn(state.time, X[turning])).max())
        states.append(state)
    return sim, states, clamp_error, middle


full, full_states, clamp_error, middle = simulate()
aff, aff_states, aff_clamp_error, _ = simulate(sa.Affinification(2e-3, 1e-3))
angle = 2.0 * full_states[-1].time  # the turning clamp's angle at the end
middle_shift = full_states[-1].x[middle, 1].mean() - full_states[0].x[middle, 1].mean()
dof_ratio = np.mean([r["dofs"] for r in aff.stats]) / full.stats[-1]["dofs"]
error = max(np.abs(a.x - f.x).max() for a, f in zip(aff_states, full_states)) / full.size

if __name__ in ("__main__", "example"):
    print(f"clamp turned {np.degrees(angle):.0f} degrees; on its path to {max(clamp_error, aff_clamp_error):.1e} m")
    print(f"middle pulled {middle_shift:+.3f} m along y")
    print(f"affinification: DOF ratio {dof_ratio:.2f}, max distance error {error:.1e} of the beam's size")
