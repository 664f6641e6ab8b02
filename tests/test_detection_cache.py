"""The candidate list of contact detection (pairs kept over frames within a skin) finds exactly the
contacts of a search from scratch, frame by frame, at rest, in an impact, and after a body moves
beyond the skin."""
import numpy as np
import pytest

import skfem_affine as sa
from skfem_affine.contact.geometry import Detector
from skfem_affine.lab.scenes import box_mesh

FIELDS = ("vertex", "others", "weights", "normal", "distance", "key", "own")


def _boxes(speed=0.0):
    """A soft box on the ground and a smaller one on it, off centre (``speed``: falling onto it)."""
    mat = sa.NeoHookean(E=1e6, nu=0.3)
    z = 0.26 if speed == 0.0 else 0.3
    bodies = [sa.ElasticBody(box_mesh(0.2, 2, (0.0, 0.0, 0.1)), mat, density=1000.0),
              sa.ElasticBody(box_mesh(0.12, 2, (0.02, 0.01, z)), mat, density=1000.0,
                             velocity=(0.3 * speed, 0.0, -speed))]
    return sa.Simulation(bodies, dt=0.01, gravity=(0.0, 0.0, -9.81), colliders=[sa.Plane()])


def _same(cs, ref):
    if cs is None or ref is None:
        return cs is None and ref is None
    return all((getattr(cs, f) is None and getattr(ref, f) is None)
               or np.array_equal(getattr(cs, f), getattr(ref, f)) for f in FIELDS)


def _compare(sim, frames):
    """Step ``sim``; each frame its detection (with the candidate list) against a search from scratch
    on the same positions and velocities. Returns the frames' contact counts."""
    det = sim.contact.detector
    scratch = Detector(sim.system, det.colliders, det.margin, skin=0.0)
    find, counts = det.find, []

    def both(x, v, dt, w=None):
        cs = find(x, v, dt, w)
        ref = scratch.find(x, v, dt, w)
        assert _same(cs, ref), f"frame {len(counts)}"
        counts.append(0 if cs is None else cs.size)
        return cs

    det.find = both
    for _ in range(frames):
        sim.step()
    return counts


def test_candidate_list_finds_the_contacts_of_a_full_search_at_rest():
    sim = _boxes()
    counts = _compare(sim, 35)
    det = sim.contact.detector
    assert min(counts[5:]) > 0
    assert det.builds < 10, det.builds          # the list is kept over most frames of a resting stack


def test_candidate_list_finds_the_contacts_of_a_full_search_in_an_impact():
    sim = _boxes(speed=2.0)
    counts = _compare(sim, 20)
    assert max(counts) > 0
    assert sim.contact.detector.builds >= 3     # rebuilt while the box falls


def test_candidate_list_rebuilt_when_a_body_moves_beyond_the_skin():
    sim = _boxes()
    det = sim.contact.detector
    scratch = Detector(sim.system, det.colliders, det.margin, skin=0.0)
    x, v = sim.state.x.copy(), np.zeros_like(sim.state.x)
    assert _same(det.find(x, v, sim.dt), scratch.find(x, v, sim.dt))
    builds = det.builds
    upper = det.body_of_vertex == 1
    # within the skin: kept; the upper box slid sideways by more than the skin: rebuilt, same contacts
    for shift, rebuilt in ((0.2 * det.skin, False), (0.3 * det.skin, False), (3.0 * det.skin, True),
                           (-0.04, True), (0.0, True)):
        y = x.copy()
        y[upper, 0] += shift
        y[upper, 2] -= 0.3 * det.margin
        assert _same(det.find(y, v, sim.dt), scratch.find(y, v, sim.dt)), shift
        assert (det.builds > builds) == rebuilt, shift
        builds = det.builds
    # a fast approach widens the reach beyond the list's: rebuilt
    v[upper, 2] = -20.0
    assert _same(det.find(x, v, sim.dt), scratch.find(x, v, sim.dt))
    assert det.builds > builds


def test_candidate_list_finds_the_edge_contacts_of_a_full_search():
    # two bars crossing like an X, coming together from beyond the first list's reach: only edges meet
    w, gap, speed = 0.1, 1.0, 5.0
    first = box_mesh((w, 1.0, w), (1, 5, 1), (-(w + gap) / 2, 0, 0))
    second = box_mesh((w, w, 1.0), (1, 1, 5), ((w + gap) / 2, 0, 0))
    mat = sa.NeoHookean(E=1e8, nu=0.35)
    sim = sa.Simulation([sa.ElasticBody(first, mat, density=1000.0, velocity=(speed, 0, 0)),
                         sa.ElasticBody(second, mat, density=1000.0, velocity=(-speed, 0, 0))],
                        dt=0.01, gravity=(0, 0, 0), contact=sa.PGS())
    det = sim.contact.detector
    edge = []
    find = det.find

    def count(*a):
        cs = find(*a)
        edge.append(0 if cs is None else int((cs.key >= det.n_vertices * det.n_kinds).sum()))
        return cs

    det.find = count
    _compare(sim, 20)
    assert max(edge) > 0 and edge[0] == 0, edge


def test_skin_is_checked():
    sim = _boxes()
    for skin in (-1.0, float("nan")):
        with pytest.raises(ValueError, match="skin"):
            Detector(sim.system, [], skin=skin)
