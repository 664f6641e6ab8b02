r"""Kinematics of P1 tetrahedra: shape gradients, volumes, and the operator B.

Conventions, used everywhere in the package:

* positions ``x`` and velocities ``v`` are ``(n, 3)`` arrays; flattened, the
  DOF order is node-major, ``3 * vertex + component``, exactly as
  ``skfem.Basis(mesh, ElementVector(ElementTetP1())).nodal_dofs``;
* element data carry the element index on the leading axis, ``(m, ...)``;
* a deformation gradient is flattened row-major, ``F_ij -> 9 e + 3 i + j``.

For P1 elements the deformation gradient is constant per element,

.. math:: F_e = \sum_k x_{t_k e} \otimes \nabla \phi_k, \qquad F = B x, \qquad
          \dot F = B \dot x       \qquad\text{(paper eq. 3-4)}.
"""
import numpy as np
import scipy.sparse as sp
from skfem import CellBasis, ElementTetP1


def shape_gradients(mesh):
    """Rest gradients of the four P1 shape functions and element volumes.

    Taken from a scikit-fem ``CellBasis`` with a one-point rule (P1 gradients
    are constant per element).

    Returns
    -------
    grads : (m, 4, 3) array, ``grads[e, k] = grad phi_k`` on element ``e``.
    volumes : (m,) array of (positive) rest volumes.
    """
    basis = CellBasis(mesh, ElementTetP1(), intorder=1)
    grads = np.stack([basis.basis[k][0].grad[:, :, 0].T for k in range(4)], axis=1)
    return np.ascontiguousarray(grads), basis.dx[:, 0].copy()


def deformation_gradient(x, t, grads):
    """F_e = sum_k x_k (x) grad phi_k for all elements (eq. 3); ``(m, 3, 3)``.

    Parameters: ``x`` (n, 3) positions (or velocities, giving F_dot, eq. 4),
    ``t`` (4, m) element vertices, ``grads`` from :func:`shape_gradients`.
    """
    return np.einsum("kei,ekj->eij", x[t], grads, optimize=True)


def deformation_operator(t, grads, n_vertices):
    """Sparse B (9m x 3n) with ``(B x)[9e + 3i + j] = F_e[i, j]`` (eq. 3)."""
    m = t.shape[1]
    e, k, i, j = np.meshgrid(np.arange(m), np.arange(4), np.arange(3), np.arange(3), indexing="ij")
    rows = 9 * e + 3 * i + j
    cols = 3 * t[k, e] + i
    vals = grads[e, k, j]
    return sp.csr_matrix((vals.ravel(), (rows.ravel(), cols.ravel())), shape=(9 * m, 3 * n_vertices))


def element_dofs(t):
    """Global DOFs of each element, ``(m, 12)``, node-major (matches scikit-fem)."""
    return (3 * t.T[:, :, None] + np.arange(3)).reshape(-1, 12)


def signed_volumes(p, t):
    """Signed volumes det[x1-x0, x2-x0, x3-x0] / 6 of the elements; ``(m,)``."""
    x = p.T[t]  # (4, m, 3)
    return np.linalg.det(np.stack([x[1] - x[0], x[2] - x[0], x[3] - x[0]], axis=-1)) / 6.0
