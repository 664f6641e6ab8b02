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
    tested = {"cantilever.py", "beam_frequency.py", "affinification.py", "compare.py"}
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


def test_compare_example_measures_the_trade():
    g = run("compare.py")
    s = g["summary"]
    assert s["full"]["max_distance_error"] == 0 and s["full"]["speedup"] == 1
    aff = s["affinification"]
    assert aff["status"] == "ok" and aff["dof_ratio"] < 0.9 and 0 < aff["max_distance_error"] < 0.1
    assert aff["max_step_error"] < aff["max_distance_error"]  # re-starting the reference discounts drift
    assert g["reference"].frames == 60 and len(g["runs"]["rigidification"].records) == 60
