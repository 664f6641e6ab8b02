"""The command line as a process: what --help imports, progress in logs, exit codes a scene file cannot fake."""
import os
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
HEAVY = ("numpy", "scipy", "numba", "skfem", "matplotlib", "meshio", "dask", "distributed", "tqdm", "pyamg")


def cli(*argv, timeout=300, cwd=None):
    """``python -m skfem_affine ARGV`` with stdout and stderr piped (not a terminal)."""
    env = dict(os.environ, PYTHONPATH=ROOT + os.pathsep + os.environ.get("PYTHONPATH", ""))
    return subprocess.run([sys.executable, "-m", "skfem_affine", *argv], env=env, capture_output=True, text=True,
                          timeout=timeout, cwd=cwd)


def test_help_imports_no_simulation_module():
    code = ("import sys\n"
            "from skfem_affine.lab.cli import main\n"
            "for argv in ([], ['demo'], ['run'], ['compare'], ['sweep'], ['budget'], ['scaling'], ['scenes']):\n"
            "    assert main(argv + ['--help']) == 0\n"
            "print(' '.join(sorted(m for m in sys.modules if m.split('.')[0] in %r)))\n"
            "print(' '.join(sorted(m for m in sys.modules if m.startswith('skfem_affine'))))\n" % (HEAVY,))
    env = dict(os.environ, PYTHONPATH=ROOT)
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    heavy, ours = out.stdout.splitlines()[-2:]
    assert heavy == "", f"--help imported {heavy}"
    assert set(ours.split()) <= {"skfem_affine", "skfem_affine.lab", "skfem_affine.lab.cli",
                                 "skfem_affine.lab.methods"}, ours


def test_the_package_imports_its_names_on_first_use():
    code = ("import sys, skfem_affine as sa\n"
            "assert 'numba' not in sys.modules and 'scipy.sparse' not in sys.modules\n"
            "assert set(sa.__all__) <= set(dir(sa))\n"
            "from skfem_affine import Affinification, runners, io\n"
            "assert sa.Affinification is Affinification and io.__name__ == 'skfem_affine.lab.io'\n"
            "assert all(getattr(sa, name) is not None for name in sa.__all__)\n"
            "try:\n    sa.nope\nexcept AttributeError as err:\n    print(err)\n")
    out = subprocess.run([sys.executable, "-c", code], env=dict(os.environ, PYTHONPATH=ROOT), capture_output=True,
                         text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "module 'skfem_affine' has no attribute 'nope'"


def test_the_budget_methods_listed_for_help_are_the_budget_reducers():
    from skfem_affine.lab import cli, methods, runners, trade
    assert cli.BUDGET_METHODS == tuple(sorted(trade.REDUCERS))
    assert runners.METHODS is methods.METHODS


def test_scaling_on_files_that_are_no_mesh_is_one_line(tmp_path):
    (tmp_path / "junk.mesh").write_text("garbage\nnot a mesh\n")
    (tmp_path / "notes.md").write_text("# notes\n")
    for name in ("junk.mesh", "notes.md"):
        out = cli("scaling", "--meshes", name, "--frames", "1", "--out", str(tmp_path / "out"), cwd=tmp_path)
        lines = out.stderr.splitlines()
        assert out.returncode == 2 and "Traceback" not in out.stderr, out.stderr
        assert len(lines) == 1 and lines[0].startswith(f"skfem-affine scaling: error: mesh file '{name}' cannot be "
                                                       "read"), out.stderr
        assert out.stdout == ""  # refused before the header: no run started
