"""Smoke test of benchmarks/subspace_paper.py: 2 frames of each scene at the smallest size."""
import json
import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "benchmarks"))
import subspace_paper  # noqa: E402


def test_two_frames_of_every_scene_give_the_tables(tmp_path, capsys):
    out = tmp_path / "paper.json"
    rows = subspace_paper.main(["--cells", "2", "--frames", "2", "--subdomains", "8", "--modes", "4",
                                "--repeats", "1", "--json", str(out)])
    assert [r["scene"] for r in rows] == list(subspace_paper.SCENES)
    for r in rows:
        assert r["frames"] == 2 and 1 <= r["hard_step"] <= 2 and r["status"] == "ok/ok"
        assert r["newton_full"] >= 1 and r["newton_ours"] >= 1
        assert r["step_ours_s"] > 0 and r["step_full_s"] > 0 and r["direct_s"] > 0 and r["cg_iters"] >= 1
        assert 0 <= r["max_error"] < 0.05 and 0 <= r["enriched"] <= 1 and r["nnz_full"] > 0
        # the hard step's phase breakdown, with the IPC time measured inside the phases
        assert r["phases_full"]["factorization"] > 0 and r["phases_full"]["ipc_eval"] > 0
        assert r["phases_full"]["ipc_ccd"] > 0 and r["phases_ours"]["ipc_eval"] > 0
        assert r["phases_ours"]["ipc_shares"] > 0 and r["phases_full"]["ipc_shares"] == 0  # the oracle's only
        assert r["phases_full"]["ipc_eval"] < r["step_full_s"]
        assert r["system"] in ("captured", "rebuilt") and r.get("enr_enriched_dofs", 1) > 0
        assert len(r["per_frame"]["wall_full"]) == 2 and max(r["per_frame"]["error"]) == r["max_error"]
    assert json.loads(out.read_text())["rows"][0]["scene"] == "drop"
    text = capsys.readouterr().out
    assert "Jello Rubber" in text and "Fig. 5" in text and "by phase" in text


def test_unknown_scene_is_a_clear_error():
    import pytest
    with pytest.raises(ValueError, match="scene must be one of"):
        subspace_paper.scene("iceberg", 2)


def test_choosing_two_frames_write_rows_and_the_trade_picture(tmp_path):
    import choosing
    out = tmp_path / "choosing.json"
    rows = choosing.main(["--scenes", "drop", "beam", "--cells", "2", "--frames", "2", "--subdomains", "8",
                          "--modes", "4", "--eps", "0.1", "--taus", "0.3,0.6", "--json", str(out)])
    assert [(r["scene"], r["method"]) for r in rows] == [("drop", "adaptive subspace"), ("drop", "affinification"),
                                                         ("beam", "adaptive subspace"), ("beam", "affinification")]
    for r in rows:
        assert r["frames"] == 2 and r["speedup"] > 0 and 0 <= r["error"] < 0.05
    assert (tmp_path / "choosing.png").stat().st_size > 1000
