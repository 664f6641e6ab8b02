import os

import meshio
import numpy as np

import skfem_affine as sa


def test_write_series_opens_with_meshio(tmp_path):
    sim = sa.scenes.cantilever(resolution=1, E=1e5, damping=None)
    pvd = sa.io.write_series(tmp_path / "beam", sim, frames=4, every=2)
    assert os.path.exists(pvd)
    text = open(pvd).read()
    files = sorted(f for f in os.listdir(tmp_path) if f.endswith(".vtu"))
    assert files == ["beam_00000.vtu", "beam_00002.vtu", "beam_00004.vtu"]
    for f in files:
        assert f in text
    last = meshio.read(tmp_path / files[-1])
    assert np.allclose(last.points, sim.state.x)
    assert np.allclose(last.point_data["velocity"], sim.state.v)
    for key in ("cluster", "affine", "material"):
        assert key in last.cell_data
    assert np.all(last.cell_data["cluster"][0] == -1)


def test_load_mesh_roundtrip(tmp_path):
    mesh = sa.scenes.beam_mesh(1)
    meshio.write(tmp_path / "b.mesh", meshio.Mesh(mesh.p.T, [("tetra", mesh.t.T)]))
    back = sa.io.load_mesh(tmp_path / "b.mesh")
    assert back.t.shape == mesh.t.shape and np.allclose(back.p, mesh.p)
