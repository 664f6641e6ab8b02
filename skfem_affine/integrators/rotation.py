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
from numba import njit

from skfem_affine import _compile_notice  # noqa: F401 (one stderr line when the cached kernels compile)


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
        _, body = np.unique(system.body_of_vertex[self.vertices], return_inverse=True)
        self.body = body.astype(np.int64)
        self.k = int(self.body.max()) + 1 if self.vertices.size else 0
        self.mass = np.ascontiguousarray(system.lumped_mass[self.vertices], dtype=float)
        self.n, self.free = system.n, system.free

    def angular_velocities(self, x, v):
        """(k, 3) each free body's centre of mass c and (k, 3) its angular velocity w = I^-1 L about
        c (lumped mass), from positions and velocities (n, 3)."""
        c, w = np.zeros((self.k, 3)), np.zeros((self.k, 3))
        _spins(np.ascontiguousarray(x, dtype=float), np.ascontiguousarray(v, dtype=float), self.vertices,
               self.body, self.mass, c, w)
        return c, w

    def __call__(self, x, v, h):
        """e on the free DOFs, (n_free,), from positions and velocities (n, 3) and the step h;
        None when no free body turns enough for it to show."""
        if not self.k:
            return None
        c, w = self.angular_velocities(x, v)
        out = np.zeros(3 * self.n)
        if not _stretch(np.ascontiguousarray(x, dtype=float), self.vertices, self.body, c, w, float(h),
                        np.finfo(float).eps, out):
            return None
        return out[self.free]


@njit(cache=True)
def _spins(x, v, vertices, body, mass, c, w):
    """c[b], w[b]: centre of mass and angular velocity I^-1 L of each body b (lumped mass)."""
    k = c.shape[0]
    total = np.zeros(k)
    for i in range(vertices.size):
        b, m = body[i], mass[i]
        total[b] += m
        for j in range(3):
            c[b, j] += m * x[vertices[i], j]
    for b in range(k):
        for j in range(3):
            c[b, j] /= total[b]
    L, q = np.zeros((k, 3)), np.zeros((k, 3, 3))  # q = sum m r r^T
    for i in range(vertices.size):
        b, m, p = body[i], mass[i], vertices[i]
        r0, r1, r2 = x[p, 0] - c[b, 0], x[p, 1] - c[b, 1], x[p, 2] - c[b, 2]
        L[b, 0] += m * (r1 * v[p, 2] - r2 * v[p, 1])
        L[b, 1] += m * (r2 * v[p, 0] - r0 * v[p, 2])
        L[b, 2] += m * (r0 * v[p, 1] - r1 * v[p, 0])
        r = (r0, r1, r2)
        for a in range(3):
            for d in range(3):
                q[b, a, d] += m * r[a] * r[d]
    for b in range(k):
        tr = q[b, 0, 0] + q[b, 1, 1] + q[b, 2, 2]
        I = -q[b]
        for a in range(3):
            I[a, a] += tr
        # the inverse of the symmetric 3 x 3 inertia by cofactors
        c00 = I[1, 1] * I[2, 2] - I[1, 2] * I[2, 1]
        c01 = I[0, 2] * I[2, 1] - I[0, 1] * I[2, 2]
        c02 = I[0, 1] * I[1, 2] - I[0, 2] * I[1, 1]
        c11 = I[0, 0] * I[2, 2] - I[0, 2] * I[2, 0]
        c12 = I[0, 2] * I[1, 0] - I[0, 0] * I[1, 2]
        c22 = I[0, 0] * I[1, 1] - I[0, 1] * I[1, 0]
        det = I[0, 0] * c00 + I[0, 1] * c01 + I[0, 2] * c02
        w[b, 0] = (c00 * L[b, 0] + c01 * L[b, 1] + c02 * L[b, 2]) / det
        w[b, 1] = (c01 * L[b, 0] + c11 * L[b, 1] + c12 * L[b, 2]) / det
        w[b, 2] = (c02 * L[b, 0] + c12 * L[b, 1] + c22 * L[b, 2]) / det


@njit(cache=True)
def _stretch(x, vertices, body, c, w, h, eps, out):
    """out[3 p + j] = e of vertex p (module docstring) for the bodies that turn (theta^2 / 2 > eps);
    returns whether any does."""
    k = c.shape[0]
    theta, axis = np.zeros(k), np.zeros((k, 3))
    turning = False
    for b in range(k):
        norm = np.sqrt(w[b, 0] ** 2 + w[b, 1] ** 2 + w[b, 2] ** 2)
        if 0.5 * (h * norm) ** 2 > eps:
            theta[b] = h * norm
            for j in range(3):
                axis[b, j] = w[b, j] / norm
            turning = True
    if not turning:
        return False
    for i in range(vertices.size):
        b, p = body[i], vertices[i]
        th = theta[b]
        if th == 0.0:
            continue
        a0, a1, a2 = axis[b, 0], axis[b, 1], axis[b, 2]
        r0, r1, r2 = x[p, 0] - c[b, 0], x[p, 1] - c[b, 1], x[p, 2] - c[b, 2]
        along = a0 * r0 + a1 * r1 + a2 * r2
        tangent, normal = th - np.sin(th), 2.0 * np.sin(0.5 * th) ** 2
        out[3 * p] = tangent * (a1 * r2 - a2 * r1) + normal * (r0 - along * a0)
        out[3 * p + 1] = tangent * (a2 * r0 - a0 * r2) + normal * (r1 - along * a1)
        out[3 * p + 2] = tangent * (a0 * r1 - a1 * r0) + normal * (r2 - along * a2)
    return True
