"""External forces that change with time, applied to a built :class:`~skfem_affine.Simulation`.

:class:`Pull` is a force on a set of vertices during a time window (the octopus
scene's tug on a tentacle, paper Fig. 11). :func:`attach_force` makes a
simulation apply any ``force(t, sim) -> (n, 3)`` from then on.

The simulation takes one constant external force vector, ``sim.f_gravity``
(gravity's weight on every free DOF), in every integrator and reducer. So that
the frame path stays untouched, :func:`attach_force` wraps the simulation's own
``step``: before each step it writes weight + ``force(t)`` into that vector, in
place (the Newton integrators hold a reference to it), with ``t`` the time at
the start of the step (explicit in the load, as gravity). The affinification
oracle splits this vector out of its prediction as it does gravity, so it does not
see the pull's local effect before it happens. ``sim.energy`` then counts the load
in its "gravity" potential.
"""
import numpy as np


class Pull:
    """A constant total force ``force`` (N) on ``vertices`` for ``start <= t < stop``.

    The force is shared in proportion to the vertices' lumped masses, as a body force on
    that region: every pulled vertex gets the same acceleration, so a light vertex on
    a fine part of the mesh is not flung away.

    Parameters
    ----------
    vertices : array of vertex indices (of the whole simulation) or boolean mask
    force : (3,) array
        Total force (N) on the vertices.
    start, stop : float
        The time window (s).
    """

    def __init__(self, vertices, force, start=0.0, stop=np.inf):
        v = np.asarray(vertices)
        if v.dtype == bool:
            v = np.flatnonzero(v)
        if v.size == 0 or not np.issubdtype(v.dtype, np.integer):
            raise ValueError("Pull vertices must be a non-empty array of vertex indices or a boolean mask")
        self.vertices = v.ravel().astype(np.int64)
        self.force = np.asarray(force, dtype=float)
        if self.force.shape != (3,) or not np.all(np.isfinite(self.force)):
            raise ValueError(f"Pull force must be a finite 3-vector, got {force!r}")
        self.start, self.stop = float(start), float(stop)
        if not self.start < self.stop:
            raise ValueError(f"Pull needs start < stop, got start={start}, stop={stop}")

    def __repr__(self):
        return (f"Pull({self.vertices.size} vertices, force={self.force.tolist()}, "
                f"start={self.start:g}, stop={self.stop:g})")

    def __call__(self, t, sim):
        """(n, 3) nodal forces of simulation ``sim`` at time ``t``."""
        mass = sim.system.lumped_mass
        f = np.zeros((mass.size, 3))
        if self.start <= t < self.stop:
            share = np.zeros(mass.size)
            np.add.at(share, self.vertices, mass[self.vertices])
            f += (share / share.sum())[:, None] * self.force
        return f


def attach_force(sim, force):
    """Make ``sim`` apply ``force(t, sim) -> (n, 3)`` (N per vertex) at every later step; returns ``sim``.

    ``force`` may be a :class:`Pull`. Forces on fixed vertices have no effect.
    """
    if not callable(force):
        raise TypeError(f"force must be callable as force(t, sim) -> (n, 3), e.g. a Pull, got {type(force).__name__}")
    n = sim.system.n
    if isinstance(force, Pull) and force.vertices.max() >= n:
        raise ValueError(f"Pull vertices out of range [0, {n}): max {force.vertices.max()}")
    weight = sim.f_gravity.copy()
    step = sim.step
    load = np.zeros(weight.shape)

    def step_with_force():
        f = np.asarray(force(sim.state.time, sim), dtype=float)
        if f.shape != (n, 3) or not np.all(np.isfinite(f)):
            raise ValueError(f"force(t, sim) must return a finite ({n}, 3) array, got shape {f.shape}")
        load[:] = f.reshape(-1)
        sim.f_gravity[:] = weight + load
        return step()

    sim.step = step_with_force
    sim.external_force = force
    return sim
