"""Property-based tests (hypothesis): nothing wrong passes as a result.

* random valid bodies (tensor meshes with random spacings, rotations, offsets, refinement;
  random materials, densities, fixed sets, velocities) and parameters: a few steps never
  return a non-finite state; if the step cannot go on it raises ``SimulationDiverged``;
* random invalid input to the public constructors (ElasticBody, materials, colliders)
  always raises a TypeError or ValueError whose message names the argument.

Kept fast: tiny meshes and a bounded number of examples.
"""
import re

import numpy as np
import pytest
import skfem
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

import skfem_affine as sa

FAST = settings(max_examples=30, deadline=None, database=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
MATERIALS = (sa.StVK, sa.Corotational, sa.NeoHookean)


# ----------------------------------------------------------------- valid scenes
def _rotation(q):
    w, x, y, z = np.asarray(q) / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


spacing = st.lists(st.floats(0.05, 2.0), min_size=1, max_size=2)
quaternion = st.tuples(*[st.floats(-1.0, 1.0)] * 4).filter(lambda q: np.linalg.norm(q) > 0.1)


@st.composite
def meshes(draw):
    axes = [np.concatenate([[0.0], np.cumsum(draw(spacing))]) for _ in range(3)]
    mesh = skfem.MeshTet.init_tensor(*axes)
    if mesh.t.shape[1] <= 12 and draw(st.booleans()):
        mesh = mesh.refined(1)
    R = _rotation(draw(quaternion))
    offset = np.array(draw(st.tuples(*[st.floats(-100.0, 100.0)] * 3)))
    return skfem.MeshTet(R @ mesh.p + offset[:, None], mesh.t)


@st.composite
def bodies(draw):
    mesh = draw(meshes())
    m, n = mesh.t.shape[1], mesh.p.shape[1]
    cls = draw(st.sampled_from(MATERIALS))
    nu = draw(st.floats(-0.9, 0.49))
    if draw(st.booleans()):
        E = draw(st.floats(1e3, 1e8))
    else:  # one value per element
        E = np.array(draw(st.lists(st.floats(1e3, 1e8), min_size=m, max_size=m)))
    density = draw(st.floats(10.0, 1e4))
    fixed = None
    if draw(st.booleans()):
        fixed = np.array(draw(st.lists(st.booleans(), min_size=n, max_size=n)))
    velocity = np.array(draw(st.tuples(*[st.floats(-5.0, 5.0)] * 3)))
    return sa.ElasticBody(mesh, cls(E=E, nu=nu), density=density, fixed=fixed, velocity=velocity)


@FAST
@given(body=bodies(), dt=st.floats(1e-4, 0.05), gravity=st.tuples(*[st.floats(-20.0, 20.0)] * 3))
def test_a_few_steps_never_return_a_non_finite_state(body, dt, gravity):
    sim = sa.Simulation(body, dt=dt, gravity=gravity)
    for _ in range(3):
        try:
            state = sim.step()
        except sa.SimulationDiverged:
            return  # an honest failure; any other exception fails the test
        assert np.all(np.isfinite(state.x)) and np.all(np.isfinite(state.v))


@FAST
@given(body=bodies(), dt=st.floats(1e-3, 0.05), which=st.sampled_from(["plane", "sphere", "box"]),
       gap=st.floats(-0.05, 0.2), speed=st.floats(0.0, 10.0))
def test_steps_against_a_collider_never_return_a_non_finite_state(body, dt, which, gap, speed):
    p = body.mesh.p
    low = p[2].min() - gap  # the obstacle's top, a little below (or into) the body
    centre = p[:2].mean(axis=1)
    col = {"plane": lambda: sa.Plane(point=(0.0, 0.0, low)),
           "sphere": lambda: sa.Sphere(center=(centre[0], centre[1], low - 1.0), radius=1.0),
           "box": lambda: sa.Box(center=(centre[0], centre[1], low - 0.5), half_extents=(5.0, 5.0, 0.5))}[which]()
    body.velocity[~body.fixed] += (0.0, 0.0, -speed)
    sim = sa.Simulation(body, dt=dt, gravity=(0.0, 0.0, -9.81), colliders=[col])
    for _ in range(3):
        try:
            state = sim.step()
        except sa.SimulationDiverged:
            return
        assert np.all(np.isfinite(state.x)) and np.all(np.isfinite(state.v))


# ----------------------------------------------------------------- invalid input
not_a_number = st.one_of(
    st.text(max_size=4), st.sampled_from(["1.0", "0.3", "nan", ""]), st.booleans(), st.none(),
    st.complex_numbers(allow_nan=False, allow_infinity=False, min_magnitude=1e-3).filter(lambda z: z.imag != 0),
    st.builds(object), st.dictionaries(st.text(max_size=2), st.integers(), max_size=1),
)
non_finite = st.sampled_from([np.nan, np.inf, -np.inf])
not_positive = st.one_of(st.floats(max_value=0.0, allow_nan=False, allow_infinity=False), st.just(-np.inf))


def _vector_bad():
    """Things that are not a finite 3-vector of real numbers."""
    return st.one_of(
        not_a_number,
        st.lists(st.floats(-10, 10), min_size=0, max_size=6).filter(lambda v: len(v) != 3),
        st.tuples(st.floats(-1, 1), non_finite, st.floats(-1, 1)),
        st.lists(st.sampled_from(["0", "1"]), min_size=3, max_size=3),
        st.lists(st.booleans(), min_size=3, max_size=3),
    )


def _raises_naming(make, name):
    """``make()`` raises TypeError or ValueError and the message names ``name`` (as a word)."""
    with pytest.raises((TypeError, ValueError)) as info:
        make()
    assert re.search(rf"(?<![A-Za-z_]){re.escape(name)}(?![A-Za-z_])", str(info.value)), \
        f"message does not name {name!r}: {info.value}"


@FAST
@given(data=st.data())
def test_bad_material_parameters_raise_naming_them(data):
    cls = data.draw(st.sampled_from(MATERIALS))
    which = data.draw(st.sampled_from(["E", "nu"]))
    if which == "E":
        bad = data.draw(st.one_of(not_a_number, non_finite, not_positive,
                                  st.lists(st.floats(1.0, 1e6), min_size=2, max_size=3).map(lambda v: np.array([v, v]))))
        _raises_naming(lambda: cls(E=bad, nu=0.3), "E")
    else:
        bad = data.draw(st.one_of(not_a_number, non_finite, st.floats(min_value=0.5), st.floats(max_value=-1.0)))
        _raises_naming(lambda: cls(E=1e5, nu=bad), "nu")


MESH = skfem.MeshTet.init_tensor(*[np.linspace(0.0, 1.0, 3)] * 3)  # 27 vertices, 48 elements
N, M = MESH.p.shape[1], MESH.t.shape[1]
MAT = sa.NeoHookean(E=1e5, nu=0.3)


@st.composite
def bad_meshes(draw):
    p, t = MESH.p.copy(), MESH.t.copy()
    kind = draw(st.sampled_from(["nan", "unused", "collapse", "repeat", "range", "empty", "type"]))
    if kind == "type":
        return draw(st.one_of(not_a_number, st.just(p), st.just(skfem.MeshTri()),
                              st.just(skfem.MeshHex()), st.just(skfem.MeshTet2())))
    if kind == "nan":
        p[draw(st.integers(0, 2)), draw(st.integers(0, N - 1))] = draw(non_finite)
    elif kind == "unused":
        extra = np.array(draw(st.lists(st.tuples(*[st.floats(-5, 5)] * 3), min_size=1, max_size=3))).T
        p = np.hstack([p, extra])
    elif kind == "collapse":  # all four vertices of one element on one point: a 0/0 quality
        e = draw(st.integers(0, M - 1))
        p = np.hstack([p, np.repeat(p[:, [t[0, e]]], 4, axis=1)])
        t = np.hstack([t, N + np.arange(4)[:, None]])
    elif kind == "repeat":
        e = draw(st.integers(0, M - 1))
        t[draw(st.integers(1, 3)), e] = t[0, e]
    elif kind == "range":
        t[draw(st.integers(0, 3)), draw(st.integers(0, M - 1))] = draw(st.sampled_from([-1, N, N + 7]))
    elif kind == "empty":
        t = t[:, :0]
    return skfem.MeshTet(p, t, validate=False, sort_t=False)


@FAST
@given(data=st.data())
def test_bad_body_arguments_raise_naming_them(data):
    which = data.draw(st.sampled_from(["mesh", "material", "density", "fixed", "velocity", "name"]))
    kwargs = dict(mesh=MESH, material=MAT)
    if which == "mesh":
        kwargs["mesh"] = data.draw(bad_meshes())
    elif which == "material":
        kwargs["material"] = data.draw(st.one_of(
            not_a_number, st.sampled_from(MATERIALS),
            st.integers(1, 3 * M).filter(lambda k: k != M).map(lambda k: sa.StVK(E=np.full(k, 1e5), nu=0.3)),
            st.integers(1, 3 * M).filter(lambda k: k != M).map(lambda k: [MAT] * k)))
        name = "material"
    elif which == "density":
        kwargs["density"] = data.draw(st.one_of(
            not_a_number, non_finite, not_positive,
            st.integers(0, 3 * M).filter(lambda k: k != M).map(lambda k: np.full(k, 1000.0)),
            st.integers(0, M - 1).map(lambda i: np.where(np.arange(M) == i, -1.0, 1000.0))))
    elif which == "fixed":
        kwargs["fixed"] = data.draw(st.one_of(
            st.text(min_size=1, max_size=3), st.just("0"),
            st.lists(st.integers(), min_size=1, max_size=5).filter(lambda v: min(v) < 0 or max(v) >= N),
            st.lists(st.floats(0.1, N - 1.1).filter(lambda x: x != int(x)), min_size=1, max_size=3),
            st.lists(st.booleans(), min_size=1, max_size=2 * N).filter(lambda v: len(v) != N).map(np.array),
            st.lists(st.integers(0, 1), min_size=N, max_size=N),   # a 0/1 "mask" given as integers
        ))
    elif which == "velocity":
        kwargs["velocity"] = data.draw(st.one_of(
            _vector_bad().filter(lambda v: v is not None),  # None is the default: zero velocity
            st.integers(1, 2 * N).filter(lambda k: k != N and k != 1).map(lambda k: np.zeros((k, 3))),
            st.just(np.zeros((N, 2))), st.just(np.full((N, 3), np.nan))))
    else:
        kwargs["name"] = data.draw(st.one_of(st.integers(), st.floats(), st.booleans(), st.builds(object)))
    _raises_naming(lambda: sa.ElasticBody(**kwargs), "mesh" if which == "mesh" else which)


COLLIDER_ARGS = {
    # constructor, argument, bad values, the name the message must carry
    "plane point": (sa.Plane, "point", _vector_bad, "point"),
    "plane normal": (sa.Plane, "normal", lambda: st.one_of(_vector_bad(), st.just((0.0, 0.0, 0.0))), "normal"),
    "sphere center": (sa.Sphere, "center", _vector_bad, "center"),
    "sphere radius": (sa.Sphere, "radius", lambda: st.one_of(not_a_number, non_finite, not_positive), "radius"),
    "box center": (sa.Box, "center", _vector_bad, "center"),
    "box half_extents": (sa.Box, "half_extents",
                         lambda: st.one_of(_vector_bad(), st.tuples(st.floats(0.1, 1), not_positive, st.floats(0.1, 1))),
                         "half_extents"),
    "box rotation": (sa.Box, "rotation", lambda: st.one_of(
        not_a_number.filter(lambda v: v is not None), st.just(np.eye(2)), st.just(2 * np.eye(3)),
        st.just(np.diag([1.0, 1.0, -1.0])), st.just(np.full((3, 3), np.nan))), "rotation"),
    "capsule a": (sa.Capsule, "a", _vector_bad, "a"),
    "capsule b": (sa.Capsule, "b", _vector_bad, "b"),
    "capsule radius": (sa.Capsule, "radius", lambda: st.one_of(not_a_number, non_finite, not_positive), "radius"),
    "bowl center": (sa.Bowl, "center", _vector_bad, "center"),
    "bowl radius": (sa.Bowl, "radius", lambda: st.one_of(not_a_number, non_finite, not_positive), "radius"),
    "bowl thickness": (sa.Bowl, "thickness",
                       lambda: st.one_of(not_a_number.filter(lambda v: v is not None), non_finite, not_positive,
                                         st.floats(1.0, 1e6, exclude_min=True)), "thickness"),
}


@FAST
@given(data=st.data())
def test_bad_collider_parameters_raise_naming_them(data):
    key = data.draw(st.sampled_from(sorted(COLLIDER_ARGS)))
    cls, arg, strategy, name = COLLIDER_ARGS[key]
    bad = data.draw(strategy())
    kwargs = {arg: bad}
    if cls is sa.Bowl and arg == "thickness":
        kwargs["radius"] = 1.0
    _raises_naming(lambda: cls(**kwargs), name)


@FAST
@given(a=st.tuples(*[st.floats(-5, 5)] * 3), r=st.floats(0.01, 3.0))
def test_capsule_with_coinciding_ends_is_refused(a, r):
    _raises_naming(lambda: sa.Capsule(a=a, b=a, radius=r), "a")


@FAST
@given(points=st.lists(st.tuples(*[st.floats(-1e6, 1e6)] * 3), min_size=1, max_size=20),
       which=st.sampled_from(["plane", "sphere", "box", "capsule", "bowl"]),
       center=st.tuples(*[st.floats(-2, 2)] * 3), size=st.floats(0.01, 10.0), q=quaternion)
def test_random_colliders_give_unit_normals_at_random_points(points, which, center, size, q):
    col = {"plane": lambda: sa.Plane(point=center, normal=_rotation(q)[:, 2]),
           "sphere": lambda: sa.Sphere(center=center, radius=size),
           "box": lambda: sa.Box(center=center, half_extents=(size, 0.5 * size, 2 * size), rotation=_rotation(q)),
           "capsule": lambda: sa.Capsule(a=center, b=np.add(center, _rotation(q)[:, 0]), radius=size),
           "bowl": lambda: sa.Bowl(center=center, radius=size, thickness=0.3 * size)}[which]()
    # the random points, plus the collider's own centre and points on the query grid's axes
    p = np.vstack([np.array(points), center, np.add(center, (0, 0, size)), np.add(center, (size, 0, 0))])
    d, n = col.query(p)
    assert np.all(np.isfinite(d)) and np.all(np.isfinite(n))
    assert np.allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-12)
    # their closest surface points, and points a hair (down to subnormal) off the surface
    surface = p - d[:, None] * n
    hair = np.array([0.0, 1e-300, 1e-15, 1e-13, -1e-15, -1e-13])[np.arange(len(p)) % 6, None] * size
    for near in (surface, surface + hair * n, surface + hair * np.roll(n, 1, axis=1)):
        d2, n2 = col.query(near)
        assert np.all(np.isfinite(d2)) and np.allclose(np.linalg.norm(n2, axis=1), 1.0, atol=1e-12)
