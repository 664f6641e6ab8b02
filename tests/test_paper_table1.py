"""benchmarks/paper_table1.py: a tiny run (2 frames) writes the paper's columns with its numbers beside ours."""
import json
import os

import numpy as np
import pytest



def test_a_two_frame_run_writes_the_table(shared_meshes, tmp_path, benchmark_script):
    bench = benchmark_script("paper_table1")
    out = str(tmp_path / "t1")
    rows = bench.main([shared_meshes, "--frames", "2", "--scenes", "beam_neo", "armadillo", "--out", out])
    beam, arma = rows
    assert beam["elements"] == 5516 and beam["vertices"] == 1264 and beam["frames"] == 2 and beam["h"] == 0.01
    assert beam["paper"]["full_s"] == 16.45 and beam["paper"]["speedup_affinification"] == 1.85
    for r in rows:
        assert r["full_s"] > 0 and r["affinification_s"] > 0 and r["rigidification_s"] > 0
        assert r["speedup_affinification"] == pytest.approx(r["full_s"] / r["affinification_s"])
        assert 0 <= r["max_distance_error_affinification"] < 0.1 and not r["diverged"]
    assert arma["stand_in"] and arma["paper_row"] == "Armadillo Res. Limited"
    table = open(out + ".md").read()
    assert "| Beam Neo | 2 (370) | 0.01 (0.01) | 5516 (5516) | 1264 (1264) |" in table
    assert "Explorer: not run" in table and "(stand-in)" in table
    assert json.load(open(out + ".json"))[0]["scene"] == "beam_neo"


def test_every_row_is_a_row_of_the_paper_and_missing_meshes_are_refused(tmp_path, benchmark_script):
    bench = benchmark_script("paper_table1")
    assert {row for row, *_ in bench.SCENES.values()} <= set(bench.PAPER)
    assert set(bench.NOT_RUN) <= set(bench.PAPER)
    with pytest.raises(SystemExit):
        bench.main([str(tmp_path), "--scenes", "beam_neo", "--frames", "1"])


def _tiny(reducer):
    import skfem_affine as sa
    return sa.scenes.drop(resolution=1, height=0.02, reducer=reducer)


def _tiny_reducers():
    import skfem_affine as sa
    return [sa.Affinification(tau_a=1e-2, tau_e=1e-1), sa.Rigidification(tau_r=1e-2, tau_e=1e-1)]


def test_a_run_stopped_and_resumed_equals_an_uninterrupted_one(tmp_path, benchmark_script):
    res = benchmark_script("resumable")
    sims, whole = res.run(_tiny, _tiny_reducers(), 8, log=open(os.devnull, "w"))
    folder = str(tmp_path / "ck")
    saved = []
    _, part = res.run(_tiny, _tiny_reducers(), 8, checkpoint=folder, every=3, stop_at=4, on_save=lambda p: saved.append(p["done"]),
                      log=open(os.devnull, "w"))
    assert part["done"] == 4 and saved == [3, 4]
    assert sorted(os.listdir(folder)) == sorted(["progress.json"] + [f"{m}-000004.npz" for m in res.METHODS])
    resumed_sims, resumed = res.run(_tiny, _tiny_reducers(), 8, checkpoint=folder, every=3,
                                    log=open(os.devnull, "w"))
    assert resumed["done"] == 8
    for key in ("errors", "kinetic"):
        assert resumed[key] == whole[key]
    for i in range(3):
        for col in ("dofs", "n_contacts", "pgs_iterations"):
            assert [r[col] for r in resumed["records"][i]] == [r[col] for r in whole["records"][i]]
        assert np.array_equal(resumed_sims[i].state.x, sims[i].state.x)
    assert any(e for e in whole["errors"][1]) and min(r["dofs"] for r in whole["records"][2]) < 75  # reduced
    with pytest.raises(ValueError, match="holds a run of 8 frames"):
        res.run(_tiny, _tiny_reducers(), 9, checkpoint=folder, log=open(os.devnull, "w"))


def test_the_rest_phase_and_its_summary(benchmark_script):
    res = benchmark_script("resumable")
    assert res.rest_start([0.0, 5.0, 10.0, 2.0, 0.05, 0.01, 0.02]) == 4
    assert res.rest_start([0.0, 5.0, 10.0, 2.0]) is None
    rec = {"wall": 1.0, "factorization": 0.2, "contact": 0.5, "delassus": 0.3, "pgs": 0.1, "dofs": 10,
           "n_contacts": 2, "pgs_iterations": 5}
    half = dict(rec, wall=0.5, dofs=5)
    progress = res.new_progress(4, res.METHODS, {})
    progress["records"] = [[rec] * 4, [rec, rec, half, half], [rec] * 4]
    progress["errors"] = [[None] * 4, [0.1, 0.2, 0.01, 0.02], [0.0] * 4]
    progress["kinetic"], progress["done"] = [1.0, 2.0, 0.001, 0.0], 4
    split = res.phases(progress)
    aff = split["rest"]["methods"]["affinification"]
    assert split["rest"]["frames"] == [3, 4] and aff["speedup"] == 2.0 and aff["dof_ratio"] == 0.5
    assert aff["max_distance_error"] == 0.02 and split["run"]["methods"]["affinification"]["max_distance_error"] == 0.2
    full = split["run"]["methods"]["full"]["means"]
    assert full["detection"] == pytest.approx(100.0) and full["other"] == pytest.approx(300.0)
    assert res.phases(progress, rest_from=2)["rest"]["frames"] == [2, 4]
    assert "| rest 3-4 | affinification | 1.0 | 2.00 | 2.0e-02 | 0.500 |" in res.tables(split)


def test_report_only_rewrites_a_saved_run_with_another_rest_phase(tmp_path, capsys, benchmark_script):
    bench, res = benchmark_script("paper_table1"), benchmark_script("resumable")
    folder = tmp_path / "wheel"
    folder.mkdir()
    rec = {"wall": 1.0, "factorization": 0.2, "contact": 0.5, "delassus": 0.3, "pgs": 0.1, "dofs": 10,
           "n_contacts": 2, "pgs_iterations": 5}
    progress = res.new_progress(1000, res.METHODS, {"scene": "wheel"})
    progress["records"] = [[rec] * 4 for _ in range(3)]
    progress["errors"] = [[None] * 4, [0.1] * 4, [0.2] * 4]
    progress["kinetic"], progress["done"] = [1.0, 2.0, 0.001, 0.0], 4
    (folder / "progress.json").write_text(json.dumps(progress))
    bench.main([str(tmp_path), "--scenes", "wheel", "--checkpoint", str(tmp_path), "--report-only", "--rest-from", "2"])
    report = (folder / "report.md").read_text()
    assert "4 of 1000 frames done" in report and "Rest phase: from frame 2 (given): frames 2-4." in report
    assert "peak 2 J at frame 2" in report and "| rest 2-4 | affinification | 3.0 | 1.00 | 1.0e-01 | 1.000 | 16.92 |" in report
    assert json.loads((folder / "report.json").read_text())["rest"]["frames"] == [2, 4]
