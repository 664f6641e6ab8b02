"""Runs, interleaved stepping, compare and scaling end to end on a tiny beam; scene specs."""

import numpy as np
import pytest

import skfem_affine as sa
from skfem_affine.lab import runners

# the earlier rope-like cantilever (SceneSpec drops None values: Rayleigh() is "undamped")
TINY = runners.SceneSpec.make("cantilever", resolution=1, E=1e5, damping=sa.Rayleigh())


class Exploding(sa.Affinification):
    """Affinification whose velocity update turns non-finite at frame 3: the integrator must raise."""

    def solve(self, problem):
        result = super().solve(problem)
        if problem.frame >= 3:
            result.dv = result.dv * np.nan
        return result


EXPLODING = runners.Method("exploding", lambda a, e: Exploding(a, e) if a > 0.05 else sa.Affinification(a, e),
                           (0.1, 0.2))


def test_scene_specs(tmp_path):
    with pytest.raises(ValueError, match="unknown scene"):
        runners.SceneSpec.make("nope")
    f = tmp_path / "myscene.py"
    f.write_text("import skfem_affine as sa\n"
                 "def scene(reducer=None, resolution=1, **kw):\n"
                 "    return sa.scenes.cantilever(resolution=resolution, reducer=reducer, E=1e5, damping=None, **kw)\n")
    spec = runners.SceneSpec.make(str(f), resolution=1)
    assert spec.label == "myscene" and spec.build().system.m == 24
    assert spec.key() != TINY.key() and spec.key() == runners.SceneSpec.make(str(f), resolution=1).key()
    (tmp_path / "bad.py").write_text("x = 1\n")
    with pytest.raises(ValueError, match="scene"):
        runners.SceneSpec.make(str(tmp_path / "bad.py")).build()
    with pytest.raises(ValueError, match="unknown method"):
        runners.get_method("nope")


def test_compare_end_to_end():
    ref, runs = runners.compare(TINY, frames=25, taus={"affinification": (0.3, 0.6)}, keep_every=5)
    assert set(runs) == {"full", "affinification", "rigidification"}
    assert ref.x.shape == (26, TINY.build().system.n, 3) and ref.frames == 25
    full, aff = runs["full"].summary, runs["affinification"].summary
    assert full["max_distance_error"] == 0 and full["speedup"] == 1 and full["dof_ratio"] == 1
    assert aff["status"] == "ok" and aff["frames"] == 25 and aff["tau_a"] == 0.3
    assert 0 < aff["dof_ratio"] < 1 and aff["mean_clusters"] > 0 and aff["speedup"] > 0
    assert 0 < aff["max_distance_error"] < 0.2
    for key in ("max_step_error", "max_residual", "max_energy_error", "assembly_s", "clustering_s"):
        assert aff[key] is not None and np.isfinite(aff[key])
    rec = runs["affinification"].records
    assert len(rec) == 25 and all("step_error" in r and "residual" in r for r in rec)
    # the distance error of frame t is the distance to the reference's frame t
    last = runs["affinification"].states[-1]
    assert last.frame == 25
    assert rec[-1]["distance_error"] == pytest.approx(np.linalg.norm(last.x - ref.x[25], axis=1).max() / ref.size)
    assert [s.frame for s in runs["rigidification"].states] == [0, 5, 10, 15, 20, 25]


def test_zero_thresholds_reproduce_the_reference():
    ref, _ = runners.reference_run(TINY, 10)
    r = runners.run(TINY, "affinification", 10, 0.0, 0.0, reference=ref)
    assert r.summary["dof_ratio"] == 1.0 and r.summary["max_distance_error"] < 1e-8
    assert r.summary["max_step_error"] < 1e-8 and r.summary["max_residual"] < 1e-6


def test_paired_timing_takes_the_speedup_from_a_lockstep_twin():
    ref, _ = runners.reference_run(TINY, 6)
    r = runners.run(TINY, "affinification", 6, reference=ref, step_error=False, residual=False, paired_timing=True)
    walls = [(rec["full_wall"], rec["wall"]) for rec in r.records]
    assert len(walls) == 6 and r.summary["timing"] == "paired" and r.summary["setup_s"] > 0
    assert r.summary["speedup"] == pytest.approx(sum(f for f, _ in walls) / sum(w for _, w in walls))
    assert runners.run(TINY, "full", 6, reference=ref).summary["timing"] == "reference"


def test_divergence_is_recorded_not_raised():
    ref, _ = runners.reference_run(TINY, 10)
    r = runners.run(TINY, EXPLODING, 10, reference=ref)
    assert r.summary["status"] == "diverged" and "frame 3" in r.summary["message"]
    assert len(r.records) == 2 and r.summary["frames"] == 2
    with pytest.raises(ValueError, match="fewer"):
        runners.run(TINY, "full", 20, reference=ref)


def test_scaling_rows():
    rows = runners.scaling(TINY, [1, 2], [6, 4])
    assert [r["elements"] for r in rows] == [24, 192] and [r["frames"] for r in rows] == [6, 4]
    for r in rows:
        assert r["time_full_s"] > 0 and r["time_reduced_s"] > 0 and r["speedup"] > 0
        assert r["max_distance_error"] >= 0 and r["status"] == "ok"
    with pytest.raises(ValueError, match="one per resolution"):
        runners.scaling(TINY, [1, 2], [5, 5, 5])


def test_subspace_method_is_measured_against_the_newton_reference():
    spec = runners.SceneSpec.make("cantilever", resolution=1, integrator="implicit_euler", E=1e5, damping=sa.Rayleigh())
    ref, runs = runners.compare(spec, frames=8, methods=("subspace",), taus={"subspace": (0.0, 0.0)})
    sub = runs["subspace"].summary
    # every threshold zero: all nodes enriched, the full-space Newton solution to its tolerance
    assert sub["status"] == "ok" and sub["frames"] == 8 and sub["max_distance_error"] < 1e-5
    loose = runners.run(spec, "subspace", 8, 1e-2, 3e-2, reference=ref, step_error=False)
    assert loose.summary["status"] == "ok" and loose.summary["max_distance_error"] > sub["max_distance_error"]
    with pytest.raises(ValueError, match="integrator"):  # the subspace reducer refuses the linearized integrator
        runners.run(TINY, "subspace", 2)


def test_every_method_is_timed_with_the_reducers_solver():
    # the cantilever's own default is "auto" (AMG-CG on large meshes); compared runs use the reducers' direct solver
    full, aff = TINY.build(), TINY.build(reducer=sa.Affinification())
    assert type(full.solver).__name__ == type(aff.reducer.solver).__name__
    assert type(TINY.with_kwargs(solver="superlu").build().solver).__name__ == "SuperLU"


def test_interleaved_steps_every_simulation_frame_by_frame_in_turn():
    sims = {"full": TINY.build(), "affine": TINY.build(reducer=sa.Affinification(0.3, 0.6)),
            "exploding": TINY.build(reducer=Exploding(0.3, 0.6))}
    seen = []

    def on_frame(frame, running):
        seen.append((frame, {name: sim.state.frame for name, sim in running.items()}))

    runs = runners.interleaved(sims, 5, on_frame=on_frame)
    # every running simulation has done the same frame when on_frame is called; the diverged one stops
    assert [f for f, _ in seen] == [1, 2, 3, 4, 5]
    assert seen[0][1] == {"full": 1, "affine": 1, "exploding": 1}
    assert seen[2][1] == {"full": 3, "affine": 3} and seen[4][1] == {"full": 5, "affine": 5}
    full, aff, bad = runs["full"], runs["affine"], runs["exploding"]
    assert len(full.records) == len(aff.records) == 5 and len(bad.records) == 2
    assert bad.summary["status"] == "diverged" and "frame 3" in bad.summary["message"]
    assert full.summary["speedup"] == 1 and full.summary["timing"] == "interleaved"
    walls = [(f["wall"], a["wall"]) for f, a in zip(full.records, aff.records)]
    assert aff.summary["speedup"] == pytest.approx(sum(f for f, _ in walls) / sum(a for _, a in walls))
    assert aff.summary["dof_ratio"] < 1 and aff.sim is sims["affine"] and aff.sim.state.frame == 5
    with pytest.raises(TypeError, match="Simulation"):
        runners.interleaved({"x": TINY}, 2)


def test_interleaved_rotates_which_simulation_steps_first():
    sims = {"a": TINY.build(), "b": TINY.build(), "c": TINY.build()}
    order = []
    for name, sim in sims.items():
        def step(sim=sim, name=name, plain=sim.step):
            order.append(name)
            return plain()
        sim.step = step
    runs = runners.interleaved(sims, 4)
    assert [order[3 * i] for i in range(4)] == ["b", "c", "a", "b"]  # each frame starts one later
    assert sorted(order[3:6]) == ["a", "b", "c"]  # every one once per frame
    assert all(len(r.records) == 4 and r.records[-1]["frame"] == 4 for r in runs.values())


def test_compare_times_interleaved_by_default_and_sequential_on_request():
    taus = {"affinification": (0.3, 0.6)}
    ref, inter = runners.compare(TINY, frames=8, methods=("affinification",), taus=taus, residual=False)
    _, seq = runners.compare(TINY, frames=8, methods=("affinification",), taus=taus, residual=False,
                             timing="sequential")
    for runs, timing in ((inter, "interleaved"), (seq, "sequential")):
        aff, full = runs["affinification"], runs["full"]
        assert aff.summary["timing"] == full.summary["timing"] == timing
        assert aff.summary["speedup"] == pytest.approx(
            sum(r["wall"] for r in full.records) / sum(r["wall"] for r in aff.records))
    # the same runs, only timed differently: identical trajectories and errors
    for key in ("distance_error", "step_error", "energy_error", "dofs"):
        assert [r[key] for r in inter["affinification"].records] == \
            pytest.approx([r[key] for r in seq["affinification"].records], rel=1e-9, abs=1e-15), key
    assert np.array_equal(ref.x[-1], inter["full"].sim.state.x)
    with pytest.raises(ValueError, match="timing"):
        runners.compare(TINY, frames=2, timing="parallel")


def test_compare_stops_when_the_reference_diverges(tmp_path):
    scene = tmp_path / "fragile.py"
    scene.write_text("import skfem_affine as sa\n"
                     "def scene(reducer=None, **kw):\n"
                     "    sim = sa.scenes.cantilever(resolution=1, reducer=reducer, **kw)\n"
                     "    if reducer is None:  # the full-space run diverges at frame 3\n"
                     "        step = sim.step\n"
                     "        def fragile():\n"
                     "            if sim.state.frame == 2:\n"
                     "                raise sa.SimulationDiverged(3, 'on purpose')\n"
                     "            return step()\n"
                     "        sim.step = fragile\n"
                     "    return sim\n")
    spec = runners.SceneSpec.make(str(scene))
    for timing in ("interleaved", "sequential"):
        with pytest.raises(sa.SimulationDiverged, match="reference diverged"):
            runners.compare(spec, frames=5, methods=("affinification",), step_error=False, residual=False,
                            timing=timing)
