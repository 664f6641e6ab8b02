"""Contact detection's compiled kernels (broad phase grid, narrow phase) find the contacts the
vectorised numpy detection found.

``tests/data/detection_reference.npz`` holds, for the small scenes below (a resting pile, a box falling
onto another, two bars whose edges cross, boxes in a bowl and on a sphere, surface triangles squashed
to a segment and a point), the detector's inputs of a few frames and the contacts the numpy detection
returned for them (written by ``python tests/test_detection_kernels.py``, from that version). Every
contact must come back the same: the same vertices, triangles, keys and order, the gaps, weights and
normals to round-off. The closest point of a point on a triangle is also checked against a numpy
transcription of Ericson's Voronoi-region test (Real-Time Collision Detection, 5.1.5), kept here
(a triangle without area: its longest edge). A box whose top has a crushed triangle checks the sign
of a vertex penetrating next to it.
"""
import functools
import os

import numpy as np
import pytest
import skfem

import skfem_affine as sa
from skfem_affine.contact import geometry
from skfem_affine.contact.geometry import Detector
from skfem_affine.lab.scenes import box_mesh

REFERENCE = os.path.join(os.path.dirname(__file__), "data", "detection_reference.npz")
INTS = ("vertex", "others", "key", "near")
FLOATS = ("weights", "normal", "distance", "own")
MAT = sa.NeoHookean(E=1e6, nu=0.35)


def _body(size, cells, centre, **kw):
    return sa.ElasticBody(box_mesh(size, cells, centre), MAT, density=1000.0, **kw)


def _pile():
    """Four boxes resting in a pile (the arrangement of ``benchmarks/budget.py``), two cells a box."""
    boxes = [(0.3, (-0.16, 0.0, 0.152)), (0.3, (0.16, 0.0, 0.152)), (0.24, (0.0, 0.01, 0.424)),
             (0.18, (0.02, -0.01, 0.636))]
    return sa.Simulation([_body(s, 2, c) for s, c in boxes], dt=0.01, colliders=[sa.Plane()])


def _falling():
    """A smaller box falling fast and sideways onto a box on the ground."""
    return sa.Simulation([_body(0.2, 2, (0.0, 0.0, 0.1)), _body(0.12, 2, (0.02, 0.01, 0.3))], dt=0.01,
                         colliders=[sa.Plane()])


def _bars():
    """Two bars crossing like an X, closing, then crossed: only their edges meet."""
    w = 0.1
    first = box_mesh((w, 1.0, w), (1, 5, 1), (-(w + 0.05) / 2, 0, 0))
    second = box_mesh((w, w, 1.0), (1, 1, 5), ((w + 0.05) / 2, 0, 0))
    mat = sa.NeoHookean(E=1e8, nu=0.35)
    return sa.Simulation([sa.ElasticBody(first, mat, density=1000.0), sa.ElasticBody(second, mat, density=1000.0)],
                         dt=0.01, gravity=(0, 0, 0))


def _bowl():
    """Two boxes in a bowl, one of them against a ball too."""
    R = np.array([[np.cos(0.4), -np.sin(0.4), 0.0], [np.sin(0.4), np.cos(0.4), 0.0], [0.0, 0.0, 1.0]])
    turned = box_mesh(0.16, 2, (0.0, 0.0, 0.0))
    turned = skfem.MeshTet(R @ turned.p + np.array([[0.05], [0.02], [-0.33]]), turned.t)
    bodies = [_body(0.2, 2, (-0.1, 0.0, -0.38)), sa.ElasticBody(turned, MAT, density=1000.0)]
    return sa.Simulation(bodies, dt=0.01, colliders=[sa.Bowl(radius=0.5), sa.Sphere((0.12, 0.0, -0.14), 0.12)])


def _frames(sim, rng, drops, noise, speed):
    """Detector inputs (x, v, dt, w) at the rest positions each body moved down by ``drops`` (one per
    frame, a (B,) array each), with vertex ``noise`` and random velocities of size ``speed``."""
    s = sim.system
    body = np.repeat(np.arange(len(s.bodies)), np.diff(s.vertex_offsets))
    out = []
    for k, drop in enumerate(drops):
        x = s.p0 + noise * rng.standard_normal(s.p0.shape)
        x[:, 2] -= np.asarray(drop)[body]
        v = speed * rng.standard_normal(s.p0.shape)
        w = v + sim.dt * np.array([0.0, 0.0, -9.81]) if k % 2 == 0 else None
        out.append((x, v, sim.dt, w))
    return out


def _squash(frames, sim, points):
    """The frames with each surface triangle of ``points`` ((triangle, how) pairs) squashed: ``how``
    0 puts its second corner on the first (a segment), 1 all three on the first (a point)."""
    tris, _ = geometry.boundary_surface(sim.system)
    for x, *_ in frames:
        for t, how in points:
            a, b, c = tris[t]
            x[b] = x[a]
            if how:
                x[c] = x[a]
    return frames


@functools.lru_cache(maxsize=None)
def cases():
    """name -> (simulation, detector settings, frames); deterministic."""
    rng = np.random.default_rng(7)
    out = {}
    sim = _pile()
    drops = [np.array([0.0, 0.001, 0.004, 0.006]) + 0.0002 * k for k in range(4)] + [np.array([0.0, 0.0, 0.04, 0.05])]
    out["pile"] = (sim, {}, _frames(sim, rng, drops, 1e-4, 0.05))
    sim = _pile()
    out["pile_scratch"] = (sim, {"skin": 0.0, "lookahead": 2.0}, _frames(sim, rng, drops[:3], 1e-3, 0.3))
    sim = _falling()
    fr = _frames(sim, rng, [np.array([0.0, 0.02 * k]) for k in range(6)], 1e-4, 0.0)
    for x, v, dt, w in fr:
        v[sim.system.vertex_offsets[1]:] += (0.5, 0.0, -2.0)
    out["falling"] = (sim, {}, fr)
    sim = _bars()
    off = sim.system.vertex_offsets[1]
    fr = []
    for k, gap in enumerate([0.04, 0.02, 0.01, 0.004, 0.0, -0.003, -0.008]):
        x = sim.system.p0.copy()
        x[:off, 0] += 0.025 - gap / 2
        x[off:, 0] -= 0.025 - gap / 2
        v = np.zeros_like(x)
        v[:off, 0], v[off:, 0] = 0.5, -0.5
        fr.append((x, v, sim.dt, v.copy() if k % 3 else None))
    out["bars"] = (sim, {}, fr)
    sim = _bars()
    out["bars_no_edges"] = (sim, {"edge_contact": False}, fr)
    sim = _bowl()
    out["bowl"] = (sim, {}, _frames(sim, rng, [np.array([0.0, 0.01 * k]) for k in range(4)], 3e-4, 0.2))
    sim = _pile()
    tris, owner = geometry.boundary_surface(sim.system)
    centre = sim.system.p0[tris].mean(axis=1)
    top = np.flatnonzero((owner == 0) & (centre[:, 2] > 0.3) & (centre[:, 0] > -0.1))  # box 0's top under box 2
    out["squashed"] = (sim, {}, _squash(_frames(sim, rng, drops[:3], 0.0, 0.05), sim, [(top[0], 0), (top[1], 1)]))
    return out


def _detect(sim, settings, frames):
    """The contacts of each frame (a dict of arrays per frame, empty for None) and the largest
    penetration, from one detector stepped over the frames."""
    lookahead = settings.get("lookahead")
    kw = {k: v for k, v in settings.items() if k != "lookahead"}
    det = Detector(sim.system, sim.contact.detector.colliders, sim.contact.detector.margin, **kw)
    det.lookahead = lookahead
    out = []
    for x, v, dt, w in frames:
        cs = det.find(x, v, dt, w)
        got = {} if cs is None else {f: getattr(cs, f) for f in INTS + FLOATS if getattr(cs, f) is not None}
        got["max_penetration"] = np.array(det.max_penetration(x))
        out.append(got)
    return out


CASES = ("pile", "pile_scratch", "falling", "bars", "bars_no_edges", "bowl", "squashed")


@pytest.mark.parametrize("name", CASES)
def test_detection_finds_the_reference_contacts(name):
    ref = np.load(REFERENCE)
    sim, settings, frames = cases()[name]
    for k, got in enumerate(_detect(sim, settings, frames)):
        prefix = f"{name}/{k}/"
        keys = sorted(key[len(prefix):] for key in ref.files if key.startswith(prefix))
        assert sorted(got) == keys, f"frame {k}"
        for f in keys:
            if f in INTS:
                np.testing.assert_array_equal(got[f], ref[prefix + f], err_msg=f"{name} frame {k} {f}")
            else:
                np.testing.assert_allclose(got[f], ref[prefix + f], rtol=1e-9, atol=1e-11,
                                           err_msg=f"{name} frame {k} {f}")


def test_reference_cases_exercise_every_path():
    """The reference frames hold contacts with every collider, between bodies (penetrating too) and
    between edges, and frames with no contact."""
    ref = np.load(REFERENCE)
    seen = {"collider": set(), "body": 0, "edge": 0, "penetration": 0, "none": 0}
    for name in CASES:
        sim, _, frames = cases()[name]
        det = sim.contact.detector
        base, kinds = det.n_vertices * det.n_kinds, det.n_kinds
        for k in range(len(frames)):
            key = ref[f"{name}/{k}/key"] if f"{name}/{k}/key" in ref.files else np.zeros(0, int)
            vertex = key < base
            seen["collider"] |= {(name, int(c)) for c in np.unique(key[vertex] % kinds) if c < len(det.colliders)}
            body = vertex & (key % kinds >= len(det.colliders))
            seen["body"] += int(body.sum())
            seen["edge"] += int((~vertex).sum())
            seen["penetration"] += int((ref[f"{name}/{k}/distance"][body] < 0).sum()) if key.size else 0
            seen["none"] += not key.size
    assert {("pile", 0), ("bowl", 0), ("bowl", 1)} <= seen["collider"]
    assert min(seen["body"], seen["edge"], seen["penetration"], seen["none"]) > 0, seen


def _weights_reference(p, a, b, c):
    """Barycentric weights (k, 3) of the closest points of p on triangles (a, b, c): Ericson's Voronoi
    regions, vectorised (interior, then edges, then vertices; later regions override earlier ones),
    and for a triangle without area (``|ab x ac| <= 1e-12`` times its longest edge squared) the
    projection on its longest edge, clamped."""
    ab, ac, ap, bp, cp = b - a, c - a, p - a, p - b, p - c

    def dot(u, v):
        return np.einsum("ij,ij->i", u, v)

    d1, d2, d3, d4, d5, d6 = dot(ab, ap), dot(ac, ap), dot(ab, bp), dot(ac, bp), dot(ab, cp), dot(ac, cp)
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2

    def safe(num, den):
        return num / np.where(np.abs(den) > 1e-300, den, 1e-300)

    s = va + vb + vc
    v, w = safe(vb, s), safe(vc, s)
    W = np.column_stack([1.0 - v - w, v, w])

    def put(mask, cols):
        W[mask] = np.column_stack(cols)[mask]

    wbc = safe(d4 - d3, (d4 - d3) + (d5 - d6))
    put((va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0), [0 * wbc, 1 - wbc, wbc])
    wac = safe(d2, d2 - d6)
    put((vb <= 0) & (d2 >= 0) & (d6 <= 0), [1 - wac, 0 * wac, wac])
    one, zero = np.ones_like(d1), np.zeros_like(d1)
    put((d6 >= 0) & (d5 <= d6), [zero, zero, one])
    vab = safe(d1, d1 - d3)
    put((vc <= 0) & (d1 >= 0) & (d3 <= 0), [1 - vab, vab, zero])
    put((d3 >= 0) & (d4 <= d3), [zero, one, zero])
    put((d1 <= 0) & (d2 <= 0), [one, zero, zero])
    # a triangle without area: the closest point on its longest edge (the first of ab, bc, ca)
    n = np.cross(ab, ac)
    length = np.column_stack([((q1 - q0) ** 2).sum(axis=1) for q0, q1 in ((a, b), (b, c), (c, a))])
    flat = ~(np.sqrt((n ** 2).sum(axis=1)) > 1e-12 * length.max(axis=1))
    edge = np.where((length[:, 0] >= length[:, 1]) & (length[:, 0] >= length[:, 2]), 0,
                    np.where(length[:, 1] >= length[:, 2], 1, 2))
    start, end = np.stack([a, b, c], axis=1), np.stack([b, c, a], axis=1)
    s, e = start[np.arange(len(p)), edge], end[np.arange(len(p)), edge]
    L = length[np.arange(len(p)), edge]
    t = np.clip(dot(e - s, p - s) / np.where(L > 0, L, 1.0), 0.0, 1.0) * (L > 0)
    seg = np.zeros_like(W)
    seg[np.arange(len(p)), edge] = 1.0 - t
    seg[np.arange(len(p)), (edge + 1) % 3] = t
    W[flat] = seg[flat]
    return W


def test_closest_point_weights_match_the_voronoi_regions():
    rng = np.random.default_rng(3)
    k = 3000
    a, b, c = (rng.normal(size=(k, 3)) for _ in range(3))
    p = 1.5 * rng.normal(size=(k, 3))
    # degenerate triangles: a segment (two corners equal), collinear corners, a point
    b[:100] = a[:100]
    c[100:200] = a[100:200] + 0.3 * (b[100:200] - a[100:200])
    b[200:300] = c[200:300] = a[200:300]
    p[300:400] = a[300:400]                      # on a corner
    p[400:500] = 0.5 * (a[400:500] + b[400:500])  # on an edge
    W = geometry.closest_points_on_triangles(p, a, b, c)
    np.testing.assert_array_equal(W, _weights_reference(p, a, b, c))
    assert np.all(np.isfinite(W))


def test_closest_surface_points_take_the_pseudo_normal_beside_an_edge():
    """The sign beside an edge and a corner of a closed surface: the point outside, its normal
    along the direction to the edge (the tie of the two faces summed)."""
    mesh = box_mesh(1.0, 1, (0.0, 0.0, 0.0))
    sim = sa.Simulation([sa.ElasticBody(mesh, MAT)], dt=0.01, gravity=(0, 0, 0))
    tris, _ = geometry.boundary_surface(sim.system)
    corners = sim.system.p0[tris]
    points = np.array([[0.6, 0.6, 0.0], [0.6, 0.6, 0.6], [0.4, 0.0, 0.0], [0.0, 0.0, 0.45]])
    rows = np.repeat(np.arange(len(points)), len(tris))
    tri = np.tile(np.arange(len(tris)), len(points))
    found, t, W, d, n = geometry.closest_surface_points(points, rows, tri, corners, 1e-12)
    np.testing.assert_array_equal(found, np.arange(4))
    np.testing.assert_allclose(d, [0.1 * np.sqrt(2), 0.1 * np.sqrt(3), -0.1, -0.05], atol=1e-14)
    np.testing.assert_allclose(n[:2], [[1, 1, 0], [1, 1, 1]] / np.sqrt([[2], [3]]), atol=1e-14)
    np.testing.assert_allclose(n[2:], [[1, 0, 0], [0, 0, 1]], atol=1e-14)
    np.testing.assert_allclose(W.sum(axis=1), 1.0)
    # rows need not be sorted nor complete: the same for a shuffled candidate list
    order = np.random.default_rng(0).permutation(len(rows))
    again = geometry.closest_surface_points(points, rows[order], tri[order], corners, 1e-12)
    np.testing.assert_array_equal(again[0], found)
    np.testing.assert_allclose(again[3], d, atol=1e-15)


def test_vertex_pairs_are_every_pair_within_reach_grouped_by_body_and_vertex():
    """The grid search returns exactly the (vertex, triangle) pairs of different bodies within the
    reach of the pair of bodies (against all distances), grouped by (triangle's body, vertex), on
    bodies of very different sizes and reaches (one reach far below its body's size: the grid's cap
    on cells), with vertices on cell boundaries, and into buffers that grow."""
    from skfem_affine.contact import grid
    rng = np.random.default_rng(5)
    sizes = [40, 300, 5, 120]
    centroid = np.concatenate([rng.uniform(-1, 1, (k, 3)) * s for k, s in zip(sizes, (1.0, 0.3, 5.0, 1e-3))])
    centroid[:3] = np.round(centroid[:3], 1)
    tri_start = np.append(0, np.cumsum(sizes))
    xs = rng.uniform(-1.2, 1.2, (500, 3))
    xs[:20] = np.round(xs[:20], 1)
    owner = rng.integers(0, 5, 500)                   # body 4 has no triangles
    B = 5
    r = rng.uniform(0.05, 0.4, (B, B))
    r[1, 3], r[2, 0] = 1e-4, 2.0
    np.fill_diagonal(r, -np.inf)
    tb = np.repeat(np.arange(4), sizes)
    dist = np.linalg.norm(xs[:, None] - centroid[None], axis=2)
    want = (dist <= r[owner[:, None], tb[None]]) & (owner[:, None] != tb[None])
    empty = np.zeros(0, dtype=np.int64)
    rows, tris, starts, k, g = grid.vertex_pairs(xs, owner, centroid, tri_start, r, empty, empty, empty)
    rows, tris, starts = rows[:k], tris[:k], starts[:g]
    got = np.zeros_like(want)
    got[rows, tris] = True
    assert np.array_equal(got, want) and k == want.sum()
    key = tb[tris] * len(xs) + rows
    assert np.all(np.diff(key) >= 0)                 # by (body, vertex)
    assert np.array_equal(starts, np.append(np.flatnonzero(np.r_[True, key[1:] != key[:-1]]), k))


def test_closest_point_inputs_are_checked():
    corners = np.zeros((2, 3, 3))
    with pytest.raises(ValueError, match="rows"):
        geometry.closest_surface_points(np.zeros((1, 3)), np.array([1]), np.array([0]), corners, 0.0)
    with pytest.raises(ValueError, match="tri"):
        geometry.closest_surface_points(np.zeros((1, 3)), np.array([0]), np.array([2]), corners, 0.0)
    with pytest.raises(ValueError, match="shape"):
        geometry.closest_points_on_triangles(np.zeros((2, 3)), np.zeros((2, 3)), np.zeros((1, 3)), np.zeros((2, 3)))


def test_non_finite_positions_are_refused_before_the_grid():
    sim, _, frames = cases()["falling"]
    det = Detector(sim.system, [], sim.contact.detector.margin)   # no collider to check the points first
    x, v, dt, _ = frames[0]
    x = x.copy()
    x[5] = np.nan
    with pytest.raises(ValueError, match="non-finite"):
        det.find(x, v, dt)
    with pytest.raises(ValueError, match="non-finite"):
        det.max_penetration(x)


def _crushed_top():
    """A box (2 cells a side, top face z = 0.5) with the top triangle whose corners are (0, -0.5),
    (0.5, 0) and the top's centre crushed to zero area (the centre moved onto the middle of the
    other two: the top stays flat), and a small box over it whose bottom is 0.01 deep in the top,
    one bottom corner right above the crushed triangle."""
    sim = sa.Simulation([sa.ElasticBody(box_mesh(1.0, 2, (0.0, 0.0, 0.0)), MAT),
                         sa.ElasticBody(box_mesh(0.2, 1, (0.3, -0.2, 0.59)), MAT)], dt=0.01, gravity=(0, 0, 0))
    x = sim.system.p0.copy()
    centre = np.flatnonzero(np.all(np.isclose(x, [0.0, 0.0, 0.5]), axis=1))
    x[centre] = [0.25, -0.25, 0.5]
    return sim, x


def test_a_vertex_beside_a_squashed_triangle_is_found_inside():
    """A vertex 0.01 deep in a body, its closest points on a zero-area triangle of the body's surface
    and on the two faces beside it: a contact with gap -0.01 and the normal out of the body (+z);
    every gap and normal finite."""
    sim, x = _crushed_top()
    tris, owner = geometry.boundary_surface(sim.system)
    area = np.linalg.norm(np.cross(x[tris[:, 1]] - x[tris[:, 0]], x[tris[:, 2]] - x[tris[:, 0]]), axis=1)
    assert np.count_nonzero(area == 0.0) == 1                     # the crushed triangle, nothing else
    det = Detector(sim.system, [], 0.005, edge_contact=False)
    cs = det.find(x, np.zeros_like(x), 0.01)
    assert np.all(np.isfinite(cs.distance)) and np.all(np.isfinite(cs.normal)) and np.all(np.isfinite(cs.weights))
    corner = np.flatnonzero(np.all(np.isclose(x, [0.2, -0.3, 0.49]), axis=1))[0]
    j = np.flatnonzero(cs.vertex == corner)
    assert j.size == 1
    np.testing.assert_allclose(cs.distance[j], -0.01, atol=1e-12)
    np.testing.assert_allclose(cs.normal[j], [[0.0, 0.0, 1.0]], atol=1e-12)
    # the contact point is on the surface, right under the vertex
    np.testing.assert_allclose(np.einsum("kj,kjd->kd", cs.weights[j], x[cs.others[j]]), [[0.2, -0.3, 0.5]],
                               atol=1e-12)
    # every bottom corner of the small box is 0.01 deep, with the normal out of the big box
    small = cs.vertex >= sim.system.vertex_offsets[1]
    assert np.count_nonzero(small) == 4
    np.testing.assert_allclose(cs.distance[small], -0.01, atol=1e-12)
    np.testing.assert_allclose(cs.normal[small], np.tile([0.0, 0.0, 1.0], (4, 1)), atol=1e-12)
    assert det.max_penetration(x) == pytest.approx(0.01, abs=1e-12)


def test_closest_point_on_a_degenerate_triangle_is_on_its_longest_edge():
    """A triangle of no area (collinear corners, two corners equal, a point): the closest point of a
    point is its projection on the longest edge, clamped to it."""
    a = np.array([[0.0, 0, 0], [0.0, 0, 0], [0.0, 0, 0], [1.0, 2, 3]])
    b = np.array([[1.0, 0, 0], [0.0, 0, 0], [2.0, 0, 0], [1.0, 2, 3]])
    c = np.array([[0.5, 0, 0], [2.0, 0, 0], [1.0, 0, 0], [1.0, 2, 3]])
    p = np.array([[0.8, 1.0, 0], [1.5, 0, 1.0], [-1.0, 0, 1.0], [0.0, 0, 0]])
    W = geometry.closest_points_on_triangles(p, a, b, c)
    q = np.einsum("kj,kjd->kd", W, np.stack([a, b, c], axis=1))
    np.testing.assert_allclose(q, [[0.8, 0, 0], [1.5, 0, 0], [0.0, 0, 0], [1.0, 2, 3]], atol=1e-15)
    np.testing.assert_allclose(W.sum(axis=1), 1.0)


def test_surface_points_of_only_degenerate_candidates_are_finite():
    """Every candidate triangle of a point without area: the sign from the mean outward normal of
    the candidates with an area (here the face beside them), else outside; never NaN."""
    seg = [[0.0, 0, 0], [1.0, 0, 0], [1.0, 0, 0]]                  # a segment on the x axis
    face = [[0.0, 0, 0], [1.0, -1, 0], [1.0, 1, 0]]                 # a face (normal +z) under it, farther
    corners = np.array([seg, face], dtype=float)
    corners[1, :, 2] -= 0.1
    points = np.array([[0.5, 0.0, -0.02], [0.5, 0.0, 0.02]])
    found, t, W, d, n = geometry.closest_surface_points(points, [0, 0, 1, 1], [0, 1, 0, 1], corners, 1e-12)
    np.testing.assert_array_equal(t, [0, 0])
    np.testing.assert_allclose(d, [-0.02, 0.02], atol=1e-15)
    np.testing.assert_allclose(n, [[0, 0, 1.0], [0, 0, 1.0]], atol=1e-15)
    # no candidate with an area: outside, along the direction from the closest point, or +z on it
    points = np.array([[0.5, 0.0, -0.02], [0.5, 0.0, 0.0]])
    found, t, W, d, n = geometry.closest_surface_points(points, [0, 1], [0, 0], corners[:1], 1e-12)
    np.testing.assert_allclose(d, [0.02, 0.0], atol=1e-15)
    np.testing.assert_allclose(n, [[0, 0, -1.0], [0, 0, 1.0]], atol=1e-15)


if __name__ == "__main__":  # writes the reference from the detection of this checkout
    arrays = {}
    for name, (sim, settings, frames) in cases().items():
        for k, got in enumerate(_detect(sim, settings, frames)):
            arrays.update({f"{name}/{k}/{f}": val for f, val in got.items()})
    os.makedirs(os.path.dirname(REFERENCE), exist_ok=True)
    np.savez_compressed(REFERENCE, **arrays)
    print({name: [len(v)] for name, v in arrays.items() if name.endswith("/vertex")})
