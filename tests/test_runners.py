"""compare, sweep (Dask LocalCluster) and scaling end to end on a tiny beam; tables; scene specs."""
import os

import numpy as np
import pytest

import skfem_affine as sa
from skfem_affine.lab import runners

# the earlier rope-like cantilever (SceneSpec drops None values: Rayleigh() is "undamped")
TINY = runners.SceneSpec.make("cantilever", resolution=1, E=1e5, damping=sa.Rayleigh())


class Exploding(sa.Affinification):
    """Affinification whose velocity update turns non-finite at frame 3: the integrator must raise."""

    def solve(self, sim, rec):
        dv = super().solve(sim, rec)
        return dv * np.nan if sim.state.frame >= 2 else dv


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


def test_sweep_on_a_local_cluster_skips_finished_cells_and_records_failures(tmp_path, monkeypatch):
    table = str(tmp_path / "sweep.csv")
    kwargs = dict(frames=8, method=EXPLODING, grid=2, tau_range=(0.01, 0.3), table=table, workers=2,
                  processes=False)
    rows = runners.sweep(TINY, **kwargs)
    assert len(rows) == 4
    status = {(r["tau_a"], r["tau_e"]): r["status"] for r in rows}
    assert status == {(0.01, 0.01): "ok", (0.01, 0.3): "ok", (0.3, 0.01): "diverged", (0.3, 0.3): "diverged"}
    ok = [r for r in rows if r["status"] == "ok"]
    for r in ok:
        assert r["frames"] == 8 and r["speedup"] > 0 and 0 < r["dof_ratio"] <= 1 and r["max_distance_error"] >= 0
    assert os.path.exists(table) and len(runners.read_table(table)) == 4
    assert any(f.startswith("reference_") for f in os.listdir(tmp_path))

    def no_cluster(*a, **k):
        raise AssertionError("a finished sweep must not start a cluster")

    monkeypatch.setattr(runners, "connect", no_cluster)
    again = runners.sweep(TINY, **kwargs)
    assert [r["cell_s"] for r in again] == pytest.approx([r["cell_s"] for r in rows])
    # a finer grid shares its corner cells: only the 5 new ones are computed (reference from the cache)
    monkeypatch.undo()
    more = runners.sweep(TINY, **{**kwargs, "grid": 3})
    assert len(more) == 9 and len(runners.read_table(table)) == 9
    old = {(r["tau_a"], r["tau_e"]): r["cell_s"] for r in rows}
    assert {k: r["cell_s"] for r in more if (k := (r["tau_a"], r["tau_e"])) in old} == pytest.approx(old)


def test_tables_csv_and_parquet(tmp_path):
    rows = [{"a": 1, "b": 0.5, "s": "ok", "n": None}, {"a": 2, "b": 1e-3, "s": "diverged", "n": 3.0}]
    for name in ("t.csv", "t.parquet"):
        path = runners.write_table(rows, str(tmp_path / name))
        back = runners.read_table(path)
        assert back[0]["a"] == 1 and back[1]["b"] == pytest.approx(1e-3) and back[1]["s"] == "diverged"
        assert back[0]["n"] is None and back[1]["n"] == 3.0


def test_scaling_rows():
    rows = runners.scaling(TINY, [1, 2], [6, 4])
    assert [r["elements"] for r in rows] == [24, 192] and [r["frames"] for r in rows] == [6, 4]
    for r in rows:
        assert r["time_full_s"] > 0 and r["time_reduced_s"] > 0 and r["speedup"] > 0
        assert r["max_distance_error"] >= 0 and r["status"] == "ok"
    with pytest.raises(ValueError, match="one per resolution"):
        runners.scaling(TINY, [1, 2], [5, 5, 5])


def test_sweep_on_an_existing_scheduler(tmp_path):
    from dask.distributed import LocalCluster
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=False, dashboard_address=":0") as cluster:
        rows = runners.sweep(TINY, frames=4, grid=1, tau_range=(0.1, 0.1), table=str(tmp_path / "s.parquet"),
                             scheduler=cluster.scheduler_address)
        assert cluster.scheduler is not None and len(cluster.scheduler.workers) == 1  # still running: not ours
    assert len(rows) == 1 and rows[0]["status"] == "ok" and rows[0]["tau_a"] == 0.1
    assert runners.read_table(str(tmp_path / "s.parquet"))[0]["frames"] == 4


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
