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

from skfem_affine.checks import positive, real_array

# a query point closer than this fraction of the shape's size to a point where the normal is
# undefined (a sphere's centre, a capsule's axis, the bowl's centre) takes a fixed unit normal
_RELATIVE_TINY = 1e-12


def _vector(value, name, size=3):
    a = real_array(value, name)
    if a.size != size:
        raise ValueError(f"{name} must be a {size}-vector, got shape {a.shape}")
    return a.reshape(size)


def _unit(value, name):
    a = _vector(value, name)
    units, _, zero = _unit_rows(a[None])
    if zero[0]:
        raise ValueError(f"{name} must be a non-zero vector, got {a.tolist()}")
    return units[0]


def check_points(points):
    """Query points as a float (k, 3) array; raises TypeError/ValueError naming the problem."""
    if isinstance(points, np.ndarray) and points.dtype == np.float64 and points.ndim == 2 and points.shape[1] == 3:
        p = points  # the per-frame path: no copy
        if not np.all(np.isfinite(p)):
            raise ValueError("points contain non-finite (NaN/inf) coordinates")
        return p
    p = real_array(points, "points")
    if p.ndim != 2 or p.shape[1] != 3:
        raise ValueError(f"points must have shape (k, 3), got {p.shape}")
    return p


def _unit_rows(v, tiny=0.0):
    """Rows of ``v`` (k, 3) scaled to unit length, their lengths, and the rows of length <= ``tiny``.

    The rows are divided by their largest entry before the norm is taken, so that very
    small (1e-200) or large vectors keep their direction; rows of length <= ``tiny``
    (``tiny`` may be an array) are returned as zero for the caller to replace.
    """
    scale = np.abs(v).max(axis=1)
    safe = np.where(scale > 0, scale, 1.0)
    w = v / safe[:, None]
    wn = np.linalg.norm(w, axis=1)
    length = scale * wn
    degenerate = ~(length > tiny) | (scale == 0)
    units = np.where(degenerate[:, None], 0.0, w / np.where(degenerate, 1.0, wn)[:, None])
    return units, length, degenerate


class Collider:
    """Base class: subclasses implement :meth:`_query` on validated (k, 3) points.

    Every collider returns finite distances and unit normals at every finite point,
    including points exactly on its surface, edges and corners, and the points where the
    gradient of the distance is undefined (a sphere's centre, a capsule's axis, a box's
    centre): there the normal is one of the valid escape directions.
    """

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
    """A solid ball: ``d = |x - c| - r``, normal ``(x - c) / |x - c|`` (+z at the centre)."""

    def __init__(self, center=(0.0, 0.0, 0.0), radius=1.0):
        self.center = _vector(center, "sphere center")
        self.radius = positive(radius, "sphere radius")

    def _query(self, p):
        n, r, centre = _unit_rows(p - self.center, _RELATIVE_TINY * self.radius)
        n[centre] = (0.0, 0.0, 1.0)  # the centre itself: every direction escapes
        return r - self.radius, n


class Box(Collider):
    """A solid box with ``half_extents`` about ``center``, axis-aligned or turned by ``rotation``.

    ``rotation`` (3, 3) has the box's axes as columns (world = R local); it must be a
    rotation (orthonormal, det +1). Outside, the distance is to the closest surface
    point; inside, minus the distance to the closest face (exact signed distance).
    On the surface and inside, the normal is that of the face of least penetration
    (at an edge, a corner or the centre, one of the faces that meet there).
    """

    def __init__(self, center=(0.0, 0.0, 0.0), half_extents=(0.5, 0.5, 0.5), rotation=None):
        self.center = _vector(center, "box center")
        self.half_extents = _vector(half_extents, "box half_extents")
        if np.any(self.half_extents <= 0):
            raise ValueError(f"box half_extents must be > 0, got {self.half_extents.tolist()}")
        if rotation is None:
            self.rotation = np.eye(3)
        else:
            R = real_array(rotation, "box rotation", shape=(3, 3))
            if not np.allclose(R.T @ R, np.eye(3), atol=1e-8) or np.linalg.det(R) < 0:
                raise ValueError("box rotation must be orthonormal with determinant +1")
            self.rotation = R

    def _query(self, p):
        q = (p - self.center) @ self.rotation      # local coordinates
        a = np.abs(q) - self.half_extents          # > 0: outside that pair of faces
        outside = np.any(a > 0, axis=1)
        sign = np.where(q >= 0, 1.0, -1.0)
        gap = np.maximum(a, 0.0) * sign            # from the closest surface point, in local axes
        n_local, dist_out, _ = _unit_rows(gap)     # exact zero only where all a <= 0 (not outside)
        # on the surface and inside: the face of least penetration
        k = np.argmax(a, axis=1)
        rows = np.flatnonzero(~outside)
        n_local[rows] = 0.0
        n_local[rows, k[rows]] = sign[rows, k[rows]]
        d = np.where(outside, dist_out, a.max(axis=1))
        return d, n_local @ self.rotation.T


class Capsule(Collider):
    """A solid capsule: points within ``radius`` of the segment from ``a`` to ``b``.

    On the segment itself the normal is a fixed direction perpendicular to it.
    """

    def __init__(self, a=(0.0, 0.0, 0.0), b=(1.0, 0.0, 0.0), radius=0.25):
        self.a = _vector(a, "capsule end a")
        self.b = _vector(b, "capsule end b")
        self.radius = positive(radius, "capsule radius")
        self._axis = self.b - self.a
        self._len2 = float(self._axis @ self._axis)
        if not np.sqrt(self._len2) > 1e-9 * self.radius or not np.isfinite(self._len2):
            raise ValueError(f"capsule ends a and b coincide (|b - a| = {np.sqrt(self._len2):g}, radius "
                             f"{self.radius:g}); use a Sphere")
        direction = self._axis / np.sqrt(self._len2)
        helper = np.eye(3)[np.argmin(np.abs(direction))]  # the axis least aligned with the segment
        side = np.cross(direction, helper)
        self._side = side / np.linalg.norm(side)

    def _query(self, p):
        s = np.clip((p - self.a) @ self._axis / self._len2, 0.0, 1.0)
        n, r, on_axis = _unit_rows(p - (self.a + s[:, None] * self._axis), _RELATIVE_TINY * self.radius)
        n[on_axis] = self._side  # on the segment: any direction normal to it escapes
        return r - self.radius, n


class Bowl(Collider):
    """A hemispherical shell of inner radius ``radius`` and ``thickness``, open towards +z.

    The shell is the set ``radius <= |x - c| <= radius + thickness`` with ``z <= c_z``;
    bodies rest on its inner surface. Above the rim plane the distance is to the
    rim (a flat ring). The signed distance is exact; inside the shell the normal
    points to the nearer of its two surfaces; at the centre it is +z (out of the bowl).
    ``thickness`` must not exceed ``radius`` (default ``0.2 * radius``).
    """

    def __init__(self, center=(0.0, 0.0, 0.0), radius=1.0, thickness=None):
        self.center = _vector(center, "bowl center")
        self.radius = positive(radius, "bowl radius")
        self.thickness = positive(0.2 * self.radius if thickness is None else thickness, "bowl thickness")
        if self.thickness > self.radius:
            raise ValueError(f"bowl thickness ({self.thickness:g}) must not exceed its radius ({self.radius:g})")

    def _query(self, p):
        q = p - self.center
        R, t = self.radius, self.thickness
        mid = R + 0.5 * t
        n_sph, r, centre = _unit_rows(q, _RELATIVE_TINY * R)
        side = np.where(r < mid, -1.0, 1.0)
        d = np.abs(r - mid) - 0.5 * t
        n = side[:, None] * n_sph
        n[centre] = (0.0, 0.0, 1.0)  # the centre: every direction is as far from the shell; leave upwards
        above = q[:, 2] > 0
        if np.any(above):
            qa = q[above]
            radial, rho, on_axis = _unit_rows(np.column_stack([qa[:, :2], np.zeros(len(qa))]), _RELATIVE_TINY * R)
            radial[on_axis] = (1.0, 0.0, 0.0)
            s = np.clip(rho, R, R + t)                  # nearest point of the rim ring
            diff = (rho - s)[:, None] * radial + qa[:, 2:3] * np.array([0.0, 0.0, 1.0])
            na, da, _ = _unit_rows(diff)                # z > 0: never the zero vector
            d[above], n[above] = da, na
        return d, n


class SDFCollider(Collider):
    """Any signed distance given by the user: ``fn(points (k, 3)) -> (distance (k,), normal (k, 3))``.

    The function must be vectorised over points, return negative distances inside the
    obstacle and outward normals (they are normalised here). Its outputs are checked
    on every query: a result that is not a pair, wrong shapes, values that are not real
    numbers, non-finite values or zero normals raise a ValueError naming the SDF.
    """

    def __init__(self, fn, name=None):
        if not callable(fn):
            hint = " (it is already a collider: pass it directly)" if hasattr(fn, "query") else ""
            raise TypeError(f"SDFCollider needs a callable fn(points) -> (distance, normal), "
                            f"got {type(fn).__name__}{hint}")
        if name is not None and not isinstance(name, str):
            raise TypeError(f"SDFCollider name must be a str or None, got {type(name).__name__}")
        self.fn = fn
        self.name = name or getattr(fn, "__name__", "sdf")

    def __repr__(self):
        return f"SDFCollider({self.name})"

    def _query(self, p):
        out = self.fn(p)
        if not isinstance(out, (tuple, list)) or len(out) != 2:
            raise ValueError(f"SDF {self.name!r} must return a pair (distance, normal), got {type(out).__name__}"
                             f"{f' of length {len(out)}' if isinstance(out, (tuple, list)) else ''}")
        k = p.shape[0]
        try:
            d = real_array(out[0], f"SDF {self.name!r} distance", shape=(k,))
            n = real_array(out[1], f"SDF {self.name!r} normal", shape=(k, 3))
        except TypeError as err:
            raise ValueError(str(err)) from None
        except ValueError as err:
            raise ValueError(f"{err} (for {k} query points the SDF must return distance ({k},) and "
                             f"normal ({k}, 3))") from None
        n, _, zero = _unit_rows(n)
        if np.any(zero):
            raise ValueError(f"SDF {self.name!r} returned zero normals at {int(zero.sum())} points "
                             f"(first at {p[np.argmax(zero)].tolist()})")
        return d, n


def check_colliders(colliders):
    """A list of collider instances from one collider, a sequence of them or None.

    Raises
    ------
    TypeError
        An entry is a class (``sa.Plane`` instead of ``sa.Plane()``) or has no
        ``query(points) -> (distance, normal)``, or ``colliders`` is not iterable;
        the message names the entry.
    """
    hint = "use sa.Plane(), sa.Sphere(), sa.Box(), sa.Capsule(), sa.Bowl() or sa.SDFCollider(fn)"
    if colliders is None:
        return []
    if hasattr(colliders, "query"):
        colliders = [colliders]
    if isinstance(colliders, (str, bytes, dict)) or not hasattr(colliders, "__iter__"):
        raise TypeError(f"colliders must be a collider or a list of them, got {type(colliders).__name__}; {hint}")
    out = list(colliders)
    for i, c in enumerate(out):
        if isinstance(c, type):
            raise TypeError(f"colliders[{i}] is the class {c.__name__}, not a collider: "
                            f"write {c.__name__}(...) with its parameters")
        if not callable(getattr(c, "query", None)):
            raise TypeError(f"colliders[{i}] ({type(c).__name__}) has no query(points) -> (distance, normal); {hint}")
    return out
