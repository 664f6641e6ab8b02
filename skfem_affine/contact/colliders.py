r"""Static colliders as signed distance functions (paper sec. 3.1: the contact Jacobian is built
from signed distance queries).

Every collider answers one vectorised question,

.. code-block:: python

    distance, normal = collider.query(points)   # points (k, 3) -> (k,), (k, 3)

with ``distance < 0`` inside the obstacle (penetration) and ``normal`` the unit
outward normal of the obstacle at the closest surface point (the gradient of the
signed distance), so that a point escapes along ``+normal``. A contact is then
the row ``n^T`` of the Jacobian acting on the vertex velocity (see
:mod:`skfem_affine.contact`).

All shapes are closed-form: :class:`Plane`, :class:`Sphere`, :class:`Box`
(axis-aligned, or oriented by a rotation matrix), :class:`Capsule`,
:class:`Bowl` (a hemispherical shell, open at the top) and :class:`SDFCollider`
for any user function ``fn(points) -> (distance, normal)``.
"""
import numpy as np

from skfem_affine.checks import positive

_TINY = 1e-12


def _vector(value, name, size=3):
    try:
        a = np.array(value, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise TypeError(f"{name} must be a {size}-vector of numbers, got {value!r}") from None
    if a.shape != (size,):
        raise ValueError(f"{name} must be a {size}-vector, got shape {np.shape(value)}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name} must be finite, got {value!r}")
    return a


def _unit(value, name):
    a = _vector(value, name)
    norm = np.linalg.norm(a)
    if norm < _TINY:
        raise ValueError(f"{name} must be a non-zero vector, got {value!r}")
    return a / norm


def check_points(points):
    """Query points as a float (k, 3) array; raises TypeError/ValueError naming the problem."""
    try:
        p = np.asarray(points, dtype=float)
    except (TypeError, ValueError):
        raise TypeError(f"points must be a (k, 3) array of numbers, got {type(points).__name__}") from None
    if p.ndim != 2 or p.shape[1] != 3:
        raise ValueError(f"points must have shape (k, 3), got {p.shape}")
    if not np.all(np.isfinite(p)):
        raise ValueError("points contain non-finite (NaN/inf) coordinates")
    return p


def _normalised(v):
    """Rows of v divided by their norm; zero rows stay zero."""
    n = np.linalg.norm(v, axis=1, keepdims=True)
    return np.where(n > _TINY, v / np.maximum(n, _TINY), 0.0), n[:, 0]


class Collider:
    """Base class: subclasses implement :meth:`_query` on validated (k, 3) points."""

    def query(self, points):
        """Signed distance (k,) (negative inside) and unit outward normal (k, 3) at each point."""
        p = check_points(points)
        if p.shape[0] == 0:
            return np.zeros(0), np.zeros((0, 3))
        return self._query(p)

    def _query(self, p):  # pragma: no cover - interface
        raise NotImplementedError

    def __repr__(self):
        fields = ", ".join(f"{k}={np.round(v, 6).tolist() if isinstance(v, np.ndarray) else v}"
                           for k, v in vars(self).items() if not k.startswith("_"))
        return f"{type(self).__name__}({fields})"


class Plane(Collider):
    """The half-space below the plane through ``point`` with outward ``normal``: d = (x - p) . n."""

    def __init__(self, point=(0.0, 0.0, 0.0), normal=(0.0, 0.0, 1.0)):
        self.point = _vector(point, "plane point")
        self.normal = _unit(normal, "plane normal")

    def _query(self, p):
        d = (p - self.point) @ self.normal
        return d, np.broadcast_to(self.normal, p.shape).copy()


class Sphere(Collider):
    """A solid ball: ``d = |x - c| - r``, normal ``(x - c) / |x - c|``."""

    def __init__(self, center=(0.0, 0.0, 0.0), radius=1.0):
        self.center = _vector(center, "sphere center")
        self.radius = positive(radius, "sphere radius")

    def _query(self, p):
        n, r = _normalised(p - self.center)
        n[r <= _TINY] = (0.0, 0.0, 1.0)  # the centre itself: any direction
        return r - self.radius, n


class Box(Collider):
    """A solid box with ``half_extents`` about ``center``, axis-aligned or turned by ``rotation``.

    ``rotation`` (3, 3) has the box's axes as columns (world = R local); it must be a
    rotation (orthonormal, det +1). Outside, the distance is to the closest surface
    point; inside, minus the distance to the closest face (exact signed distance).
    """

    def __init__(self, center=(0.0, 0.0, 0.0), half_extents=(0.5, 0.5, 0.5), rotation=None):
        self.center = _vector(center, "box center")
        self.half_extents = _vector(half_extents, "box half_extents")
        if np.any(self.half_extents <= 0):
            raise ValueError(f"box half_extents must be > 0, got {half_extents!r}")
        if rotation is None:
            self.rotation = np.eye(3)
        else:
            R = np.array(rotation, dtype=float)
            if R.shape != (3, 3) or not np.all(np.isfinite(R)):
                raise ValueError(f"box rotation must be a finite 3x3 matrix, got shape {R.shape}")
            if not np.allclose(R.T @ R, np.eye(3), atol=1e-8) or np.linalg.det(R) < 0:
                raise ValueError("box rotation must be orthonormal with determinant +1")
            self.rotation = R

    def _query(self, p):
        q = (p - self.center) @ self.rotation      # local coordinates
        a = np.abs(q) - self.half_extents
        outside = np.maximum(a, 0.0)
        dist_out = np.linalg.norm(outside, axis=1)
        inside = dist_out <= 0.0
        n_local = np.sign(q) * outside
        # inside: the face of least penetration
        k = np.argmax(a, axis=1)
        rows = np.flatnonzero(inside)
        n_local[rows] = 0.0
        n_local[rows, k[rows]] = np.where(q[rows, k[rows]] >= 0, 1.0, -1.0)
        n_local, _ = _normalised(n_local)
        d = np.where(inside, a.max(axis=1), dist_out)
        return d, n_local @ self.rotation.T


class Capsule(Collider):
    """A solid capsule: points within ``radius`` of the segment from ``a`` to ``b``."""

    def __init__(self, a=(0.0, 0.0, 0.0), b=(1.0, 0.0, 0.0), radius=0.25):
        self.a = _vector(a, "capsule end a")
        self.b = _vector(b, "capsule end b")
        self.radius = positive(radius, "capsule radius")
        self._axis = self.b - self.a
        self._len2 = float(self._axis @ self._axis)
        if self._len2 < _TINY:
            raise ValueError("capsule ends a and b coincide (use a Sphere)")

    def _query(self, p):
        s = np.clip((p - self.a) @ self._axis / self._len2, 0.0, 1.0)
        n, r = _normalised(p - (self.a + s[:, None] * self._axis))
        if np.any(r <= _TINY):  # on the axis: any direction normal to it
            side = np.cross(self._axis, (1.0, 0.0, 0.0) if abs(self._axis[0]) < 0.9 * np.sqrt(self._len2)
                            else (0.0, 1.0, 0.0))
            n[r <= _TINY] = side / np.linalg.norm(side)
        return r - self.radius, n


class Bowl(Collider):
    """A hemispherical shell of inner radius ``radius`` and ``thickness``, open towards +z.

    The shell is the set ``radius <= |x - c| <= radius + thickness`` with ``z <= c_z``;
    bodies rest on its inner surface. Above the rim plane the distance is to the
    rim (a flat ring). The signed distance is exact; inside the shell the normal
    points to the nearer of its two surfaces.
    """

    def __init__(self, center=(0.0, 0.0, 0.0), radius=1.0, thickness=None):
        self.center = _vector(center, "bowl center")
        self.radius = positive(radius, "bowl radius")
        self.thickness = positive(0.2 * self.radius if thickness is None else thickness, "bowl thickness")

    def _query(self, p):
        q = p - self.center
        R, t = self.radius, self.thickness
        mid = R + 0.5 * t
        n_sph, r = _normalised(q)
        n_sph[r <= _TINY] = (0.0, 0.0, 1.0)
        side = np.sign(r - mid)
        side[side == 0] = 1.0
        d = np.abs(r - mid) - 0.5 * t
        n = side[:, None] * n_sph
        above = q[:, 2] > 0
        if np.any(above):
            qa = q[above]
            radial, rho = _normalised(np.column_stack([qa[:, :2], np.zeros(len(qa))]))
            radial[rho <= _TINY] = (1.0, 0.0, 0.0)
            s = np.clip(rho, R, R + t)                  # nearest point of the rim ring
            diff = (rho - s)[:, None] * radial + qa[:, 2:3] * np.array([0.0, 0.0, 1.0])
            na, da = _normalised(diff)
            na[da <= _TINY] = (0.0, 0.0, 1.0)
            d[above], n[above] = da, na
        return d, n


class SDFCollider(Collider):
    """Any signed distance given by the user: ``fn(points (k, 3)) -> (distance (k,), normal (k, 3))``.

    The function must be vectorised over points, return negative distances inside the
    obstacle and outward normals (they are normalised here). Its outputs are checked
    on every query: wrong shapes or non-finite values raise a ValueError.
    """

    def __init__(self, fn, name=None):
        if not callable(fn):
            raise TypeError(f"SDFCollider needs a callable fn(points) -> (distance, normal), got {type(fn).__name__}")
        self.fn = fn
        self.name = name or getattr(fn, "__name__", "sdf")

    def __repr__(self):
        return f"SDFCollider({self.name})"

    def _query(self, p):
        try:
            d, n = self.fn(p)
        except (TypeError, ValueError) as err:
            if "unpack" in str(err):
                raise ValueError(f"SDF {self.name!r} must return a pair (distance, normal)") from err
            raise
        d = np.asarray(d, dtype=float)
        n = np.asarray(n, dtype=float)
        k = p.shape[0]
        if d.shape != (k,) or n.shape != (k, 3):
            raise ValueError(f"SDF {self.name!r} must return distance ({k},) and normal ({k}, 3), "
                             f"got {d.shape} and {n.shape}")
        if not (np.all(np.isfinite(d)) and np.all(np.isfinite(n))):
            raise ValueError(f"SDF {self.name!r} returned non-finite distances or normals")
        n, norm = _normalised(n)
        if np.any(norm <= _TINY):
            raise ValueError(f"SDF {self.name!r} returned zero normals at {int(np.sum(norm <= _TINY))} points")
        return d, n


def check_colliders(colliders):
    """A list of colliders (objects with ``query``); raises TypeError naming a bad entry."""
    if colliders is None:
        return []
    if hasattr(colliders, "query"):
        colliders = [colliders]
    out = list(colliders)
    for i, c in enumerate(out):
        if not callable(getattr(c, "query", None)):
            raise TypeError(f"collider {i} ({type(c).__name__}) has no query(points) -> (distance, normal); "
                            f"use sa.Plane, sa.Sphere, sa.Box, sa.Capsule, sa.Bowl or sa.SDFCollider(fn)")
    return out
