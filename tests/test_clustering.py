"""Algorithm 2: adjacency, thresholds, hinges, singletons, seeding, resource limiting."""
import numpy as np
import pytest

from skfem_affine.reducers.affine import clustering
from skfem_affine.kinematics import deformation_gradient, shape_gradients
from skfem_affine.lab.scenes import beam_mesh


@pytest.fixture(scope="module")
def beam():
    mesh = beam_mesh(2)
    grads, _ = shape_gradients(mesh)
    return mesh, grads, clustering.element_adjacency(mesh.t)


def rates(mesh, grads, v):
    return deformation_gradient(v, mesh.t, grads)


def test_adjacency_matches_scikit_fem(beam):
    mesh, _, (indptr, indices) = beam
    m = mesh.t.shape[1]
    pairs = set(zip(np.repeat(np.arange(m), np.diff(indptr)), indices))
    assert all((b, a) in pairs for a, b in pairs)
    assert np.diff(indptr).max() <= 4
    f2t = mesh.f2t[:, mesh.f2t[1] >= 0]
    ref = set(zip(f2t[0], f2t[1])) | set(zip(f2t[1], f2t[0]))
    assert pairs == ref


def test_uniform_affine_field_gives_one_cluster_and_zero_tau_none(beam):
    mesh, grads, adj = beam
    L = np.array([[0.1, 0.2, -0.3], [0.0, 0.5, 0.1], [0.4, -0.2, 0.2]])
    Fd = rates(mesh, grads, mesh.p.T @ L.T + 1.0)
    labels = clustering.cluster_deformation_rates(Fd, adj, mesh.t, mesh.p.shape[1], 1e-6, 1e-6)
    assert np.all(labels == 0)
    labels = clustering.cluster_deformation_rates(Fd, adj, mesh.t, mesh.p.shape[1], 0.0, 0.0)
    assert np.all(labels == -1)


def test_threshold_respected_at_insertion_and_clusters_are_vertex_disjoint(beam):
    mesh, grads, adj = beam
    rng = np.random.default_rng(3)
    v = np.sin(mesh.p.T * [1.3, 2.1, 0.7]) + 0.05 * rng.normal(size=mesh.p.T.shape)
    Fd = rates(mesh, grads, v)
    tau = 0.8
    labels, seeds, dist = clustering.cluster_deformation_rates(
        Fd, adj, mesh.t, mesh.p.shape[1], tau, tau, seeds=np.random.default_rng(0).permutation(mesh.t.shape[1]),
        return_seeds=True, return_distances=True)
    k = labels.max() + 1
    assert k >= 2 and np.any(labels == -1)
    members = labels >= 0
    accepted = members & ~np.isin(np.arange(labels.size), seeds)
    assert np.all(dist[accepted] < tau)
    # every surviving cluster has >= 2 elements; no vertex belongs to two clusters
    assert np.bincount(labels[members]).min() >= 2
    owner = np.full(mesh.p.shape[1], -1)
    for e in np.flatnonzero(members):
        for vtx in mesh.t[:, e]:
            assert owner[vtx] in (-1, labels[e])
            owner[vtx] = labels[e]


def test_two_regions_never_mix(beam):
    mesh, grads, adj = beam
    x = mesh.p.T
    v = np.where(x[:, :1] < 2.0, x @ np.diag([0.1, 0.1, 0.1]), x @ np.array([[0, -3.0, 0], [3.0, 0, 0], [0, 0, 0]]))
    Fd = rates(mesh, grads, v)
    left = np.all(mesh.p[0, mesh.t] <= 2.0 + 1e-12, axis=0)
    right = np.all(mesh.p[0, mesh.t] >= 2.0 - 1e-12, axis=0)
    labels = clustering.cluster_deformation_rates(Fd, adj, mesh.t, mesh.p.shape[1], 1e-3, 1e-3)
    for c in range(labels.max() + 1):
        inside = labels == c
        assert np.all(left[inside]) or np.all(right[inside])


def test_excluded_stay_elastic_and_forced_join(beam):
    mesh, grads, adj = beam
    rng = np.random.default_rng(0)
    Fd = rng.normal(size=(mesh.t.shape[1], 3, 3))  # all different: nothing clusters with tiny tau
    m = mesh.t.shape[1]
    assert np.all(clustering.cluster_deformation_rates(Fd, adj, mesh.t, mesh.p.shape[1], 1e-9, 1e-9) == -1)
    forced = np.ones(m, dtype=bool)
    excluded = np.zeros(m, dtype=bool)
    excluded[:10] = True
    labels = clustering.cluster_deformation_rates(Fd, adj, mesh.t, mesh.p.shape[1], 1e-9, 1e-9,
                                                  excluded=excluded, forced=forced)
    assert np.all(labels[:10] == -1) and np.mean(labels >= 0) > 0.3


def test_forced_set_selects_the_k_smallest(beam):
    mesh, grads, adj = beam
    Fd = np.random.default_rng(1).normal(size=(mesh.t.shape[1], 3, 3))
    sel = clustering.forced_set(Fd, adj, 0.25)
    m = Fd.shape[0]
    assert sel.sum() == round(0.25 * m)
    indptr, indices = adj
    worst = np.array([max(np.linalg.norm(Fd[e] - Fd[n]) for n in indices[indptr[e]:indptr[e + 1]]) for e in range(m)])
    assert worst[sel].max() <= np.sort(worst)[sel.sum() - 1] + 1e-12
    assert not clustering.forced_set(Fd, adj, 0.0).any()
    assert clustering.forced_set(Fd, adj, 1.0).all()
    with pytest.raises(ValueError, match="fraction"):
        clustering.forced_set(Fd, adj, 1.5)


def test_tau_e_applies_only_between_previously_affine_elements(beam):
    mesh, grads, adj = beam
    m = mesh.t.shape[1]
    Fd = np.zeros((m, 3, 3))
    Fd[1::2, 0, 0] = 1.0  # neighbours differ by d between tau_a and tau_e
    tau_a, tau_e = 0.1, 10.0
    none = clustering.cluster_deformation_rates(Fd, adj, mesh.t, mesh.p.shape[1], tau_a, tau_e)
    prev = clustering.cluster_deformation_rates(Fd, adj, mesh.t, mesh.p.shape[1], tau_a, tau_e,
                                                was_affine=np.ones(m, dtype=bool))
    assert (prev >= 0).sum() > (none >= 0).sum()


def test_seeding_is_deterministic_and_temporal_reuses_seeds(beam):
    mesh, grads, adj = beam
    v = np.sin(mesh.p.T * [1.3, 2.1, 0.7])
    Fd = rates(mesh, grads, v)
    m = mesh.t.shape[1]
    runs = [clustering.cluster_deformation_rates(
        Fd, adj, mesh.t, mesh.p.shape[1], 0.5, 0.5,
        seeds=clustering.seed_order(m, "random", np.random.default_rng(7))) for _ in range(2)]
    assert np.array_equal(*runs)
    order = clustering.seed_order(m, "temporal", np.random.default_rng(0), previous_seeds=[5, 3, 9])
    assert list(order[:3]) == [5, 3, 9] and np.array_equal(np.sort(order), np.arange(m))
    assert np.array_equal(clustering.seed_order(m, "index"), np.arange(m))
    with pytest.raises(ValueError, match="seeding"):
        clustering.seed_order(m, "spiral")


def test_components_of_eligible_elements(beam):
    mesh, _, adj = beam
    m = mesh.t.shape[1]
    eligible = np.all(mesh.p[0, mesh.t] > 2.5, axis=0)
    labels = clustering.cluster_components(eligible, adj, mesh.t, mesh.p.shape[1])
    assert np.all(labels[~eligible] == -1) and labels.max() == 0 and (labels == 0).sum() == eligible.sum()


def test_bad_input(beam):
    mesh, grads, adj = beam
    Fd = np.zeros((mesh.t.shape[1], 3, 3))
    with pytest.raises(ValueError, match="tau_a"):
        clustering.cluster_deformation_rates(Fd, adj, mesh.t, mesh.p.shape[1], -1.0, 1.0)
    Fd[0, 0, 0] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        clustering.cluster_deformation_rates(Fd, adj, mesh.t, mesh.p.shape[1], 1.0, 1.0)
