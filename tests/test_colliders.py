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
    assert sa.Simulation([body, body], contact=False).contact is None        # two bodies, contact off
    assert sa.Simulation(body, colliders=sa.Plane()).colliders[0].normal[2] == 1.0  # one collider, no list
    with pytest.raises(ValueError, match="friction"):
        sa.PGS(friction=-0.1)
    with pytest.raises(ValueError, match="iterations"):
        sa.PGS(iterations=0)
    with pytest.raises(ValueError, match="erp"):
        sa.PGS(erp=2.0)
