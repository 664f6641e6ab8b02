"""Near-incompressible bodies: the locking warning and the volumetric energy on vertex patches."""
import warnings

import numpy as np
import pytest
import scipy.sparse.linalg as spl
import skfem
from skfem.models.elasticity import lame_parameters, linear_elasticity

import skfem_affine as sa
from skfem_affine.assembly import ElasticSystem
from skfem_affine.lab import metrics, runners

L, B, E_BEAM, LOAD = 1.0, 0.1, 1e7, 10.0


def beam_mesh(nx=20, ny=2, nz=6):
    return skfem.MeshTet.init_tensor(np.linspace(0, L, nx + 1), np.linspace(0, B, ny + 1), np.linspace(0, B, nz + 1))


def body(mesh, nu, volumetric, material=sa.NeoHookean, E=E_BEAM):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", sa.SimulationWarning)
        return sa.ElasticBody(mesh, material(E=E, nu=nu), fixed=mesh.p[0] < 1e-9, volumetric=volumetric)


def test_near_incompressible_element_body_warns_once_naming_the_stiffening_and_the_option():
    mesh = beam_mesh(4, 1, 2)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        sa.ElasticBody(mesh, sa.NeoHookean(E=1e6, nu=0.49))
    locking = [w for w in caught if issubclass(w.category, sa.SimulationWarning)]
    assert len(locking) == 1
    text = str(locking[0].message)
    assert "nu = 0.49" in text and "lam / mu = 49" in text and "too stiff" in text
    assert 'volumetric="nodal"' in text
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        sa.ElasticBody(mesh, sa.NeoHookean(E=1e6, nu=0.44))                      # below the threshold
        sa.ElasticBody(mesh, sa.NeoHookean(E=1e6, nu=0.49), volumetric="nodal")  # the locking-free option
    with pytest.warns(sa.SimulationWarning, match="nu = 0.45"):  # per-element nu: the largest counts
        sa.ElasticBody(mesh, sa.StVK(E=1e6, nu=np.r_[0.3, np.full(mesh.t.shape[1] - 1, 0.45)]))


def test_volumetric_must_be_element_or_nodal():
    mesh = beam_mesh(2, 1, 1)
    with pytest.raises(ValueError, match="volumetric must be one of 'element', 'nodal'"):
        sa.ElasticBody(mesh, sa.NeoHookean(E=1e6, nu=0.3), volumetric="mean")
    with pytest.raises(ValueError, match="volumetric"):
        sa.ElasticBody(mesh, sa.NeoHookean(E=1e6, nu=0.3), volumetric=None)


@pytest.mark.parametrize("material", [sa.NeoHookean, sa.StVK, sa.Corotational])
def test_nodal_forces_and_stiffness_are_the_derivatives_of_the_energy(material):
    mesh = beam_mesh(3, 2, 2)
    other = skfem.MeshTet.init_tensor(np.linspace(2, 2.3, 3), np.linspace(0, 0.2, 2), np.linspace(0, 0.2, 2))
    sysm = ElasticSystem([body(mesh, 0.49, "nodal", material, E=1e5), body(other, 0.3, "element", material, E=1e5)])
    rng = np.random.default_rng(1)
    x = sysm.p0 + 0.03 * rng.standard_normal(sysm.p0.shape)
    f, H = sysm.forces_and_stiffness(x, project=False, full=True)
    d, h = rng.standard_normal(x.shape), 1e-6
    slope = (sysm.strain_energy(x + h * d) - sysm.strain_energy(x - h * d)) / (2 * h)
    assert slope == pytest.approx(-f @ d.ravel(), rel=1e-7)
    fd = -(sysm.forces_and_stiffness(x + h * d, tangent=False)[0]
           - sysm.forces_and_stiffness(x - h * d, tangent=False)[0]) / (2 * h)
    assert np.linalg.norm(fd - H @ d.ravel()) <= 1e-7 * np.linalg.norm(fd)
    # the free-DOF pattern holds the same matrix, vertex couplings included; projected it is PSD
    data = sysm.evaluate(x, project=False)
    assert abs(sysm.pattern.matrix(data.H) - H[sysm.free][:, sysm.free]).max() <= 1e-9 * abs(H).max()
    Hp = sysm.pattern.matrix(sysm.evaluate(x, project=True).H).toarray()
    assert np.linalg.eigvalsh(Hp).min() >= -1e-9 * np.abs(Hp).max()
    # the stresses give the same forces (the route of the line searches and of stress output)
    P, _ = sysm.stresses(sysm.deformation_gradients(x), tangent=False)
    assert np.allclose(sysm._internal_force(P), f, rtol=0, atol=1e-12 * np.abs(f).max())


def p2_tip_deflection(mesh, nu):
    """scikit-fem's linear elastic P2 solve on the same mesh: the tip load as a uniform traction."""
    element = skfem.ElementVector(skfem.ElementTetP2())
    basis = skfem.Basis(mesh, element)
    K = skfem.asm(linear_elasticity(*lame_parameters(E_BEAM, nu)), basis)

    @skfem.LinearForm
    def traction(v, w):
        return -LOAD / B ** 2 * v[2]

    f = skfem.asm(traction, skfem.FacetBasis(mesh, element, facets=mesh.facets_satisfying(lambda x: x[0] > L - 1e-9)))
    u = skfem.solve(*skfem.condense(K, f, D=basis.get_dofs(lambda x: x[0] < 1e-9)))
    return -u[basis.get_dofs(lambda x: x[0] > L - 1e-9).nodal["u^3"]].mean()


def tip_deflection(mesh, nu, volumetric):
    """Our static equilibrium under the tip load (Newton on the exact tangent)."""
    sysm = ElasticSystem([body(mesh, nu, volumetric)])
    tip = np.flatnonzero(mesh.p[0] > L - 1e-9)
    f_ext = np.zeros((sysm.n, 3))
    f_ext[tip, 2] = -LOAD / tip.size
    x = sysm.p0.copy()
    for _ in range(3):
        f, H = sysm.forces_and_stiffness(x, project=False)
        x.ravel()[sysm.free] += spl.spsolve(sysm.pattern.matrix(H).tocsc(), (f + f_ext.ravel())[sysm.free])
    return -(x[tip, 2] - sysm.p0[tip, 2]).mean()


@pytest.mark.slow
def test_nodal_volume_removes_the_locking_of_a_near_incompressible_cantilever():
    """At nu = 0.49 the nodal treatment deflects, relative to P2, as P1 does at nu = 0.3: what is left
    is the bending error of linear tetrahedra, which does not depend on nu (docs/materials.md)."""
    mesh = beam_mesh()
    compressible = tip_deflection(mesh, 0.3, "element") / p2_tip_deflection(mesh, 0.3)
    p2 = p2_tip_deflection(mesh, 0.49)
    nodal, element = tip_deflection(mesh, 0.49, "nodal") / p2, tip_deflection(mesh, 0.49, "element") / p2
    assert nodal == pytest.approx(compressible, rel=0.05)
    assert element < 0.7 * compressible  # the locking it removes


def test_an_element_body_evaluates_bit_identically_beside_a_nodal_one():
    mesh = beam_mesh(3, 1, 2)
    other = skfem.MeshTet.init_tensor(np.linspace(2, 2.3, 3), np.linspace(0, 0.2, 2), np.linspace(0, 0.2, 2))
    alone = ElasticSystem([body(other, 0.3, "element")])
    both = ElasticSystem([body(mesh, 0.49, "nodal"), body(other, 0.3, "element")])
    rng = np.random.default_rng(2)
    x = both.p0 + 0.02 * rng.standard_normal(both.p0.shape)
    n0 = both.vertex_offsets[1]
    f_alone, H_alone = alone.forces_and_stiffness(x[n0:], full=True)
    f_both, H_both = both.forces_and_stiffness(x, full=True)
    assert np.array_equal(f_both[3 * n0:], f_alone)
    assert (H_both[3 * n0:, 3 * n0:] != H_alone).nnz == 0
    assert H_both[:3 * n0, 3 * n0:].nnz == 0  # no coupling between the bodies
    assert both.strain_energy(x) - both.nodal.energy(both.deformation_gradients(x)) > 0


def test_affinification_reduces_a_nodal_body_within_its_budget():
    mesh = beam_mesh(10, 2, 4)

    def simulation(reducer):
        return sa.Simulation(body(mesh, 0.49, "nodal", E=1e6), dt=0.01, gravity=(0, 0, -9.81), reducer=reducer)

    budget = 0.05
    sims = {"full": simulation(None), "aff": simulation(sa.Affinification(target_error=budget, never_slower=False))}
    full, worst, peak = sims["full"], [0.0], [0.0]

    def on_frame(frame, running):
        peak[0] = max(peak[0], metrics.response_amplitude(full.state.x, full.system.p0))
        worst[0] = max(worst[0], metrics.distance_m(running["aff"].state.x, full.state.x))

    runs = runners.interleaved(sims, 40, on_frame=on_frame)
    assert peak[0] > 0.01                      # it bends
    assert worst[0] <= 1.25 * budget * peak[0]
    assert runs["aff"].summary["dof_ratio"] < 1.0  # it was reduced


def test_nodal_bodies_refuse_what_does_not_see_their_vertex_couplings():
    mesh = beam_mesh(4, 1, 2)
    clamp = sa.Prescribed(np.flatnonzero(mesh.p[0] < 1e-9), lambda t, X: X)
    with pytest.raises(ValueError, match='prescribed vertices are not supported with volumetric="nodal"'):
        sa.ElasticBody(mesh, sa.NeoHookean(E=1e6, nu=0.49), prescribed=clamp, volumetric="nodal")
    with pytest.raises(ValueError, match="AdaptiveSubspace does not support"):
        sim = sa.Simulation(body(mesh, 0.49, "nodal", E=1e6), dt=0.01, integrator="implicit_euler",
                            reducer=sa.AdaptiveSubspace())
        sim.step()
