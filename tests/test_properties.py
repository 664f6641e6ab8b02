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


# ----------------------------------------------------------------- the input policy, every public constructor
# docs/reliability.md, "Numbers, switches and options": a bool is no number, a string no switch,
# an integer option is never truncated, a bad value is a TypeError/ValueError naming the argument.
def _with_bool(values):
    """A list of numbers with one bool put in (np.asarray would turn it into 1.0 silently)."""
    return st.tuples(st.integers(0, len(values)), st.booleans()).map(lambda ib: values[:ib[0]] + [ib[1]] + values[ib[0]:])


numbers_with_a_bool = st.lists(st.floats(0.1, 10.0), min_size=1, max_size=3).flatmap(_with_bool)
BAD = {
    "real": lambda: st.one_of(not_a_number, non_finite),
    "positive": lambda: st.one_of(not_a_number, non_finite, not_positive),
    "nonnegative": lambda: st.one_of(not_a_number, non_finite, st.floats(max_value=-1e-6, allow_infinity=False)),
    # a threshold: >= 0, inf allowed (it switches a test off)
    "threshold": lambda: st.one_of(not_a_number, st.just(np.nan), st.floats(max_value=-1e-6)),
    "fraction": lambda: st.one_of(not_a_number, non_finite, st.floats(max_value=-1e-6, allow_infinity=False),
                                  st.floats(min_value=1.000001, allow_infinity=False)),
    "count": lambda: st.one_of(not_a_number, non_finite, st.integers(max_value=0),
                               st.floats(0.01, 1e3).filter(lambda x: x != int(x))),
    "flag": lambda: st.one_of(st.text(max_size=5), st.sampled_from(["False", "True", "0"]), st.none(),
                              st.integers().filter(lambda k: k not in (0, 1)), st.floats(0.01, 0.99),
                              st.builds(object)),
    "choice": lambda: st.one_of(st.text(max_size=6), st.integers(), st.booleans(), st.builds(object)),
    "vector": lambda: st.one_of(_vector_bad(), st.lists(st.floats(-1.0, 1.0), min_size=2, max_size=2).flatmap(_with_bool)),
    "numbers": lambda: st.one_of(not_a_number, numbers_with_a_bool),
    "vertices": lambda: st.one_of(st.text(min_size=1, max_size=3), st.floats(0.1, 5.5).filter(lambda x: x != int(x)),
                                  st.lists(st.integers(), min_size=1, max_size=4).filter(lambda v: min(v) < 0 or max(v) >= N)),
    # before a body is known (their range is checked where they are bound; a str is a boundary
    # name, resolved there too): not indices
    "indices": lambda: st.one_of(st.binary(min_size=1, max_size=3), st.floats(0.1, 5.5).filter(lambda x: x != int(x)),
                                 st.lists(st.integers(0, 9), min_size=2, max_size=4).map(lambda v: v + v[:1])),
    "count0": lambda: st.one_of(not_a_number, non_finite, st.integers(max_value=-1),
                                st.floats(0.01, 1e3).filter(lambda x: x != int(x))),
    "callable": lambda: st.one_of(not_a_number, st.integers(), st.lists(st.integers(), max_size=2)),
    "object": lambda: st.one_of(not_a_number.filter(lambda v: v is not None), st.integers(), st.just(MESH)),
}
FLAGS = ("flag",)
_BODY = sa.ElasticBody(MESH, MAT)
_PATH = lambda t, X: X  # noqa: E731
BASE = {  # the valid arguments each constructor is called with, beside the bad one
    sa.ElasticBody: dict(mesh=MESH, material=MAT), sa.Simulation: dict(bodies=_BODY),
    sa.Prescribed: dict(vertices=[0], path=_PATH), sa.VertexForce: dict(vertices=[0], force=lambda t, x, v: x * 0),
    sa.StVK: dict(E=1e5, nu=0.3), sa.Corotational: dict(E=1e5, nu=0.3), sa.NeoHookean: dict(E=1e5, nu=0.3),
    sa.Bowl: dict(radius=1.0),
}
# (class, argument, kind, None allowed): every argument of every public constructor that takes a value
POLICY = [
    (sa.ElasticBody, "density", "positive", False), (sa.ElasticBody, "density", "numbers", False),
    (sa.ElasticBody, "velocity", "vector", True), (sa.ElasticBody, "fixed", "vertices", True),
    (sa.ElasticBody, "prescribed", "object", True), (sa.ElasticBody, "material", "object", False),
    (sa.Prescribed, "vertices", "indices", False), (sa.Prescribed, "path", "callable", False),
    (sa.VertexForce, "vertices", "indices", False), (sa.VertexForce, "force", "callable", False),
    (sa.Simulation, "dt", "positive", False), (sa.Simulation, "gravity", "vector", False),
    (sa.Simulation, "damping", "object", True), (sa.Simulation, "reducer", "object", True),
    (sa.Simulation, "newton_iters", "count", True), (sa.Simulation, "newton_tol", "positive", True),
    (sa.Simulation, "project_hessian", "flag", False), (sa.Simulation, "mass", "choice", False),
    (sa.Simulation, "integrator", "choice", True), (sa.Simulation, "on_inverted", "choice", False),
    (sa.Simulation, "on_nonconvergence", "choice", False), (sa.Simulation, "check_energy", "flag", False),
    (sa.Simulation, "colliders", "object", True), (sa.Simulation, "forces", "object", True),
    (sa.Simulation, "bodies", "object", False), (sa.Simulation, "solver", "choice", False),
    (sa.Rayleigh, "alpha", "nonnegative", False), (sa.Rayleigh, "beta", "nonnegative", False),
    *[(cls, "E", kind, False) for cls in MATERIALS for kind in ("positive", "numbers")],
    *[(cls, "nu", "real", False) for cls in MATERIALS],
    *[(cls, arg, kind, True) for cls in (sa.Affinification, sa.Rigidification) for arg, kind in (
        ("target_error", "fraction"), ("time_budget", "positive"), ("never_slower", "flag"), ("min_fraction", "fraction"),
        ("seed", "count0"))],
    *[(cls, arg, kind, False) for cls in (sa.Affinification, sa.Rigidification) for arg, kind in (
        ("seeding", "choice"), ("preconditioner", "choice"), ("shadow_every", "count"), ("memory", "positive"),
        ("refresh_tol", "nonnegative"), ("refresh_background", "flag"), ("refresh", "choice"))],
    (sa.Affinification, "tau_a", "nonnegative", True), (sa.Affinification, "min_body_elements", "count", False),
    (sa.Affinification, "pinned_bodies", "flag", False),
    (sa.Rigidification, "tau_r", "nonnegative", True), (sa.Rigidification, "warmup_frames", "count0", False),
    *[(sa.AdaptiveSubspace, arg, kind, none) for arg, kind, none in (
        ("eps_nodal", "threshold", True), ("eps_modal", "threshold", True), ("eps_progress", "threshold", False),
        ("eps_down", "threshold", False), ("subdomains", "count", False), ("newton_tol", "positive", True),
        ("max_newton", "count", True), ("pcg_tol", "positive", False), ("pcg_maxiter", "count", False),
        ("record_residual", "flag", False), ("hessian_init", "choice", False), ("blas_threads", "count", True),
        ("fallback", "fraction", True), ("target_error", "fraction", True), ("time_budget", "positive", True),
        ("never_slower", "flag", True), ("shadow_every", "count", False), ("memory", "positive", False),
        ("basis", "object", True))],
    *[(cls, "cache", "flag", False) for cls in (sa.AffineModes, sa.LinearModes, sa.SkinningEigenmodes)],
    *[(cls, "n", "count", False) for cls in (sa.LinearModes, sa.SkinningEigenmodes)],
    (sa.SDFCollider, "fn", "callable", False),
    *[(sa.PGS, arg, kind, none) for arg, kind, none in (
        ("friction", "nonnegative", False), ("iterations", "count", False), ("tolerance", "nonnegative", False),
        ("erp", "fraction", False), ("margin", "nonnegative", True), ("push_limit", "positive", True),
        ("warm_start", "flag", False), ("body_contact", "flag", False), ("block", "count", False),
        ("edge_contact", "flag", False), ("slop", "nonnegative", True))],
    *[(sa.IPC, arg, kind, none) for arg, kind, none in (
        ("dhat", "positive", True), ("kappa", "positive", True), ("friction", "nonnegative", False),
        ("epsv", "positive", True), ("self_contact", "flag", False), ("body_contact", "flag", False),
        ("ccd", "choice", False), ("ccd_tolerance", "positive", False), ("ccd_max_iterations", "count", False),
        ("ccd_rescaling", "fraction", False))],
]
# the colliders' arguments: COLLIDER_ARGS above; data containers and errors take no user settings
NOT_CONSTRUCTORS = {sa.State, sa.Stats, sa.SimulationDiverged, sa.SimulationWarning, sa.Material}
VALID_CHOICES = {"solver": ("auto", "direct", "cg", "amg", "pardiso", "superlu", "cholmod")}


def test_every_public_class_has_its_input_policy_tested():
    classes = {getattr(sa, name) for name in sa.__all__ if isinstance(getattr(sa, name), type)}
    covered = {cls for cls, *_ in POLICY} | {cls for cls, *_ in COLLIDER_ARGS.values()} | NOT_CONSTRUCTORS
    assert classes <= covered, f"no input-policy test for {sorted(c.__name__ for c in classes - covered)}"


@pytest.mark.parametrize("cls, arg, kind, none_ok", POLICY,
                         ids=[f"{c.__name__}-{a}-{k}" for c, a, k, _ in POLICY])
@settings(max_examples=12, deadline=None, database=None, suppress_health_check=[HealthCheck.too_slow])
@given(data=st.data())
def test_bad_arguments_of_public_constructors_raise_naming_them(cls, arg, kind, none_ok, data):
    bad = data.draw(BAD[kind]().filter(lambda v: not (none_ok and v is None)))
    if kind == "choice" and isinstance(bad, str):
        assume(bad not in VALID_CHOICES.get(arg, ()) and bad.strip())
    if arg == "refresh":  # a switch, or the kind of refresh
        assume(not (isinstance(bad, (bool, int)) and bad in (0, 1)))
    if arg == "fallback":
        assume(bad != "nnz")
    kwargs = dict(BASE.get(cls, {}), **{arg: bad})
    if cls is sa.Affinification and arg == "tau_e":
        kwargs["tau_a"] = 0.1
    _raises_naming(lambda: cls(**kwargs), arg)


@pytest.mark.parametrize("make, name", [
    (lambda: sa.Simulation(_BODY, gravity=[0, 0, True]), "gravity"),
    (lambda: sa.NeoHookean(E=[1e5, True], nu=0.3), "E"),
    (lambda: sa.ElasticBody(MESH, MAT, velocity=[0, 0, True]), "velocity"),
    (lambda: sa.Affinification(never_slower="False"), "never_slower"),
    (lambda: sa.Rigidification(never_slower="False"), "never_slower"),
    (lambda: sa.IPC(ccd_max_iterations=True), "ccd_max_iterations"),
    (lambda: sa.IPC(friction="0.3"), "friction"),
])
def test_the_reported_silent_accepts_are_refused(make, name):
    with pytest.raises(TypeError, match=name):
        make()
