"""The core runs without the extras, and each feature of an extra says in one line which extra it needs.

The core is checked in a child process whose imports of the optional packages fail, as in an
environment with only the core installed; the features of the extras in this process, with the
package set to None in ``sys.modules`` (which makes its import fail with ModuleNotFoundError).
"""
import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest

import skfem_affine as sa
from skfem_affine._extras import MissingExtra
from test_readme import EXTRA, PAGES, RUN, where

ROOT = os.path.normpath(os.path.join(os.path.dirname(__file__), ".."))

#: The packages of the extras (pyproject.toml's optional dependencies).
OPTIONAL = ("pypardiso", "ipctk", "pymetis", "dask", "distributed", "cloudpickle", "tqdm", "h5py", "pyarrow")

#: Prepended to a child's code: every import of an optional package fails as if it were not installed.
HIDE = textwrap.dedent(f"""
    import sys
    HIDDEN = {set(OPTIONAL)!r}

    class Hidden:
        def find_spec(self, name, path=None, target=None):
            if name.split(".")[0] in HIDDEN:
                raise ModuleNotFoundError(f"No module named {{name!r}}", name=name)
            return None

    sys.meta_path.insert(0, Hidden())
""")

#: Appended: which optional packages were imported after all (none may be).
LEAKED = 'print("LEAKED", sorted(m for m in sys.modules if m.split(".")[0] in HIDDEN))'


def run_core(code, tmp_path):
    """Run ``code`` in a child process without the optional packages; its stdout."""
    script = tmp_path / "core.py"
    script.write_text(HIDE + "\n" + code + "\n" + LEAKED + "\n")
    env = {**os.environ, "PYTHONPATH": ROOT + os.pathsep + os.environ.get("PYTHONPATH", "")}
    done = subprocess.run([sys.executable, str(script)], cwd=tmp_path, env=env, capture_output=True, text=True,
                          timeout=900)
    assert done.returncode == 0, done.stderr[-3000:]
    assert "LEAKED []" in done.stdout, done.stdout[-500:]
    return done.stdout


def test_the_hider_hides(tmp_path):
    out = run_core("import importlib\nfor m in HIDDEN:\n    try:\n        importlib.import_module(m)\n"
                   "    except ModuleNotFoundError:\n        print('hidden', m)", tmp_path)
    assert sorted(line.split()[1] for line in out.splitlines() if line.startswith("hidden")) == sorted(OPTIONAL)


def test_the_core_simulates_without_the_extras(tmp_path):
    out = run_core(textwrap.dedent("""
        import numpy as np
        import skfem_affine as sa

        full = sa.scenes.cantilever(resolution=1)
        reduced = sa.scenes.cantilever(resolution=1, reducer=sa.Affinification(tau_a=0.1, tau_e=0.2))
        drop = sa.scenes.drop(resolution=1)
        newton = sa.scenes.cantilever(resolution=1, integrator="implicit_euler",
                                      colliders=[sa.Plane(point=(0, 0, -1.0), normal=(0, 0, 1))])
        for sim in (full, reduced, drop, newton):
            for state in sim.run(3):
                pass
            assert np.all(np.isfinite(state.x)), sim
        series = sa.io.Series("out/beam", full)
        series.write(full.state)
        print("solver", full.stats[-1]["solver"], "contacts", max(r["n_contacts"] for r in drop.stats))
        print(full.stats.summary())
    """), tmp_path)
    assert "solver superlu" in out  # the auto solver without Pardiso
    assert (tmp_path / "out" / "beam.pvd").is_file()


CORE_BLOCKS = [(p, n, c) for p, n, info, c in RUN if p == PAGES[0] and not EXTRA.match(info)]


@pytest.mark.slow
@pytest.mark.parametrize("path, line, code", CORE_BLOCKS, ids=[where(p, n) for p, n, _ in CORE_BLOCKS])
def test_a_readme_block_without_an_extra_runs_on_the_core(path, line, code, tmp_path):
    run_core("\n" * (line - 1) + code, tmp_path)


def test_the_readme_names_the_extra_of_a_block_that_needs_one():
    assert [info for p, _, info, _ in RUN if p == PAGES[0] and EXTRA.match(info)] == ["extra: subspace"]


# ------------------------------------------------------------------ each extra's features without it
def hide(monkeypatch, *packages):
    for name in packages:
        for loaded in [m for m in sys.modules if m == name or m.startswith(name + ".")]:
            monkeypatch.delitem(sys.modules, loaded)
        monkeypatch.setitem(sys.modules, name, None)


def assert_names_extra(err, extra):
    text = str(err.value)
    assert "\n" not in text and f"the '{extra}' extra: pip install 'skfem-affine[{extra}]'" in text, text
    assert isinstance(err.value, ModuleNotFoundError)


def two_beams(**kwargs):
    a = sa.scenes.cantilever(resolution=1).bodies[0]
    b = sa.ElasticBody(a.mesh.translated((0, 3, 0)), sa.StVK(E=1e6, nu=0.3))
    return sa.Simulation([a, b], dt=0.01, **kwargs)


def test_ipc_names_the_ipc_extra(monkeypatch):
    hide(monkeypatch, "ipctk")
    with pytest.raises(MissingExtra, match=r"^sa\.IPC .*default with several bodies") as err:
        two_beams(integrator="implicit_euler", contact=sa.IPC())
    assert_names_extra(err, "ipc")
    with pytest.raises(MissingExtra, match=r"^sa\.IPC") as err:  # the default between bodies under Newton
        two_beams(integrator="implicit_euler")
    assert_names_extra(err, "ipc")
    two_beams(integrator="implicit_euler", contact=False).step()  # no contact: no ipctk


def test_pardiso_names_the_fast_extra(monkeypatch):
    hide(monkeypatch, "pypardiso")
    for make in (lambda: sa.solvers.make_solver("pardiso"), sa.solvers.Pardiso):
        with pytest.raises(MissingExtra, match="Pardiso") as err:
            make()
        assert_names_extra(err, "fast")
    assert sa.solvers.make_solver("auto").name == "auto"  # auto chooses among what is installed


def test_pardiso_orderings_name_the_fast_extra(monkeypatch):
    pytest.importorskip("pypardiso")
    hide(monkeypatch, "pymetis")
    with pytest.raises(MissingExtra, match="METIS") as err:
        sa.scenes.cantilever(resolution=1, solver="pardiso", reducer=sa.Affinification(tau_a=0.1, tau_e=0.2))
    assert_names_extra(err, "fast")


def test_subspace_subdomains_name_the_subspace_extra(monkeypatch):
    hide(monkeypatch, "pymetis")
    body = sa.scenes.cantilever(resolution=1).bodies[0]
    with pytest.raises(MissingExtra, match="AdaptiveSubspace") as err:
        sa.Simulation(body, dt=0.01, integrator="implicit_euler",
                      reducer=sa.AdaptiveSubspace(basis=sa.AffineModes(), subdomains=4))
    assert_names_extra(err, "subspace")
    sim = sa.Simulation(body, dt=0.01, integrator="implicit_euler",  # one subdomain: no METIS
                        reducer=sa.AdaptiveSubspace(basis=sa.AffineModes(), subdomains=1))
    assert np.all(np.isfinite(sim.step().x))


def test_sweep_names_the_lab_extra(monkeypatch):
    from skfem_affine.lab import sweep
    hide(monkeypatch, "dask", "distributed")
    with pytest.raises(MissingExtra, match="sweep") as err:
        sweep.connect(workers=1)
    assert_names_extra(err, "lab")


def test_sweep_cells_name_the_lab_extra(monkeypatch):
    from skfem_affine.lab import cells
    hide(monkeypatch, "cloudpickle")
    with pytest.raises(MissingExtra, match="sweep's cells") as err:
        cells.cloudpickle.dumps(len)
    assert_names_extra(err, "lab")


def test_xdmf_names_the_lab_extra(monkeypatch, tmp_path):
    import meshio
    mesh = sa.scenes.cantilever(resolution=1).bodies[0].mesh
    path = str(tmp_path / "beam.xdmf")
    meshio.write(path, meshio.Mesh(mesh.p.T, [("tetra", mesh.t.T)]))  # with h5py
    hide(monkeypatch, "h5py")
    with pytest.raises(MissingExtra, match="beam.xdmf") as err:
        sa.io.load_mesh(path)
    assert_names_extra(err, "lab")


def test_parquet_names_the_parquet_extra(monkeypatch, tmp_path):
    from skfem_affine.lab import tables
    hide(monkeypatch, "pyarrow")
    with pytest.raises(MissingExtra, match="parquet") as err:
        tables.write_table([{"a": 1}], tmp_path / "t.parquet")
    assert_names_extra(err, "parquet")
    assert tables.read_table(tables.write_table([{"a": 1}], tmp_path / "t.csv")) == [{"a": 1}]


def test_progress_without_tqdm_is_lines(monkeypatch):
    from skfem_affine.lab import progress
    hide(monkeypatch, "tqdm")
    monkeypatch.setattr(progress, "_is_terminal", lambda stream: True)
    assert isinstance(progress.bar(3, "run", enabled=True), progress.LogProgress)


def test_another_missing_module_is_not_called_an_extra(monkeypatch):
    from skfem_affine._extras import require
    with pytest.raises(ModuleNotFoundError) as err:
        require("no_such_module_here", "a feature", "fast")
    assert not isinstance(err.value, MissingExtra)


def test_the_test_extra_installs_every_extra():
    tomllib = pytest.importorskip("tomllib")  # Python >= 3.11
    with open(os.path.join(ROOT, "pyproject.toml"), "rb") as fh:
        project = tomllib.load(fh)["project"]
    extras = project["optional-dependencies"]
    core = " ".join(project["dependencies"])
    assert not any(name in core for name in OPTIONAL)
    assert "skfem-affine[all,docs]" in extras["test"]
    named = {e for e in extras["all"][0].split("[")[1].rstrip("]").split(",")}
    listed = " ".join(d for e in named for d in extras[e])
    assert all(name in listed for name in OPTIONAL), listed
