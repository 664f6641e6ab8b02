"""Candidate bases: affine modes, linear eigenmodes, Skinning Eigenmodes (sec. 4.6); disk cache."""
import numpy as np
import pytest

import skfem_affine as sa
from skfem_affine.reducers.subspace import bases


def cube(**kw):
    return sa.scenes.free_body(resolution=3, **kw).system


def beam():
    return sa.scenes.cantilever(resolution=1, E=1e5, damping=None).system


def in_span(U, field):
    q, *_ = np.linalg.lstsq(U, field, rcond=None)
    return np.linalg.norm(U @ q - field) / np.linalg.norm(field)


def affine_field(system, rng):
    A, c = rng.normal(size=(3, 3)), rng.normal(size=3)
    return (system.p0 @ A.T + c).reshape(-1)


@pytest.mark.parametrize("kind", [bases.AffineModes(), bases.SkinningEigenmodes(n=4, cache=False)])
def test_initial_block_reproduces_affine_and_rigid_motion(kind):
    system = cube()
    b = kind.build(system)
    U0 = b.U[:, np.concatenate([b.blocks[i] for i in b.initial])]
    rng = np.random.default_rng(0)
    assert in_span(U0, affine_field(system, rng)) < 1e-10
    assert in_span(U0, np.tile([0.0, 0.0, 1.0], system.n)) < 1e-10
    for blk in b.blocks:  # columns orthonormal within a block
        assert np.allclose(b.U[:, blk].T @ b.U[:, blk], np.eye(blk.size), atol=1e-10)


def test_skinning_weights_are_mass_orthonormal_eigenvectors():
    system = cube()
    [(verts, W, lam)] = bases.SkinningEigenmodes(n=5, cache=False).weights(system)
    M = np.diag(system.lumped_mass[verts])
    assert np.allclose(W.T @ M @ W, np.eye(5), atol=1e-8)
    assert np.ptp(W[:, 0]) < 1e-8 and abs(lam[0]) < 1e-8 * lam[-1]   # constant weight, zero eigenvalue
    assert np.all(np.diff(lam) >= -1e-9 * lam[-1])
    b = bases.SkinningEigenmodes(n=5, cache=False).build(system)
    assert b.size == 60 and len(b.blocks) == 5 and b.initial == [0]


def test_skinning_weights_vanish_at_fixed_vertices():
    system = beam()
    b = bases.SkinningEigenmodes(n=3, cache=False).build(system)
    fixed = np.repeat(system.fixed, 3)
    assert np.all(b.U[fixed] == 0) and np.linalg.norm(b.U[~fixed]) > 0


def test_linear_modes_are_orthonormal_eigenpairs_with_rigid_modes_first():
    system = cube()
    b = bases.LinearModes(n=10, cache=False).build(system)
    _, K = system.forces_and_stiffness(system.p0, project=False, full=True)
    M = system.M
    U, lam = b.U, b.eigenvalues
    assert np.allclose(U.T @ (M @ U), np.eye(10), atol=1e-8)
    assert np.linalg.norm(K @ U - (M @ U) * lam) <= 1e-6 * np.linalg.norm(K @ U)
    assert b.initial == list(range(6))  # six zero modes of a free body
    U6 = U[:, :6]
    assert in_span(U6, np.tile([1.0, 0.0, 0.0], system.n)) < 1e-8
    assert lam[6] > 1e3 * abs(lam[:6]).max()


def test_cache_hit_and_key(tmp_path):
    system = cube()
    first = bases.SkinningEigenmodes(n=3, cache_dir=tmp_path)
    b1 = first.build(system)
    assert not first.last_cache_hit and len(list(tmp_path.glob("*.npz"))) == 1
    second = bases.SkinningEigenmodes(n=3, cache_dir=tmp_path)
    b2 = second.build(system)
    assert second.last_cache_hit
    assert np.array_equal(b1.U, b2.U) and all(np.array_equal(x, y) for x, y in zip(b1.blocks, b2.blocks))
    stiff = cube(material=sa.NeoHookean(E=2e5, nu=0.35))
    assert first.key(stiff) != first.key(system)
    assert bases.SkinningEigenmodes(n=4).key(system) != first.key(system)


def test_cache_key_includes_the_code_version(tmp_path, monkeypatch):
    system = cube()
    kind = bases.SkinningEigenmodes(n=3, cache_dir=tmp_path)
    kind.build(system)
    key = kind.key(system)
    monkeypatch.setattr(bases, "_SOURCE", "0" * 40)  # other basis code
    assert kind.key(system) != key
    kind.build(system)
    assert not kind.last_cache_hit and len(list(tmp_path.glob("*.npz"))) == 2
    monkeypatch.undo()
    assert kind.key(system) == key
    monkeypatch.setattr(sa, "__version__", "0.0.0-other")  # another release
    assert kind.key(system) != key and "0.0.0-other" in bases.code_version()


def test_bad_mode_count():
    with pytest.raises(ValueError, match="n must be"):
        bases.SkinningEigenmodes(n=0)
