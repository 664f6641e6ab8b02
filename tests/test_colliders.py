"""Static colliders: signed distances against closed forms, normals against finite differences, bad input."""
import numpy as np
import pytest

import skfem_affine as sa
from skfem_affine.contact.colliders import Collider


def _rotation(axis, angle):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


COLLIDERS = {
    "plane": sa.Plane(point=(0.1, -0.2, 0.3), normal=(1.0, 2.0, 2.0)),
    "sphere": sa.Sphere(center=(0.2, 0.0, -0.1), radius=0.7),
    "box": sa.Box(center=(0.1, 0.2, 0.0), half_extents=(0.5, 0.3, 0.4)),
    "oriented_box": sa.Box(center=(0.1, 0.2, 0.0), half_extents=(0.5, 0.3, 0.4),
                           rotation=_rotation((1, 1, 0), 0.6)),
    "capsule": sa.Capsule(a=(-0.4, 0.0, 0.1), b=(0.5, 0.3, -0.2), radius=0.3),
    "bowl": sa.Bowl(center=(0.0, 0.0, 0.0), radius=0.8, thickness=0.2),
}


@pytest.mark.parametrize("name", sorted(COLLIDERS))
def test_normal_is_the_gradient_of_the_distance(name):
    col = COLLIDERS[name]
    rng = np.random.default_rng(1)
    p = rng.uniform(-1.2, 1.2, (400, 3))
    d, n = col.query(p)
    assert d.shape == (400,) and n.shape == (400, 3)
    assert np.allclose(np.linalg.norm(n, axis=1), 1.0)
    eps = 1e-6
    grad = np.column_stack([(col.query(p + eps * e)[0] - col.query(p - eps * e)[0]) / (2 * eps) for e in np.eye(3)])
    smooth = np.linalg.norm(grad, axis=1) > 0.999  # away from kinks (medial axis), |grad d| = 1
    assert smooth.mean() > 0.9
    assert np.allclose(grad[smooth], n[smooth], atol=1e-4)


def test_closed_forms():
    p = np.array([[0.0, 0.0, 2.0], [0.0, 0.0, 0.5], [2.0, 0.0, 0.0]])
    d, n = sa.Sphere(radius=1.0).query(p)
    assert np.allclose(d, [1.0, -0.5, 1.0]) and np.allclose(n[0], [0, 0, 1])
    d, n = sa.Plane(point=(0, 0, 1), normal=(0, 0, 2)).query(p)
    assert np.allclose(d, [1.0, -0.5, -1.0]) and np.allclose(n, [0, 0, 1])
    box = sa.Box(half_extents=(1.0, 0.5, 0.25))
    d, n = box.query(np.array([[0.0, 0.0, 0.0], [2.0, 1.5, 0.0], [0.9, 0.0, 0.0]]))
    assert np.allclose(d, [-0.25, np.sqrt(2.0), -0.1])
    assert np.allclose(n[0], [0, 0, 1]) and np.allclose(n[2], [1, 0, 0])
    # an oriented box is the axis-aligned one seen in turned coordinates
    R = _rotation((0.3, -1.0, 0.5), 1.1)
    turned = sa.Box(center=(1, 2, 3), half_extents=(1.0, 0.5, 0.25), rotation=R)
    q = np.random.default_rng(0).normal(size=(50, 3))
    d0, n0 = box.query(q)
    d1, n1 = turned.query(q @ R.T + (1, 2, 3))
    assert np.allclose(d0, d1) and np.allclose(n0 @ R.T, n1)
    capsule = sa.Capsule(a=(0, 0, 0), b=(2, 0, 0), radius=0.5)
    d, _ = capsule.query(np.array([[1.0, 0, 1.0], [-1.0, 0, 0], [1.0, 0.2, 0]]))
    assert np.allclose(d, [0.5, 0.5, -0.3])


def test_bowl_holds_bodies_inside():
    bowl = sa.Bowl(center=(0, 0, 1.0), radius=1.0, thickness=0.1)
    p = np.array([[0.0, 0.0, 0.2], [0.0, 0.0, -0.02], [0.0, 0.0, -0.2], [0.0, 0.0, 1.5], [1.05, 0.0, 1.3]])
    d, n = bowl.query(p)
    # inside the cavity the distance is to the inner surface and pushes towards the centre
    assert d[0] == pytest.approx(0.2) and np.allclose(n[0], [0, 0, 1])
    assert d[1] == pytest.approx(-0.02) and np.allclose(n[1], [0, 0, 1])   # in the shell, nearer the inside
    assert d[2] == pytest.approx(0.1) and np.allclose(n[2], [0, 0, -1])    # below the shell
    assert d[3] == pytest.approx(np.hypot(1.0, 0.5))                       # above: distance to the rim
    assert d[4] == pytest.approx(0.3) and np.allclose(n[4], [0, 0, 1])     # straight above the rim


def test_sdf_collider_equals_the_built_in_shape():
    def ball(points):
        r = np.linalg.norm(points, axis=1)
        return r - 0.5, 3.0 * points / r[:, None]  # unnormalised normals are accepted

    p = np.random.default_rng(2).normal(size=(30, 3))
    d0, n0 = sa.Sphere(radius=0.5).query(p)
    d1, n1 = sa.SDFCollider(ball).query(p)
    assert np.allclose(d0, d1) and np.allclose(n0, n1)
    assert isinstance(sa.SDFCollider(ball), Collider)


def test_bad_collider_input_raises_clearly():
    with pytest.raises(ValueError, match="non-zero"):
        sa.Plane(normal=(0, 0, 0))
    with pytest.raises(ValueError, match="3-vector"):
        sa.Plane(point=(0, 0))
    with pytest.raises(ValueError, match="finite"):
        sa.Sphere(center=(0, np.nan, 0))
    with pytest.raises(ValueError, match="radius"):
        sa.Sphere(radius=-1)
    with pytest.raises(TypeError, match="radius"):
        sa.Capsule(radius="big")
    with pytest.raises(ValueError, match="half_extents"):
        sa.Box(half_extents=(1, 0, 1))
    with pytest.raises(ValueError, match="orthonormal"):
        sa.Box(rotation=np.diag([1.0, 2.0, 1.0]))
    with pytest.raises(ValueError, match="coincide"):
        sa.Capsule(a=(1, 1, 1), b=(1, 1, 1))
    with pytest.raises(ValueError, match="thickness"):
        sa.Bowl(thickness=0)
    with pytest.raises(ValueError, match=r"shape \(k, 3\)"):
        sa.Plane().query(np.zeros((4, 2)))
    with pytest.raises(ValueError, match="non-finite"):
        sa.Sphere().query([[0, 0, np.inf]])
    with pytest.raises(TypeError, match="callable"):
        sa.SDFCollider(3.0)
    with pytest.raises(ValueError, match="pair"):
        sa.SDFCollider(lambda p: p[:, 0]).query(np.zeros((3, 3)))
    with pytest.raises(ValueError, match=r"distance \(3,\) and normal \(3, 3\)"):
        sa.SDFCollider(lambda p: (p[:, 0], p[:, :2])).query(np.zeros((3, 3)))
    with pytest.raises(ValueError, match="non-finite"):
        sa.SDFCollider(lambda p: (np.full(len(p), np.nan), p)).query(np.ones((3, 3)))
    with pytest.raises(ValueError, match="zero normals"):
        sa.SDFCollider(lambda p: (p[:, 0], 0 * p)).query(np.ones((3, 3)))
    body = sa.scenes.free_body(resolution=1).bodies[0]
    with pytest.raises(TypeError, match="no query"):
        sa.Simulation(body, colliders=[sa.Plane(), "floor"])
    with pytest.raises(TypeError, match="sa.PGS"):
        sa.Simulation(body, colliders=[sa.Plane()], contact="pgs")
    with pytest.raises(ValueError, match="contact=False"):
        sa.Simulation(body, colliders=[sa.Plane()], contact=False)
    other = sa.scenes.free_body(resolution=1).bodies[0]
    assert sa.Simulation([body, other], contact=False).contact is None       # two bodies, contact off
    assert sa.Simulation(body, colliders=sa.Plane()).colliders[0].normal[2] == 1.0  # one collider, no list
    with pytest.raises(ValueError, match="friction"):
        sa.PGS(friction=-0.1)
    with pytest.raises(ValueError, match="iterations"):
        sa.PGS(iterations=0)
    with pytest.raises(ValueError, match="erp"):
        sa.PGS(erp=2.0)


def _special_points(col):
    """Points where normals are easy to get wrong: exact surface, edges, corners, centres, axes,
    just inside/outside by one ulp or by subnormal amounts, and far away."""
    pts = [np.zeros(3), np.full(3, 1e-300), np.full(3, -1e-300), [1e300, -1e300, 1e300], [0, 0, 1e200]]
    if isinstance(col, sa.Sphere):
        c, r = col.center, col.radius
        dirs = np.vstack([np.eye(3), -np.eye(3), np.ones((1, 3)) / np.sqrt(3)])
        pts += [c, c + 1e-300, c + 1e-14 * r * dirs[0]]
        pts += list(c + r * dirs) + list(c + np.nextafter(r, 0) * dirs) + list(c + np.nextafter(r, 2 * r) * dirs)
    elif isinstance(col, sa.Box):
        c, h, R = col.center, col.half_extents, col.rotation
        signs = np.array(np.meshgrid([-1, 0, 1], [-1, 0, 1], [-1, 0, 1])).reshape(3, -1).T  # centre, faces, edges, corners
        local = []
        for f in (1.0, 1.0 - 1e-16, 1.0 + 1e-16, 1.0 + 1e-13, 1.0 - 1e-13, 2.0):
            local += list(signs * h * f)
        pts += list(np.array(local) @ R.T + c)
    elif isinstance(col, sa.Capsule):
        a, b, r = col.a, col.b, col.radius
        ax = (b - a) / np.linalg.norm(b - a)
        side = col._side
        for s in (0.0, 0.5, 1.0, -0.1, 1.1):
            q = a + s * (b - a)
            pts += [q, q + r * side, q + np.nextafter(r, 0) * side, q + 1e-300 * side]
        pts += [a - r * ax, b + r * ax]
    elif isinstance(col, sa.Bowl):
        c, R, t = col.center, col.radius, col.thickness
        for rho in (0.0, R, R + 0.5 * t, R + t, np.nextafter(R, 0), np.nextafter(R + t, 2 * R)):
            for z in (0.0, 1e-300, -1e-300, 1e-16, -1e-16, 0.5 * R, -0.5 * R):
                pts.append(c + (rho, 0.0, z))
        for r in (0.0, R, R + t, R + 0.5 * t):
            pts.append(c + (0.0, 0.0, -r))
            pts.append(c - r * np.array([1.0, 1.0, 1.0]) / np.sqrt(3))
    elif isinstance(col, sa.Plane):
        pts += [col.point, col.point + 1e-300 * col.normal, col.point - col.normal]
    return np.array(pts, dtype=float)


@pytest.mark.parametrize("name", sorted(COLLIDERS))
def test_normals_are_unit_everywhere_including_degenerate_points(name):
    col = COLLIDERS[name]
    rng = np.random.default_rng(3)
    p = np.vstack([_special_points(col), rng.uniform(-1.5, 1.5, (2000, 3)),
                   rng.normal(size=(200, 3)) * np.logspace(-300, 300, 200)[:, None]])
    d, n = col.query(p)
    assert np.all(np.isfinite(d)) and np.all(np.isfinite(n))
    assert np.allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-12)


def test_box_normal_just_outside_a_face_edge_and_corner():
    box = sa.Box(half_extents=(1.0, 2.0, 3.0))
    eps = 1e-13
    p = np.array([[1 + eps, 0, 0], [0, -2 - eps, 0], [1 + eps, 2 + eps, 0], [1 + eps, 2 + eps, 3 + eps],
                  [1, 0, 0], [0, 0, 0], [1, 2, 3]])
    d, n = box.query(p)
    assert np.allclose(n[0], [1, 0, 0]) and np.allclose(n[1], [0, -1, 0])
    assert np.allclose(n[2], [1, 1, 0] / np.sqrt(2)) and np.allclose(n[3], np.ones(3) / np.sqrt(3))
    assert np.allclose(n[4], [1, 0, 0]) and d[4] == 0.0           # on a face: that face
    assert np.allclose(n[5], [1, 0, 0]) and d[5] == -1.0   # centre: the nearest face
    assert d[6] == 0.0 and np.isclose(np.linalg.norm(n[6]), 1.0)   # corner: one of its faces


def test_degenerate_points_have_an_escape_normal():
    d, n = sa.Sphere(center=(1, 2, 3), radius=0.5).query([[1, 2, 3]])
    assert d[0] == -0.5 and np.allclose(n, [[0, 0, 1]])
    cap = sa.Capsule(a=(0, 0, 0), b=(0, 0, 2), radius=0.3)
    d, n = cap.query([[0, 0, 0], [0, 0, 1], [0, 0, 2]])
    assert np.allclose(d, -0.3) and np.allclose(n[:, 2], 0.0) and np.allclose(np.linalg.norm(n, axis=1), 1.0)
    bowl = sa.Bowl(center=(0, 0, 1), radius=1.0, thickness=0.1)
    d, n = bowl.query([[0, 0, 1]])
    assert d[0] == pytest.approx(1.0) and np.allclose(n, [[0, 0, 1]])  # the centre: leave upwards


@pytest.mark.parametrize("make, match", [
    (lambda: sa.Bowl(radius=1.0, thickness=1.5), "thickness.*must not exceed"),
    (lambda: sa.Capsule(a=(0, 0, 0), b=(0, 0, 1e-12), radius=1.0), "coincide"),
    (lambda: sa.Sphere(radius=True), "radius"),
    (lambda: sa.Sphere(radius="1"), "radius"),
    (lambda: sa.Sphere(center="abc"), "center"),
    (lambda: sa.Sphere(center=(0, 0, 1j)), "center"),
    (lambda: sa.Box(rotation="identity"), "rotation"),
    (lambda: sa.Box(rotation=np.eye(2)), "rotation"),
    (lambda: sa.Box(half_extents=(1, np.inf, 1)), "half_extents"),
    (lambda: sa.Box(half_extents=(1, 1)), "half_extents"),
    (lambda: sa.Plane(normal=(True, False, False)), "normal"),
    (lambda: sa.Plane(point=None), "point"),
    (lambda: sa.Bowl(radius=np.nan), "radius"),
    (lambda: sa.Capsule(radius=[1, 2]), "radius"),
    (lambda: sa.SDFCollider(sa.Sphere()), "already a collider"),
    (lambda: sa.SDFCollider(lambda p: p, name=3), "name"),
])
def test_impossible_collider_parameters_are_refused(make, match):
    with pytest.raises((TypeError, ValueError), match=match):
        make()


def _sphere_sdf(p):
    r = np.linalg.norm(p, axis=1)
    return r - 0.5, p


@pytest.mark.parametrize("fn, match", [
    (lambda p: None, "pair"),
    (lambda p: (p[:, 0], p, p), "pair"),
    (lambda p: np.zeros((2, len(p))), "pair"),
    (lambda p: (p[:, 0], p.T), r"normal must have shape \(4, 3\)"),
    (lambda p: (p[:, :1], p), r"distance must have shape \(4,\)"),
    (lambda p: (p[:, 0].astype(str), p), "distance must be a real number"),
    (lambda p: (p[:, 0] + 1j, p), "distance"),
    (lambda p: (p[:, 0] > 0, p), "distance"),
    (lambda p: (p[:, 0], np.full(p.shape, np.inf)), "non-finite"),
    (lambda p: (p[:, 0], np.where(p[:, :1] > 0.5, 0.0, p)), "zero normals"),
])
def test_sdf_collider_checks_what_the_user_function_returns(fn, match):
    p = np.array([[0.1, 0.2, 0.3], [1.0, 0.0, 0.0], [0.0, 2.0, 0.0], [0.0, 0.0, -1.0]])
    with pytest.raises(ValueError, match=match):
        sa.SDFCollider(fn, name="mine").query(p)


def test_sdf_collider_normalises_tiny_and_huge_normals():
    p = np.array([[0.1, 0.2, 0.3], [1.0, 0.0, 0.0]])
    d, n = sa.SDFCollider(lambda q: (q[:, 0], q * np.array([[1e-200], [1e200]]))).query(p)
    assert np.allclose(n, p / np.linalg.norm(p, axis=1, keepdims=True))
    d, n = sa.SDFCollider(lambda q: (list(q[:, 0]), q.tolist())).query(p)  # lists are accepted
    assert np.allclose(d, p[:, 0])


def test_colliders_must_be_instances():
    from skfem_affine.contact.colliders import check_colliders
    with pytest.raises(TypeError, match="class Plane.*Plane\\(...\\)"):
        check_colliders([sa.Plane])
    with pytest.raises(TypeError, match="class Sphere"):
        check_colliders(sa.Sphere)
    with pytest.raises(TypeError, match=r"colliders\[1\]"):
        check_colliders([sa.Plane(), "floor"])
    with pytest.raises(TypeError, match="colliders must be"):
        check_colliders(3.0)
    with pytest.raises(TypeError, match="colliders must be"):
        check_colliders("floor")
    assert check_colliders(None) == [] and len(check_colliders((sa.Plane(), sa.Sphere()))) == 2
