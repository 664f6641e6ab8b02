r"""The stretch a linear position update gives a spinning body, for the linearized step's Taylor term.

The linearized step (eq. 1-2) stands for f at the frame's end, x_t + h v, by its first-order
Taylor expansion f(x_t) + K h v. Along a rigid rotation that expansion is not good enough: a
body turning at angular velocity w about its centre of mass c moves, under x + h v, along the
tangent of its rotation, not around it, and ends stretched by

.. math:: e_i = (I + h[w]_\times - R(h w))(x_i - c)
              = (\theta - \sin\theta)\, a \times r_i + (1 - \cos\theta)\, r_{i\perp},
          \qquad \theta = h |w|,\; a = w / |w|,

(r_i = x_i - c, r_{i\perp} its part normal to the axis): a strain of order theta^2 that the
linear term does not see. In a stiff body that strain is a large force at the next frame, and its
stress turns the rotation into a stiff mode of H (the geometric stiffness): the step then damps
the spin by much more than backward Euler does. The exact rotation of a body's force,
f(R x) = R f(x), splits the end position into the rigid turn and e, so that

.. math:: f(x_t + h v) \approx f(x_t) + K (h v + e),

which is eq. 2's Taylor term with e added to the displacement (the rotation of f(x_t) itself,
R f - f, agrees with K h w x r to first order and is left to it). :meth:`StepProblem.rhs
<skfem_affine.integrators.problem.StepProblem.rhs>` subtracts h H e.

Only free bodies (no fixed or prescribed vertex) turn rigidly about their centre of mass; bodies
held by fixed vertices get no term. A body whose turn is too small for e to show in its positions
(theta^2 / 2 below the double-precision epsilon) gets none either.
"""
import numpy as np


class RotationStretch:
    """e (above) of the free bodies of an :class:`~skfem_affine.assembly.ElasticSystem`.

    Parameters
    ----------
    system : ElasticSystem
    """

    def __init__(self, system):
        held = np.zeros(len(system.bodies), dtype=bool)
        held[system.body_of_vertex[system.fixed]] = True
        self.vertices = np.flatnonzero(~held[system.body_of_vertex])  # the free bodies' vertices
        _, self.body = np.unique(system.body_of_vertex[self.vertices], return_inverse=True)
        self.k = int(self.body.max()) + 1 if self.vertices.size else 0
        self.mass = system.lumped_mass[self.vertices]
        self.body_mass = np.bincount(self.body, weights=self.mass, minlength=self.k)
        self.n, self.free = system.n, system.free

    def _sum(self, values):
        """Per-body sums of per-vertex values (len(vertices), j) -> (k, j)."""
        return np.stack([np.bincount(self.body, weights=values[:, j], minlength=self.k)
                         for j in range(values.shape[1])], axis=1)

    def angular_velocities(self, x, v):
        """(k, 3) each free body's angular velocity w = I^-1 L about its centre of mass (lumped mass),
        and (len(vertices), 3) the vertices' positions r relative to it."""
        m = self.mass[:, None]
        xs, vs = x[self.vertices], v[self.vertices]
        c = self._sum(m * xs) / self.body_mass[:, None]
        r = xs - c[self.body]
        L = self._sum(m * np.cross(r, vs))
        rr = self._sum(m * np.einsum("ni,nj->nij", r, r).reshape(-1, 9)).reshape(-1, 3, 3)
        inertia = np.trace(rr, axis1=1, axis2=2)[:, None, None] * np.eye(3) - rr
        return np.linalg.solve(inertia, L[:, :, None])[:, :, 0], r

    def __call__(self, x, v, h):
        """e on the free DOFs, (n_free,), from positions and velocities (n, 3) and the step h;
        None when no free body turns enough for it to show."""
        if not self.k:
            return None
        w, r = self.angular_velocities(np.asarray(x, float), np.asarray(v, float))
        theta = h * np.linalg.norm(w, axis=1)
        turning = 0.5 * theta * theta > np.finfo(float).eps
        if not np.any(turning):
            return None
        theta = np.where(turning, theta, 0.0)
        a = np.divide(w, np.where(turning, theta / h, 1.0)[:, None])[self.body]
        th = theta[self.body][:, None]
        axial = np.einsum("ni,ni->n", a, r)[:, None] * a
        e = (th - np.sin(th)) * np.cross(a, r) + 2.0 * np.sin(0.5 * th) ** 2 * (r - axial)
        out = np.zeros((self.n, 3))
        out[self.vertices] = e
        return out.reshape(-1)[self.free]
