"""The command line as a process: what --help imports, progress in logs, exit codes a scene file cannot fake."""
import os
import subprocess
import sys

import pytest

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


@pytest.mark.slow
def test_a_scene_that_calls_sys_exit_is_an_error_not_a_success(tmp_path):
    (tmp_path / "exits.py").write_text("import sys\n\ndef scene(reducer=None, **kwargs):\n    sys.exit(0)\n")
    (tmp_path / "leaves.py").write_text("import sys\nsys.exit(0)\n")
    sweep = ["sweep", "--frames", "1", "--grid", "1", "--workers", "1"]
    for name, line, commands in (("exits.py", 4, (["run", "--frames", "1"], sweep)),
                                 ("leaves.py", 2, (["run", "--frames", "1"],))):
        for command in commands:
            out = cli(command[0], name, *command[1:], "--out", str(tmp_path / "out"), cwd=tmp_path)
            assert out.returncode == 2, (command, out.stderr)
            assert out.stderr.splitlines()[-1] == f"skfem-affine {command[0]}: error: scene file {name}, line {line}: " \
                                                  "called sys.exit(0) instead of returning a Simulation (scene(**kwargs) " \
                                                  "must return one)", out.stderr
            assert "Traceback" not in out.stderr


def test_out_of_memory_is_one_line_naming_the_size(tmp_path):
    out = cli("run", "--resolution", "5000", "--frames", "1", "--out", str(tmp_path))
    assert out.returncode == 1 and "Traceback" not in out.stderr, out.stderr
    line = out.stderr.splitlines()[-1]
    assert line.startswith("skfem-affine run: error: out of memory (Unable to allocate ") and "iB for an array" in line
    assert "--resolution 5000" in line


def test_progress_reaches_a_log_file(tmp_path):
    out = cli("run", "free_body", "--resolution", "1", "--frames", "3", "--method", "full", "--no-paraview",
              "--out", str(tmp_path))
    assert out.returncode == 0, out.stderr
    lines = [line for line in out.stderr.splitlines() if "frame" in line and "compiling" not in line]
    assert lines and lines[-1].startswith("free_body full: frame 3/3"), out.stderr


# a scene whose sweep cells sleep (with SLOW set) once the sweep's reference is cached: Ctrl-C then
# comes while the cells run on the cluster's worker processes
SLEEPY = """import glob, os, time
import skfem_affine as sa

def scene(reducer=None, **kwargs):
    if reducer is not None and os.environ.get("SLOW") and glob.glob({out!r} + "/sweep/*/reference_*.npz"):
        time.sleep(120)
    return sa.scenes.free_body(resolution=1, reducer=reducer, **kwargs)
"""


@pytest.mark.slow
def test_ctrl_c_on_a_sweep_prints_one_line_and_the_sweep_resumes(tmp_path):
    import signal
    import time
    out = tmp_path / "out"
    (tmp_path / "sleepy.py").write_text(SLEEPY.format(out=str(out)))
    argv = [sys.executable, "-m", "skfem_affine", "sweep", "sleepy.py", "--frames", "3", "--grid", "1", "--workers",
            "1", "--no-step-error", "--no-residual", "--out", str(out)]
    env = dict(os.environ, PYTHONPATH=ROOT, SLOW="1")
    # a terminal's foreground job takes Ctrl-C; a test runner started in the background of a script
    # inherits SIGINT ignored, which exec keeps: restore the terminal's disposition for the sweep
    proc = subprocess.Popen(argv, cwd=tmp_path, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True, preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    deadline = time.time() + 240
    while not list(out.glob("sweep/*/reference_*.npz")) and proc.poll() is None and time.time() < deadline:
        time.sleep(0.2)
    time.sleep(2.0)  # the cell has started (and sleeps)
    os.killpg(proc.pid, signal.SIGINT)  # what Ctrl-C in a terminal does: the whole foreground group
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 130 and "Traceback" not in err, err
    assert [line for line in err.splitlines() if "compiling" not in line] == ["skfem-affine sweep: interrupted"]
    env.pop("SLOW")
    done = subprocess.run(argv + ["--json"], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    import json
    summary = json.loads(done.stdout)
    assert summary["cells"] == 1 and summary["failed"] == 0 and summary["rows"][0]["status"] == "ok"


def test_log_progress_says_the_start_every_interval_and_the_end():
    import io

    from skfem_affine.lab.progress import LogProgress, NoProgress, bar
    stream = io.StringIO()
    log = LogProgress(4, "beam full", seconds=3600, stream=stream)
    for _ in range(4):
        log.update(1)
    log.close()
    lines = stream.getvalue().splitlines()
    assert [line.split(",")[0] for line in lines] == ["beam full: frame 1/4", "beam full: frame 4/4"]
    assert "about" in lines[0] and "left" not in lines[1]
    stream = io.StringIO()
    log = LogProgress(3, "sweep cells", unit="cell", seconds=0, stream=stream)  # a line per update
    log.update(1)
    log.update(1)
    log.close()  # stopped early: the last count is said once
    assert [line.split(",")[0] for line in stream.getvalue().splitlines()] == ["sweep cells: cell 1/3",
                                                                             "sweep cells: cell 2/3"]
    assert isinstance(bar(3, "x", False), NoProgress)
