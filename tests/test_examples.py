"""Every example in examples/ runs (at its default, small size) and computes the right thing."""
import os
import runpy
import sys

import meshio
import numpy as np
import pytest

import skfem_affine as sa

EXAMPLES = os.path.join(os.path.dirname(__file__), "..", "examples")


def run(name):
    return runpy.run_path(os.path.join(EXAMPLES, name), run_name="example")


def test_every_example_is_tested():
    tested = {"cantilever.py", "beam_frequency.py", "affinification.py", "contact_drop.py",
              "contact_stacking.py", "contact_materials.py", "compare.py", "adaptive_subspace.py",
              "custom_reducer.py", "own_mesh.py", "boundaries.py", "threshold_sweep.py", "output.py",
              "rotating_clamp.py", "skfem_static_to_dynamic.py",
              "engineer_beam.py"}
    assert set(f for f in os.listdir(EXAMPLES) if f.endswith(".py")) <= tested


@pytest.mark.slow
def test_engineer_beam_example_agrees_with_scikit_fem_and_beam_theory(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    g = run("engineer_beam.py")
    assert g["deflection"] == pytest.approx(g["static_p1"], rel=0.01)  # at rest = scikit-fem's static solve
    assert g["static_p2"] == pytest.approx(g["delta_timoshenko"], rel=0.03)
    assert g["deflection"] < g["deflection_limit"] < g["delta_timoshenko"]  # locking, shrinking with refinement
    assert g["f_sim"] == pytest.approx(g["f_fe"], rel=0.02)  # the period against scikit-fem's eigenvalue
    assert g["sigma_limit"] == pytest.approx(g["sigma_theory"], rel=0.05)  # root stress: M c / I
    for row in g["rows"]:  # the budget, relative to the response, holds
        assert row["response_error"] <= 1.25 * row["budget"]
    back = meshio.read(tmp_path / "out" / "engineer_beam" / "engineer_beam_00150.vtu")
    assert "cauchy_stress" in back.cell_data and "von_mises_stress" in back.point_data


def test_rotating_clamp_example():
    g = run("rotating_clamp.py")
    assert g["clamp_error"] <= 1e-12 and g["aff_clamp_error"] <= 1e-12  # the clamp stays on its path
    assert g["angle"] == pytest.approx(1.2)
    assert g["middle_shift"] > 0.01  # the pull moves the middle along +y
    assert g["dof_ratio"] <= 1.0 and g["error"] < 0.05


def test_cantilever_example(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    g = run("cantilever.py")
    assert g["sim"].state.frame == 100
    assert np.all(np.isfinite(g["tip_height"]))
    # a stiff-rubber beam: the tip dips and rings about its static deflection (0.19 m by beam theory)
    assert -0.3 < g["lowest"] < -0.15                     # a few % of the 4 m length
    # the ParaView series holds the run itself, frames 0 to 100, in out/cantilever/
    out = tmp_path / "out" / "cantilever"
    pvd = (out / "cantilever.pvd").read_text()
    assert pvd.count("<DataSet") == 101 and "cantilever_00000.vtu" in pvd and "cantilever_00100.vtu" in pvd
    assert np.allclose(meshio.read(out / "cantilever_00100.vtu").points, g["sim"].state.x)


def test_cantilever_example_as_a_script(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(sys, "argv", ["cantilever.py", "--resolution", "1", "--frames", "5", "--out", "here"])
    runs, run_ = [], sa.Simulation.run
    monkeypatch.setattr(sa.Simulation, "run", lambda sim, frames: runs.append(frames) or run_(sim, frames))
    g = runpy.run_path(os.path.join(EXAMPLES, "cantilever.py"), run_name="__main__")
    assert runs == [5] and g["sim"].state.frame == 5 and g["sim"].system.m == 24  # simulated once, as asked
    assert sorted(os.listdir(tmp_path)) == ["here"]
    assert sorted(os.listdir(tmp_path / "here")) == ["cantilever.pvd"] + [f"cantilever_{i:05d}.vtu" for i in range(6)] \
        + ["tip.png"]
    assert "frames 0-5" in capsys.readouterr().out


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


def test_contact_drop_example():
    g = run("contact_drop.py")
    assert g["energy_gain"] <= 0.0                 # zero restitution: energy never grows
    assert g["contacts"].max() >= 9                # the box's bottom face (3 x 3 vertices) lands
    assert g["affine_share"] > 0.5 and g["com_gap"] < 0.03
    assert 0.05 < g["ball_travel"] < 1.0           # rolls down the SDF ramp (+x), not through it
    d, _ = g["ball"].colliders[0].query(g["ball"].state.x)
    assert d.min() > -1e-3


@pytest.mark.slow
def test_contact_stacking_example():
    g = run("contact_stacking.py")
    assert g["beam_tops"] == pytest.approx([0.4, 0.8], abs=0.02)
    assert g["beams_depth"] < 1e-3 and g["pills_depth"] < 1e-2
    assert g["pills_contacts"] > 10 and np.isfinite(g["pills_speed"])


def test_contact_materials_example():
    g = run("contact_materials.py")
    assert 0 < g["peak_elastic"][0] <= g["peak_elastic"][1] <= 1  # higher drop, larger elastic region
    assert 1e-3 < g["trail"] < 0.06                                 # friction bends the bristles backwards


def test_compare_example_measures_the_trade():
    g = run("compare.py")
    s = g["summary"]
    assert s["full"]["max_distance_error"] == 0 and s["full"]["speedup"] == 1
    aff = s["affinification"]
    assert aff["status"] == "ok" and aff["dof_ratio"] < 0.9 and 0 < aff["max_distance_error"] < 0.1
    assert aff["max_step_error"] < aff["max_distance_error"]  # re-starting the reference discounts drift
    assert g["reference"].frames == 60 and len(g["runs"]["rigidification"].records) == 60


def test_custom_reducer_example_runs_beside_full_and_affinification():
    g = run("custom_reducer.py")
    s = g["summary"]
    assert set(s) == {"full", "affinification", "static-kmeans"}
    assert s["full"]["max_distance_error"] == 0 and s["full"]["dof_ratio"] == 1
    mine = s["static-kmeans"]
    assert mine["status"] == "ok" and mine["frames"] == 40
    assert mine["dof_ratio"] < 0.5
    assert 0 < mine["max_distance_error"] < 0.05
    assert all(r["n_clusters"] == 3 and r["dofs"] == 81 for r in g["runs"]["static-kmeans"].records)


def test_own_mesh_example_loads_regions_and_assigns_their_materials():
    g = run("own_mesh.py")
    assert g["regions"] == {"ref1": 324, "ref2": 324}
    sysm = g["two_materials"].system
    assert len(g["two_materials"].bodies[0].materials) == 2
    left = sysm.p0[sysm.t].mean(axis=0)[:, 0] < 2.0
    assert np.unique(sysm.material_index[left]).size == 1 and np.unique(sysm.material_index[~left]).size == 1
    assert sysm.material_index[left][0] != sysm.material_index[~left][0]
    # a stiff root holds the bar up: the tip sags far less than when all of it is soft
    assert -1.0 < g["sag_two_materials"] < 0 and g["sag_soft"] < 3 * g["sag_two_materials"]


def test_boundaries_example_holds_fixed_vertices():
    g = run("boundaries.py")
    r = g["results"]
    assert all(v["fixed_moved"] == 0.0 for v in r.values())
    assert (r["cantilever"]["n_fixed"], r["bridge"]["n_fixed"], r["hinge"]["n_fixed"]) == (16, 32, 4)
    assert r["bridge"]["tip"] == 0.0                       # the far end is held too
    assert r["bridge"]["middle"] > r["cantilever"]["middle"] > r["hinge"]["middle"]
    assert r["hinge"]["tip"] < r["cantilever"]["tip"] < 0


def test_threshold_sweep_example_trades_dofs_for_error():
    g = run("threshold_sweep.py")
    assert np.all(np.diff(g["dof_ratio"]) < 0)            # larger thresholds solve fewer DOFs
    assert g["error"][-1] > g["error"][0] > 0              # and pay with accuracy
    assert np.all(g["dof_ratio"] < 1) and np.all(np.isfinite(g["speedup"]))
    assert all(row["status"] == "ok" for row in g["rows"])
    (budget,) = g["budget_rows"]  # the error budget: 1 % asked, at most 1 % (plus a quarter) achieved
    assert budget["status"] == "ok" and budget["error"] <= 1.25 * budget["budget"]


def test_output_example_writes_paraview_and_gif(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    g = run("output.py")
    out = tmp_path / "out" / "output"
    pvd = (out / "drop.pvd").read_text()
    assert pvd.count("<DataSet") == 31 == len(g["frames"])
    frame = meshio.read(out / "drop_00060.vtu")
    assert {"cluster", "affine", "material"} <= set(frame.cell_data)
    assert np.asarray(frame.cell_data["cluster"][0]).max() >= 0     # affine bodies were written
    from PIL import Image
    with Image.open(out / "drop.gif") as gif:
        assert gif.n_frames == len(g["states"]) == 16
    assert (out / "drop_clusters.png").stat().st_size > 0


def test_skfem_static_to_dynamic_example_agrees_with_scikit_fem(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    g = run("skfem_static_to_dynamic.py")
    assert g["deflection_static"] < 0 and g["deflection_error"] < 1e-3    # at rest on the static solution
    assert g["stress_error"] < 1e-3                                         # the same root stress
    assert g["stepped_error"] < 1e-3 < g["trajectory_error"] < 0.15        # the modes, damped by backward Euler
    frame = meshio.read(tmp_path / "out" / "skfem_static_to_dynamic" / "bar_00200.vtu")
    assert "von_mises_stress" in frame.cell_data and "cauchy_stress" in frame.point_data
