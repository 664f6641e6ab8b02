"""benchmarks/paper_table1.py: a tiny run (2 frames) writes the paper's columns with its numbers beside ours."""
import importlib.util
import json
import os

import pytest

SCRIPT = os.path.join(os.path.dirname(__file__), "..", "benchmarks", "paper_table1.py")


def load():
    spec = importlib.util.spec_from_file_location("paper_table1", SCRIPT)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_a_two_frame_run_writes_the_table(shared_meshes, tmp_path):
    bench = load()
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


def test_every_row_is_a_row_of_the_paper_and_missing_meshes_are_refused(tmp_path):
    bench = load()
    assert {row for row, *_ in bench.SCENES.values()} <= set(bench.PAPER)
    assert set(bench.NOT_RUN) <= set(bench.PAPER)
    with pytest.raises(SystemExit):
        bench.main([str(tmp_path), "--scenes", "beam_neo", "--frames", "1"])
