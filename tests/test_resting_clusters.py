"""A body at rest keeps its clusters: the oracle does not take a touching vertex's estimated impulse
(the contact solver's guess for a contact that carried none last frame) as a push on a body at rest,
only on a body an impact hits (oracle.explicit_impulse)."""
import numpy as np
import pytest

import skfem_affine as sa
from skfem_affine.lab.scenes import box_mesh
from skfem_affine.reducers.affine import oracle


def _box_on_two_planes(reducer):
    """A soft box resting on the ground, and under the ground a slightly tilted plane: at rest the
    bottom vertices on one side are within one step of gravity of it, touching it with no impulse
    (as the paper's pills touch the bowl around their support)."""
    body = sa.ElasticBody(box_mesh(0.2, 2, (0.0, 0.0, 0.1)), sa.NeoHookean(E=1e6, nu=0.3), density=1000.0)
    under = sa.Plane(point=(0.0, 0.0, -1e-4), normal=(0.005, 0.0, 1.0))
    return sa.Simulation(body, dt=0.01, gravity=(0.0, 0.0, -9.81), colliders=[sa.Plane(), under], reducer=reducer)


def _same_partition(a, b):
    """Whether two labelings group the elements alike (cluster ids may differ)."""
    pairs = set(zip(a.tolist(), b.tolist()))
    return len(pairs) == len(set(a.tolist())) == len(set(b.tolist()))


def _run(frames, rest_from, compare=True):
    """Affinification at the paper's thresholds (and full space stepped with it, ``compare``): the
    largest vertex distance between them, and per frame from ``rest_from`` whether the clusters changed."""
    full, reduced = _box_on_two_planes(None) if compare else None, _box_on_two_planes(sa.Affinification(1e-5, 1e-4))
    error, changed, previous = 0.0, [], None
    for frame in range(1, frames + 1):
        reduced.step()
        if compare:
            full.step()
            error = max(error, float(np.linalg.norm(full.state.x - reduced.state.x, axis=1).max()))
        labels = reduced.reducer.labels.copy()
        if frame > rest_from:
            changed.append(not _same_partition(previous, labels))
        previous = labels
    return reduced, error, changed


@pytest.mark.slow
def test_a_resting_box_keeps_its_clusters_frame_to_frame():
    # settled by frame 60 (largest speed 4e-8 m/s); measured: one cluster, unchanged from frame 66
    sim, error, changed = _run(80, 70)
    rest = sim.stats[70:]
    assert not any(changed)
    assert all(r["n_clusters"] == 1 and r["reduced_fraction"] == 1.0 for r in rest)
    assert np.abs(sim.state.v).max() < 1e-7
    # the trajectory: within 1.2e-4 of the box's size of full space over the whole run (measured 4.1e-5 m,
    # all of it from the settling, the same as with the contact solver's impulses); no vertex sinks
    size = np.linalg.norm(np.ptp(sim.system.p0, axis=0))
    assert error < 1.5e-4 * size
    assert sim.state.x[:, 2].min() > -1e-6


def test_the_touching_vertices_estimates_made_the_resting_box_flicker(monkeypatch):
    """The cause, kept as a check: with every contact solver's impulse as an explicit force (the
    estimates on touching vertices included), the box at rest changes its clusters every frame."""
    monkeypatch.setattr(oracle, "explicit_impulse", lambda problem: problem.contact_impulse)
    sim, _, changed = _run(80, 70, compare=False)
    assert sum(changed) >= 8
    assert np.mean([r["reduced_fraction"] for r in sim.stats[70:]]) < 0.9


def test_an_impact_keeps_its_estimated_impulses_and_a_resting_body_its_support(monkeypatch):
    """Two boxes side by side: one resting on the ground, one landing beside it. In the landing
    frame the landing box takes the contact solver's impulses (its new contacts' estimates), the
    resting one its warm-started support alone."""
    mat = sa.NeoHookean(E=1e6, nu=0.3)
    bodies = [sa.ElasticBody(box_mesh(0.2, 1, (0.0, 0.0, 0.1)), mat, density=1000.0),
              sa.ElasticBody(box_mesh(0.2, 1, (0.5, 0.0, 0.1 + 0.05)), mat, density=1000.0, velocity=(0, 0, -1.0))]
    sim = sa.Simulation(bodies, dt=0.01, gravity=(0.0, 0.0, -9.81), colliders=[sa.Plane()],
                        reducer=sa.Affinification(1e-5, 1e-4))
    seen = []
    plain = oracle.explicit_impulse

    def recording(problem):
        out = plain(problem)
        seen.append((problem, np.array(out) if np.ndim(out) else out))
        return out
    monkeypatch.setattr(oracle, "explicit_impulse", recording)
    for _ in range(10):
        sim.step()
    sysm = sim.system
    n0 = bodies[0].mesh.p.shape[1]
    first = np.flatnonzero(sysm.free // 3 < n0)  # the resting box's free DOFs
    second = np.flatnonzero(sysm.free // 3 >= n0)
    landing = [(p, out) for p, out in seen if p.contacts is not None and np.any(p.contacts.impact)]
    assert landing, "no frame with an impact"
    for problem, out in landing:
        offered, support = problem.contact_impulse, problem.support_impulse
        support = np.zeros_like(offered) if not np.ndim(support) else support
        assert np.array_equal(out[second], offered[second]) and np.any(offered[second] != support[second])
        assert np.array_equal(out[first], support[first])
    # frames without an impact take the support alone
    quiet = [(p, out) for p, out in seen if p.contacts is not None and not np.any(p.contacts.impact)]
    assert quiet and all(np.array_equal(out, p.support_impulse if np.ndim(p.support_impulse) else np.zeros_like(out))
                         for p, out in quiet)


def test_without_contacts_the_offered_impulse_is_kept():
    class Problem:  # no contact set: whatever the contact solver offered (here nothing)
        contact_impulse, support_impulse, contacts = 0.0, 0.0, None
    assert oracle.explicit_impulse(Problem()) == 0.0


@pytest.mark.slow
def test_a_frame_in_the_last_frames_clusters_reuses_its_mapping_bit_for_bit():
    """Affine bodies' G depends on their clusters alone (rows from the rest positions): a frame with
    the last frame's clusters reuses its mapping, numbering and order; a frame whose clusters changed
    (the box settling) builds them anew. Positions equal a run that rebuilds every frame, bit for bit."""
    reusing, rebuilding = (_box_on_two_planes(sa.Affinification(1e-5, 1e-4)) for _ in range(2))
    rebuilding.reducer.mapping_from_rest = False
    kept, changed = [], []
    for _ in range(80):
        before = reusing.reducer.labels.copy()
        reusing.step()
        rebuilding.step()
        kept.append(reusing.reducer._kept["gmap"])
        changed.append(not np.array_equal(before, reusing.reducer.labels))
    assert np.array_equal(reusing.state.x, rebuilding.state.x) and np.array_equal(reusing.state.v, rebuilding.state.v)
    assert any(changed[1:60]) and not any(changed[70:])
    for i in range(1, 80):
        assert (kept[i] is kept[i - 1]) == (not changed[i])  # reused exactly while the clusters stay
    sysm, red = reusing.system, reusing.reducer
    fresh = red._mapping(_Problem(sysm), kept[-1].vcluster, kept[-1].n_bodies)
    assert (fresh.G != kept[-1].G).nnz == 0
    # rigid bodies' rows follow the pose: rigidification never reuses
    assert sa.Rigidification(1e-5, 1e-4).mapping_from_rest is False


class _Problem:
    """What a reducer's _mapping reads of a frame: its system."""

    def __init__(self, system):
        self.system = system


def test_a_spinning_affine_box_reuses_its_mapping_and_moves_as_when_rebuilt():
    """A box flying and spinning (one affine body, the same cluster every frame): its G is kept while
    it moves and rotates, and the positions equal those of a run that rebuilds G every frame, bit for bit."""
    mesh = box_mesh(0.2, 2, (0.0, 0.0, 1.0))
    spin = np.cross([0.0, 0.0, 3.0], mesh.p.T - [0.0, 0.0, 1.0]) + [1.0, 0.0, 0.0]

    def flying(reuse):
        body = sa.ElasticBody(mesh, sa.NeoHookean(E=1e6, nu=0.3), density=1000.0, velocity=spin)
        sim = sa.Simulation(body, dt=0.01, gravity=(0.0, 0.0, -9.81), reducer=sa.Affinification(1e-2, 2e-2))
        sim.reducer.mapping_from_rest = reuse
        return sim
    reusing, rebuilding = flying(True), flying(False)
    kept = []
    for _ in range(20):
        reusing.step()
        rebuilding.step()
        kept.append(reusing.reducer._kept["gmap"])
    assert all(r["n_clusters"] == 1 for r in reusing.stats[1:])
    assert all(k is kept[1] for k in kept[2:])                      # kept while it moves and turns
    assert np.array_equal(reusing.state.x, rebuilding.state.x) and np.array_equal(reusing.state.v, rebuilding.state.v)
    assert np.abs(reusing.state.x.mean(axis=0)[0] - 0.2) < 1e-2      # it flew 0.2 m along x


def test_the_clustering_sees_predicted_rates_where_affine_and_actual_rates_elsewhere(monkeypatch):
    """Algorithm 2's rates: the predicted velocities' for elements affine the frame before, the actual
    ones' for the others, whether most elements were affine (one pass with the predicted velocities)
    or few (one pass with the actual ones), bit for bit."""
    from skfem_affine.reducers.affine import clustering
    sim = _box_on_two_planes(sa.Affinification(1e-5, 1e-4))
    sim.step()
    red, sysm = sim.reducer, sim.system
    rng = np.random.default_rng(0)
    v, v_pred = rng.normal(size=(sysm.n, 3)), rng.normal(size=(sysm.n, 3))
    seen = []

    def recording(Fdot, *args, **kwargs):
        seen.append(np.array(Fdot))
        return np.full(sysm.m, -1), np.zeros(0, dtype=np.int64)
    monkeypatch.setattr(clustering, "cluster_deformation_rates", recording)

    class Problem:
        system = sysm
    Problem.v = v
    for fraction in (0.0, 0.2, 0.8, 1.0):
        red.was_reduced = rng.random(sysm.m) < fraction
        red._labels(Problem, v_pred)
        expected = np.where(red.was_reduced[:, None, None], sysm.deformation_gradients(v_pred),
                            sysm.deformation_gradients(v))
        assert np.array_equal(seen[-1], expected)
