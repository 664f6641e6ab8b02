"""Every example in examples/ runs (at its default, small size) and computes the right thing."""
import os
import runpy

import numpy as np
import pytest

import skfem_affine as sa

EXAMPLES = os.path.join(os.path.dirname(__file__), "..", "examples")


def run(name):
    return runpy.run_path(os.path.join(EXAMPLES, name), run_name="example")


def test_every_example_is_tested():
    tested = {"cantilever.py", "beam_frequency.py", "affinification.py", "adaptive_subspace.py"}
    assert set(f for f in os.listdir(EXAMPLES) if f.endswith(".py")) <= tested


def test_cantilever_example():
    g = run("cantilever.py")
    assert g["sim"].state.frame == 100
    assert np.all(np.isfinite(g["tip_height"]))
    # soft beam: the tip falls, at first like a hinged rod (3g/2), then slower than free fall would allow
    assert -6.0 < g["lowest"] < -4.0


def test_beam_frequency_example_matches_euler_bernoulli():
    g = run("beam_frequency.py")
    assert g["f2"] > g["f3"] > g["f_theory"]  # locking: too stiff, improving with refinement
    assert abs(g["relative_error"]) < 0.05


def test_affinification_example_trades_dofs_for_error():
    g = run("affinification.py")
    r = g["results"]
    assert r["full"]["error"] == 0 and r["full"]["dof_ratio"] == 1
    assert r["affinification"]["dof_ratio"] < 0.9 and r["affinification"]["error"] < 0.05
    assert r["rigidification"]["dof_ratio"] < 1.0 and np.isfinite(r["rigidification"]["error"])


def test_adaptive_subspace_example_trades_enrichment_for_error():
    g = run("adaptive_subspace.py")
    r = g["results"]
    assert r[0.0]["enriched"].min() > 0.9 and r[0.0]["error"] < 1e-6  # the full-space solve
    assert 0.0 < r[1e-3]["enriched"].mean() < r[0.0]["enriched"].mean()
    assert r[0.0]["error"] < r[1e-3]["error"] < r[0.5]["error"] < 0.05
    assert r[0.5]["enriched"].max() == 0.0


def test_cli_demo(tmp_path, capsys):
    from skfem_affine.__main__ import main
    assert main(["demo", "--resolution", "1", "--frames", "20", "--every", "10", "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "frames/s" in out and "cantilever.pvd" in out
    assert sorted(os.listdir(tmp_path)) == ["cantilever.pvd", "cantilever_00000.vtu", "cantilever_00010.vtu",
                                            "cantilever_00020.vtu"]
