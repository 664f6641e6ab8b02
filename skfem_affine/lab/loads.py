"""Time-windowed pulls on a set of vertices (the octopus scene's tug on a tentacle, paper Fig. 11).

A :class:`Pull` is the force function of a :class:`skfem_affine.VertexForce`: the simulation
evaluates it once per step, at the start of the step, adds it to gravity, and counts its work
in the energy check (:mod:`skfem_affine.motion`).
"""
import numpy as np

from skfem_affine.checks import real, real_array
from skfem_affine.kinematics import signed_volumes
from skfem_affine.motion import VertexForce, vertex_indices


class Pull:
    """A constant total force ``force`` (N) on ``vertices`` for ``start <= t < stop``.

    The force is shared in proportion to ``weights`` (e.g. the vertices' lumped masses, so that
    every pulled vertex gets the same acceleration and a light vertex on a fine part of the
    mesh is not flung away); equal shares without weights.

    Parameters
    ----------
    vertices : array of vertex indices or boolean mask
    force : (3,) array
        Total force (N) on the vertices.
    start, stop : float
        The time window (s).
    weights : (k,) array, optional
        Positive share of each vertex.
    """

    def __init__(self, vertices, force, start=0.0, stop=np.inf, weights=None):
        self.vertices = vertex_indices(vertices, None, "Pull vertices")
        self.force = np.asarray(force, dtype=float)
        if self.force.shape != (3,) or not np.all(np.isfinite(self.force)):
            raise ValueError(f"Pull force must be a finite 3-vector, got {force!r}")
        self.start = real(start, "Pull start", finite=False)
        self.stop = real(stop, "Pull stop", finite=False)
        if not self.start < self.stop:
            raise ValueError(f"Pull needs start < stop, got start={start}, stop={stop}")
        w = np.ones(self.vertices.size) if weights is None else real_array(weights, "Pull weights", shape=(None,))
        if w.shape != self.vertices.shape or not np.all(w > 0):
            raise ValueError(f"Pull weights must be {self.vertices.size} positive numbers, one per vertex")
        self.share = w / w.sum()

    def __repr__(self):
        return (f"Pull({self.vertices.size} vertices, force={self.force.tolist()}, "
                f"start={self.start:g}, stop={self.stop:g})")

    def __call__(self, t, x, v):
        """The forces (k, 3) on the vertices at time ``t`` (a VertexForce's force function)."""
        if self.start <= t < self.stop:
            return self.share[:, None] * self.force
        return np.zeros((self.vertices.size, 3))

    def vertex_force(self):
        """The :class:`~skfem_affine.VertexForce` that applies this pull (``Simulation(forces=[...])``)."""
        return VertexForce(self.vertices, self)


def vertex_volumes(mesh, density=1.0):
    """What each vertex carries of ``density`` (a number or one per element) times volume: a
    quarter of each of its tetrahedra's, the lumped masses of P1 tetrahedra."""
    vol = np.abs(signed_volumes(mesh.p, mesh.t)) * density
    return np.bincount(mesh.t.ravel(), np.repeat(vol[None, :] / 4.0, 4, axis=0).ravel(), minlength=mesh.p.shape[1])
