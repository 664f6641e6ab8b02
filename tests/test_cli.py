"""The command line: every subcommand end to end on a tiny beam, --json output, written files."""
import json
import os
import socket
import time

import meshio
import numpy as np
import pytest

from skfem_affine.lab.cli import SUMMARY_KEYS, main, parser


def run_json(capsys, argv):
    code = main(argv + ["--json"])
    out = capsys.readouterr().out
    lines = [line for line in out.splitlines() if line.strip()]
    assert len(lines) == 1, f"--json must print exactly one line, got: {out!r}"
    return code, json.loads(lines[0])


def test_help_on_every_subcommand(capsys):
    for command in ("demo", "run", "compare", "sweep", "budget", "scaling", "scenes"):
        assert main([command, "--help"]) == 0
        assert "usage: skfem-affine " + command in capsys.readouterr().out
    commands = parser()._subparsers._group_actions[0].choices
    assert set(commands) == {"demo", "run", "compare", "sweep", "budget", "scaling", "scenes"}


def test_scenes_lists_the_scene_registry(capsys):
    code, listing = run_json(capsys, ["scenes"])
    assert code == 0 and {"cantilever", "free_body"} <= set(listing["scenes"])
    assert "resolution" in listing["scenes"]["cantilever"]["parameters"]
    main(["scenes"])
    assert "cantilever" in capsys.readouterr().out


def test_run_json_with_reference(tmp_path, capsys):
    code, s = run_json(capsys, ["run", "cantilever", "--resolution", "1", "--frames", "6", "--method",
                                "affinification", "--tau-a", "0.3", "--tau-e", "0.6", "--reference", "--out",
                                str(tmp_path), "--every", "3"])
    assert code == 0 and set(SUMMARY_KEYS) <= set(s)
    assert s["scene"] == "cantilever" and s["method"] == "affinification" and s["frames"] == 6
    assert s["elements"] == 24 and s["vertices"] == 20
    for key in ("wall_s", "speedup", "dof_ratio", "mean_clusters", "max_distance_error"):
        assert isinstance(s[key], float), key
    out = tmp_path / "run" / "cantilever"
    assert {"affinification_frames.csv", "affinification_clusters.png", "paraview"} <= set(os.listdir(out))
    assert sorted(os.listdir(out / "paraview")) == ["affinification.pvd", "affinification_00000.vtu",
                                                    "affinification_00003.vtu", "affinification_00006.vtu"]
    # without a reference the reference metrics are null, but every key is there
    code, s = run_json(capsys, ["run", "free_body", "--resolution", "1", "--frames", "3", "--method", "full",
                                "--out", str(tmp_path), "--no-paraview"])
    assert code == 0 and set(SUMMARY_KEYS) <= set(s) and s["speedup"] is None and s["max_distance_error"] is None


def test_compare_json_and_outputs(tmp_path, capsys):
    code, s = run_json(capsys, ["compare", "--resolution", "1", "--frames", "12", "--tau-a", "0.3", "--tau-e",
                                "0.6", "--every", "4", "--gif", "--out", str(tmp_path)])
    assert code == 0 and set(SUMMARY_KEYS) <= set(s) and s["method"] == "affinification"
    assert set(s["methods"]) == {"full", "affinification", "rigidification"}
    assert s["methods"]["full"]["speedup"] == 1.0 and s["max_distance_error"] >= 0
    out = tmp_path / "compare" / "cantilever"
    names = set(os.listdir(out))
    assert {"frames.csv", "summary.csv", "compare_speedup.png", "compare_dofs.png", "compare_phases.png",
            "compare_error.png", "compare_clusters.png", "affinification.gif", "full.gif"} <= names
    # the ParaView series opens with meshio and holds the cell data
    pv = out / "paraview"
    assert {"full.pvd", "affinification.pvd", "rigidification.pvd"} <= set(os.listdir(pv))
    assert "affinification_00012.vtu" in open(pv / "affinification.pvd").read()
    mesh = meshio.read(pv / "affinification_00012.vtu")
    cluster = mesh.cell_data["cluster"][0]
    assert cluster.shape == (24,) and mesh.point_data["velocity"].shape == (20, 3)
    assert np.array_equal(mesh.cell_data["affine"][0], (cluster >= 0).astype(np.int8))
    assert np.all(mesh.cell_data["material"][0] == 0)


@pytest.mark.slow
def test_sweep_json(tmp_path, capsys):
    argv = ["sweep", "--resolution", "1", "--frames", "4", "--grid", "2", "--tau-range", "0.01", "0.3",
            "--workers", "1", "--threads", "--no-step-error", "--paired-timing", "--out", str(tmp_path)]
    code, s = run_json(capsys, argv)
    assert code == 0 and set(SUMMARY_KEYS) <= set(s) and s["cells"] == 4 and s["failed"] == 0
    assert len(s["rows"]) == 4 and os.path.exists(s["table"]) and os.path.exists(s["heatmaps"]) and os.path.exists(s["trade"])
    assert s["best_tau_a"] in (0.01, 0.3) and all(r["timing"] == "paired" for r in s["rows"])


def test_scaling_json(tmp_path, capsys):
    code, s = run_json(capsys, ["scaling", "--resolutions", "1", "2", "--frames", "4", "3", "--out", str(tmp_path)])
    assert code == 0 and set(SUMMARY_KEYS) <= set(s)
    assert [r["elements"] for r in s["rows"]] == [24, 192] and s["elements"] == 192
    assert os.path.exists(s["figure"]) and os.path.exists(s["table"])


def test_scaling_on_mesh_files(tmp_path, capsys):
    import skfem
    m = skfem.MeshTet.init_tensor(np.linspace(-1, 1, 2), np.linspace(-1, 1, 2), np.linspace(0, 6, 4))
    path = str(tmp_path / "little.mesh")
    meshio.write(path, meshio.Mesh(m.p.T, [("tetra", m.t.T)]))
    code, s = run_json(capsys, ["scaling", "--meshes", path, "--material", "corotational", "--frames", "3",
                                "--tau-a", "0.1", "1", "--target-error", "0.5", "--out", str(tmp_path)])
    assert code == 0 and set(SUMMARY_KEYS) <= set(s) and s["scene"] == "paper_beam"
    rows = s["rows"]
    assert [(r["mesh"], r["elements"], r["material"], r["tau_a"], r["tau_e"]) for r in rows] == \
        [("little.mesh", 18, "corotational", 0.1, 0.2), ("little.mesh", 18, "corotational", 1.0, 2.0)]
    assert sum(r["chosen"] for r in rows) == 1 and all(r["paper"] is None for r in rows)
    assert os.path.exists(s["figure"]) and os.path.exists(s["table"])


def test_scaling_prints_the_papers_speedup_beside_ours(tmp_path, capsys, shared_meshes):
    beam = os.path.join(shared_meshes, "beam913.mesh")
    assert main(["scaling", "--meshes", beam, "--frames", "2", "--tau-a", "0.1", "--target-error", "1",
                 "--phases", "--out", str(tmp_path)]) == 0
    lines = capsys.readouterr().out.splitlines()
    head = lines[1].split()
    assert head[:2] == ["size", "elements"] and "paper" in head and "err/len" in head
    row = lines[2].split()
    assert row[:2] == ["beam913", "3803"] and row[9] == "1.64" and row[-1] == "*"  # size ... speedup paper
    assert lines[3].strip().startswith("ms per frame, full: wall") and "assembly" in lines[3]


def test_user_scene_file(tmp_path, capsys):
    f = tmp_path / "drop.py"
    f.write_text("import skfem_affine as sa\n"
                 "def scene(reducer=None, **kw):\n"
                 "    return sa.scenes.free_body(resolution=1, reducer=reducer, **kw)\n")
    code, s = run_json(capsys, ["run", str(f), "--frames", "3", "--method", "full", "--out", str(tmp_path),
                                "--no-paraview", "--set", "spin=(0, 0, 1)"])
    assert code == 0 and s["scene"] == "drop" and s["elements"] == 6 * 1


def error_line(capsys):
    """The one stderr line of a refused command (and no traceback)."""
    err = capsys.readouterr().err
    lines = err.splitlines()
    assert len(lines) == 1 and lines[0].startswith("skfem-affine") and "Traceback" not in err, err
    return lines[0]


MISTAKES = [
    (["run", "nope"], "unknown scene 'nope'"),
    (["run", "cantilever", "--set", "oops"], "KEY=VALUE"),
    (["compare", "--methods", "nope"], "unknown method"),
    (["compare", "--frames", "0"], "argument --frames: must be >= 1, got 0"),
    (["run", "--frames", "ten"], "argument --frames: must be a whole number, got 'ten'"),
    (["run", "--resolution", "0"], "argument --resolution: must be >= 1"),
    (["run", "--every", "0"], "argument --every: must be >= 1"),
    (["run", "--tau-a", "nan"], "argument --tau-a: must be a finite number >= 0"),
    (["run", "--tau-e", "-1"], "argument --tau-e: must be a finite number >= 0"),
    (["compare", "--taus", "rigidification=inf,1"], "must be finite"),
    (["compare", "--taus", "rigidification=1"], "METHOD=TAU_A,TAU_E"),
    (["sweep", "--grid", "0"], "argument --grid: must be >= 1"),
    (["sweep", "--workers", "-1"], "argument --workers: must be >= 1, got -1"),
    (["sweep", "--workers", "100000"], "--workers 100000 is more than this machine's"),
    (["run", "--set", "frames=abc"], "--set frames=abc: frames must be a whole number >= 1"),
    (["sweep", "--tau-range", "0.1", "inf"], "argument --tau-range: must be a finite number > 0, got inf"),
    (["sweep", "--tau-range", "0", "1"], "argument --tau-range: must be a finite number > 0"),
    (["sweep", "--tau-range", "1", "0.1"], "LO <= HI"),
    (["sweep", "--scheduler", "nonsense"], "--scheduler takes tcp://HOST:PORT"),
    (["scaling", "--resolution", "2"], "--resolution is not an option here; use --resolutions"),
    (["scaling", "--resolutions", "1", "2", "--frames", "1", "2", "3"], "one per resolution (2), got 3"),
    (["scaling", "--resolutions", "0"], "argument --resolutions: must be >= 1"),
    (["scaling", "--meshes", "nope.mesh"], "--meshes: 'nope.mesh' is not a file (give the path of a mesh file"),
    (["scaling", "cantilever", "--meshes", "nope.mesh"], "scene 'cantilever' has no mesh parameter to scale"),
    (["scaling", "--tau-a", "0.1", "--tau-e", "0.2", "0.3"], "--tau-e takes one value per --tau-a (1), got 2"),
    (["scaling", "--tau-e", "0.2"], "--tau-e needs --tau-a"),
    (["scaling", "--target-error", "0"], "argument --target-error: must be a finite number > 0"),
    (["scaling", "--material", "rubber"], "argument --material: invalid choice: 'rubber'"),
    (["demo", "extra"], "unrecognized arguments: extra"),
    (["run", "--frame", "-2"], "argument --frame: must be >= 0"),
]


@pytest.mark.parametrize("argv, says", MISTAKES, ids=[" ".join(a) for a, _ in MISTAKES])
def test_every_mistake_is_one_line_and_exit_code_2(tmp_path, capsys, argv, says):
    code = main(argv + ["--out", str(tmp_path / "out")])
    line = error_line(capsys)
    assert code == 2
    assert says in line
    assert not os.path.exists(tmp_path / "out") or not os.listdir(tmp_path / "out")  # refused before any work


def test_out_pointing_at_a_file_is_refused(tmp_path, capsys):
    (tmp_path / "results").write_text("mine")
    for argv in (["demo"], ["run", "--frames", "1"], ["compare", "--frames", "1"], ["scaling", "--resolutions", "1"]):
        assert main(argv + ["--out", str(tmp_path / "results")]) == 2
        assert "--out" in error_line(capsys) and (tmp_path / "results").read_text() == "mine"


def test_a_scene_file_that_raises_is_named_with_its_line(tmp_path, capsys):
    files = {"imports.py": "import skfem_affine\nx = 1 / 0\n",
             "builds.py": "def scene(reducer=None, **kwargs):\n    raise RuntimeError('no mesh here')\n",
             "typo.py": "def scene(reducer=None:\n    pass\n"}
    expected = {"imports.py": "line 2: ZeroDivisionError: division by zero",
                "builds.py": "line 2: RuntimeError: no mesh here",
                "typo.py": "line 1: SyntaxError"}
    for name, text in files.items():
        (tmp_path / name).write_text(text)
        for command in (["run", "--frames", "2"], ["compare", "--frames", "2"]):
            assert main([command[0], str(tmp_path / name)] + command[1:] + ["--out", str(tmp_path)]) == 2
            line = error_line(capsys)
            assert f"scene file {tmp_path / name}, {expected[name]}" in line, line


def test_a_scheduler_at_a_closed_port_is_refused_at_once(tmp_path, capsys):
    with socket.socket() as s:  # a free localhost port: nothing listens there once closed
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    t0 = time.perf_counter()
    code = main(["sweep", "--resolution", "1", "--frames", "2", "--grid", "1", "--scheduler",
                 f"tcp://127.0.0.1:{port}", "--out", str(tmp_path)])
    assert code == 2 and time.perf_counter() - t0 < 20
    assert f"--scheduler tcp://127.0.0.1:{port}: no dask scheduler answers there" in error_line(capsys)


def test_headers_are_human_readable(tmp_path, capsys):
    assert main(["run", "free_body", "--resolution", "1", "--frames", "2", "--method", "full", "--no-paraview",
                 "--out", str(tmp_path)]) == 0
    assert capsys.readouterr().out.splitlines()[0] == "run: free_body (resolution=1), 2 frames: full"
    assert main(["run", "--resolution", "1", "--frames", "2", "--tau-a", "0.3", "--no-paraview",
                 "--set", "dt=0.005", "--out", str(tmp_path)]) == 0
    assert capsys.readouterr().out.splitlines()[0] == \
        "run: cantilever (dt=0.005, resolution=1), 2 frames: affinification (tau_a=0.3, tau_e=0.2)"
    assert main(["scaling", "--resolutions", "1", "--frames", "2", "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert out.splitlines()[0] == "scaling: cantilever, resolutions 1, 2 frames: affinification " \
                                  "(tau_a=0.1, tau_e=0.2) against full space"
    assert "{" not in out


def test_demo(tmp_path, capsys):
    assert main(["demo", "--resolution", "1", "--frames", "10", "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "speedup" in out and "affinification-budget" in out and "a looser one buys little" in out
    names = set(os.listdir(tmp_path / "demo"))
    assert {"compare_clusters.png", "compare_speedup.png", "trade.png"} <= names


def test_budget_command_runs_each_budget_against_full_space(tmp_path, capsys):
    code, s = run_json(capsys, ["budget", "--resolution", "1", "--frames", "6", "--errors", "0.01", "0.05",
                                "--never-slower", "off", "--out", str(tmp_path)])
    assert code == 0 and [r["budget"] for r in s["rows"]] == [0.01, 0.05]
    assert all(r["timing"] == "interleaved" and r["speedup"] > 0 and r["error"] >= 0 for r in s["rows"])
    assert os.path.isfile(s["trade"]) and os.path.isfile(s["table"])
    assert main(["budget", "--errors", "2", "--resolution", "1", "--frames", "2", "--out", str(tmp_path)]) == 2
    assert "target_error" in capsys.readouterr().err


def test_compare_and_run_say_how_they_timed(tmp_path, capsys):
    base = ["--resolution", "1", "--frames", "4", "--no-step-error", "--no-residual", "--no-paraview",
            "--out", str(tmp_path)]
    assert main(["compare"] + base) == 0
    assert "timing: interleaved frame by frame in one process" in capsys.readouterr().out
    code, s = run_json(capsys, ["compare", "--sequential-timing"] + base)
    assert code == 0 and s["timing"] == "sequential"
    assert all(m["timing"] == "sequential" for m in s["methods"].values())
    code, s = run_json(capsys, ["run", "--reference", "--method", "rigidification"] + base)
    assert code == 0 and s["timing"] == "interleaved" and s["speedup"] > 0
    assert main(["run", "--reference"] + base) == 0
    assert "timing: interleaved frame by frame in one process" in capsys.readouterr().out


def test_scaling_needs_a_resolution_parameter(tmp_path, capsys):
    f = tmp_path / "fixed.py"
    f.write_text("import skfem_affine as sa\n"
                 "def scene(reducer=None, dt=0.01):\n"
                 "    return sa.scenes.free_body(resolution=1, reducer=reducer, dt=dt)\n")
    assert main(["scaling", str(f), "--resolutions", "1", "2", "--out", str(tmp_path / "out")]) == 2
    assert "has no resolution parameter to scale" in error_line(capsys)
    assert not os.path.exists(tmp_path / "out")


def test_a_status_is_never_ok_beside_an_error_over_the_budget(tmp_path, capsys):
    from types import SimpleNamespace

    from skfem_affine.lab.cli import _hold_to_budget
    for error, budget, status in ((0.02, 0.01, "over-budget"), (0.005, 0.01, "ok"), (0.02, None, "ok"),
                                  (None, 0.01, "ok")):
        run = SimpleNamespace(summary={"status": "ok", "max_distance_error": error},
                              sim=SimpleNamespace(reducer=SimpleNamespace(target_error=budget, relative_to="size")))
        _hold_to_budget(run)
        assert run.summary["status"] == status
    # the error is read in the budget's unit: 2 % of the response is over a 1 % budget of the response
    run = SimpleNamespace(summary={"status": "ok", "max_distance_error": 0.001, "max_response_error": 0.02},
                          sim=SimpleNamespace(reducer=SimpleNamespace(target_error=0.01, relative_to="response")))
    _hold_to_budget(run)
    assert run.summary["status"] == "over-budget"
    # the budget command: every row's status agrees with its achieved error and its budget
    code, s = run_json(capsys, ["budget", "--resolution", "1", "--frames", "6", "--errors", "1e-7", "0.05",
                                "--never-slower", "off", "--out", str(tmp_path)])
    for r in s["rows"]:
        assert r["status"] == ("over-budget" if r["error"] > r["budget"] else "ok"), r
    assert code == (0 if all(r["status"] == "ok" for r in s["rows"]) else 1)


def test_run_uses_the_error_budget_by_default_and_says_so(tmp_path, capsys):
    assert main(["run", "--resolution", "1", "--frames", "2", "--no-paraview", "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert out.splitlines()[0] == "run: cantilever (resolution=1), 2 frames: affinification-budget (error budget " \
                                  "0.01, thresholds chosen per frame)"
    assert "errors: not measured (--reference" in out
    assert main(["run", "--resolution", "1", "--frames", "2", "--no-paraview", "--reference", "--no-step-error",
                 "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    for column in ("status:", "speedup =", "DOF ratio =", "bodies =", "dist err =", "step err =", "residual =",
                   "energy err ="):
        assert column in out, column
    assert "-: not measured (step err: --no-step-error;" in out
    help_text = parser()._subparsers._group_actions[0].choices["run"].format_help()
    assert "default: affinification-budget" in " ".join(help_text.split())


def test_a_scene_file_that_ignores_the_reducer_is_refused_not_reported_as_the_method(tmp_path, capsys):
    f = tmp_path / "deaf.py"
    f.write_text("import skfem_affine as sa\n"
                 "def scene(reducer=None, **kw):  # never hands the reducer to the simulation\n"
                 "    return sa.scenes.cantilever(resolution=1, **kw)\n")
    for method in ([], ["--method", "affinification"]):  # the default error budget, and fixed thresholds
        code = main(["run", str(f), "--frames", "2", "--no-paraview", "--out", str(tmp_path / "out")] + method)
        line = error_line(capsys)
        assert code == 2
        assert "scene 'deaf' was given reducer=Affinification(...) but its simulation runs in full space" in line
    out = tmp_path / "sweep"  # a sweep refuses it before it starts a cluster or makes a folder
    assert main(["sweep", str(f), "--frames", "2", "--grid", "1", "--workers", "1", "--out", str(out)]) == 2
    assert "was given reducer=Affinification(...) but its simulation runs in full space" in error_line(capsys)
    assert not out.exists()
    code, s = run_json(capsys, ["run", str(f), "--frames", "2", "--method", "full", "--no-paraview",
                                "--out", str(tmp_path / "out")])
    assert code == 0 and s["method"] == "full" and s["status"] == "ok"  # what it does run is measured
    f.write_text("import skfem_affine as sa\n"
                 "def scene(reducer=None, **kw):  # its own reducer whatever it is given\n"
                 "    return sa.scenes.cantilever(resolution=1, reducer=sa.Rigidification(0.1, 0.2), **kw)\n")
    assert main(["run", str(f), "--frames", "2", "--method", "full", "--no-paraview", "--out", str(tmp_path)]) == 2
    assert "was given reducer=None (full space) but its simulation runs under its own Rigidification" in \
        error_line(capsys)
