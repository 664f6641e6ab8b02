import os

import meshio
import numpy as np
import pytest

import skfem_affine as sa


def test_series_holds_exactly_the_states_written_in_the_loop(tmp_path):
    sim = sa.scenes.cantilever(resolution=1)
    series = sa.io.Series(tmp_path / "beam", sim)
    series.write(sim.state)
    for state in sim.run(4):
        if state.frame % 2 == 0:
            series.write(state)
    assert sim.state.frame == 4  # the series simulated nothing of its own
    text = open(series.pvd).read()
    files = sorted(f for f in os.listdir(tmp_path) if f.endswith(".vtu"))
    assert files == ["beam_00000.vtu", "beam_00002.vtu", "beam_00004.vtu"]
    assert [line.split('file="')[1].split('"')[0] for line in text.splitlines() if "DataSet" in line] == files
    last = meshio.read(tmp_path / files[-1])
    assert np.allclose(last.points, sim.state.x)
    assert np.allclose(last.point_data["velocity"], sim.state.v)
    for key in ("cluster", "affine", "material"):
        assert key in last.cell_data
    assert np.all(last.cell_data["cluster"][0] == -1)
    first = meshio.read(tmp_path / files[0])
    assert np.allclose(first.points, sim.system.p0)
    # writing a frame again replaces it rather than listing it twice
    series.write(sim.state)
    assert open(series.pvd).read().count("beam_00004.vtu") == 1


def test_write_series_writes_the_given_states_and_simulates_nothing(tmp_path):
    sim = sa.scenes.cantilever(resolution=1)
    states = list(sim.run(3))
    pvd = sa.io.write_series(tmp_path / "out" / "beam.pvd", sim, states=states)
    assert pvd == str(tmp_path / "out" / "beam.pvd") and sim.state.frame == 3
    assert sorted(os.listdir(tmp_path / "out")) == ["beam.pvd", "beam_00001.vtu", "beam_00002.vtu",
                                                    "beam_00003.vtu"]
    assert np.allclose(meshio.read(tmp_path / "out" / "beam_00002.vtu").points, states[1].x)
    with pytest.raises(TypeError):
        sa.io.write_series(tmp_path / "beam", sim, frames=100)  # the old, simulating call is refused


def test_series_refuses_what_is_not_its_simulation_s_state(tmp_path):
    sim = sa.scenes.cantilever(resolution=1)
    other = sa.scenes.cantilever(resolution=2)
    with pytest.raises(ValueError, match="not one of this simulation"):
        sa.io.Series(tmp_path / "beam", sim).write(other.state)
    with pytest.raises(TypeError, match="state must be"):
        sa.io.Series(tmp_path / "beam", sim).write(sim.state.x)
    with pytest.raises(TypeError, match="sim must be"):
        sa.io.Series(tmp_path / "beam", "beam")


def test_load_mesh_roundtrip(tmp_path):
    mesh = sa.scenes.beam_mesh(1)
    meshio.write(tmp_path / "b.mesh", meshio.Mesh(mesh.p.T, [("tetra", mesh.t.T)]))
    back = sa.io.load_mesh(tmp_path / "b.mesh")
    assert back.t.shape == mesh.t.shape and np.allclose(back.p, mesh.p)


@pytest.mark.parametrize("name, text", [("junk.mesh", "garbage\nnot a mesh\n"), ("empty.vtu", ""),
                                        ("notes.md", "# notes\n"), ("bad.msh", "$MeshFormat\n2.2 0 8\n")])
def test_load_mesh_on_a_file_meshio_cannot_read_is_a_value_error_naming_it(tmp_path, capfd, name, text):
    path = tmp_path / name
    path.write_text(text)
    with pytest.raises(ValueError, match=f"{name}'? (cannot be read|holds no tetrahedra)"):
        sa.io.load_mesh(path)
    out, err = capfd.readouterr()
    assert out == "" and err == ""  # meshio's own prints are folded into the message
    with pytest.raises(FileNotFoundError, match="nope.mesh"):
        sa.io.load_mesh(tmp_path / "nope.mesh")


def _written_frames(pvd):
    """The VTU files a .pvd lists (it must parse as XML)."""
    import xml.etree.ElementTree as ET
    return [d.get("file") for d in ET.parse(pvd).getroot().iter("DataSet")]


def test_a_vtu_write_that_fails_midway_leaves_no_partial_file_and_the_index_readable(tmp_path, monkeypatch):
    from skfem_affine.lab import io
    sim = sa.scenes.cantilever(resolution=1)
    series = io.Series(tmp_path / "beam", sim)
    series.write(sim.state)
    write = meshio.write

    def disk_full(filename, *args, **kwargs):  # a part of the file reaches the disk, then the write fails
        with open(filename, "wb") as fh:
            fh.write(b'<?xml version="1.0"?>\n<VTKFile type="UnstructuredGrid"')
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(meshio, "write", disk_full)
    state = next(sim.run(1))
    with pytest.raises(OSError, match="No space left"):
        series.write(state)
    assert sorted(os.listdir(tmp_path)) == ["beam.pvd", "beam_00000.vtu"]  # nothing truncated, no temporary file
    assert _written_frames(series.pvd) == ["beam_00000.vtu"]
    monkeypatch.setattr(meshio, "write", write)
    series.write(state)  # the series carries on after the failure
    assert _written_frames(series.pvd) == ["beam_00000.vtu", "beam_00001.vtu"]


def test_an_index_write_that_fails_midway_leaves_the_previous_index_readable(tmp_path, monkeypatch):
    from skfem_affine.lab import io
    sim = sa.scenes.cantilever(resolution=1)
    series = io.Series(tmp_path / "beam", sim)
    series.write(sim.state)
    state = next(sim.run(1))
    series.write(state)
    listed = _written_frames(series.pvd)

    class FailsAfterTheHeader:  # the index file's second write fails (a full disk, an interrupt)
        def __init__(self, *args, **kwargs):
            self.file, self.writes = open(*args, **kwargs), 0

        def write(self, text):
            self.writes += 1
            if self.writes > 1:
                raise KeyboardInterrupt
            return self.file.write(text)

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            self.file.close()

    monkeypatch.setattr(io, "open", FailsAfterTheHeader, raising=False)
    with pytest.raises(KeyboardInterrupt):
        series.write(next(sim.run(1)))
    assert _written_frames(series.pvd) == listed == ["beam_00000.vtu", "beam_00001.vtu"]
    assert not [f for f in os.listdir(tmp_path) if ".tmp" in f]
    monkeypatch.undo()
    series.write(sim.state)
    assert _written_frames(series.pvd) == listed + ["beam_00002.vtu"]
