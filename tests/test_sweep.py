"""Sweeps on Dask: finished cells skipped, cells keyed by the scene's contents, a crashing or
hanging cell recorded (not fatal), damaged cached files named; the CLI's one-line errors."""
import os
import time

import pytest

import skfem_affine as sa
from skfem_affine.lab import runners
from skfem_affine.lab import sweep as sweeps
from skfem_affine.lab.cli import main
from test_runners import EXPLODING  # an affinification that diverges above tau_a = 0.05

TINY = runners.SceneSpec.make("cantilever", resolution=1)


def misbehaving(tau_a, tau_e):
    """A reducer factory that takes its cell's process down: killed, exiting, or hanging, by threshold."""
    if tau_a > 0.05 and tau_e < 0.05:
        os.kill(os.getpid(), 9)  # as the out-of-memory killer would
    if tau_a < 0.05 and tau_e > 0.05:
        os._exit(3)
    if tau_a > 0.05 and tau_e > 0.05:
        time.sleep(3600)
    return sa.Affinification(tau_a, tau_e)


MISBEHAVING = runners.Method("misbehaving", misbehaving, (0.01, 0.01))


@pytest.mark.slow
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

    monkeypatch.setattr(sweeps, "connect", no_cluster)
    again = runners.sweep(TINY, **kwargs)
    assert [r["cell_s"] for r in again] == pytest.approx([r["cell_s"] for r in rows])
    # a finer grid shares its corner cells: only the 5 new ones are computed (reference from the cache)
    monkeypatch.undo()
    more = runners.sweep(TINY, **{**kwargs, "grid": 3})
    assert len(more) == 9 and len(runners.read_table(table)) == 9
    old = {(r["tau_a"], r["tau_e"]): r["cell_s"] for r in rows}
    assert {k: r["cell_s"] for r in more if (k := (r["tau_a"], r["tau_e"])) in old} == pytest.approx(old)


@pytest.mark.slow
def test_sweep_on_an_existing_scheduler(tmp_path):
    from dask.distributed import LocalCluster
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=False, dashboard_address=":0") as cluster:
        rows = runners.sweep(TINY, frames=4, grid=1, tau_range=(0.1, 0.1), table=str(tmp_path / "s.parquet"),
                             scheduler=cluster.scheduler_address)
        assert cluster.scheduler is not None and len(cluster.scheduler.workers) == 1  # still running: not ours
    assert len(rows) == 1 and rows[0]["status"] == "ok" and rows[0]["tau_a"] == 0.1
    assert runners.read_table(str(tmp_path / "s.parquet"))[0]["frames"] == 4




@pytest.mark.slow
def test_a_crashing_or_hanging_cell_is_recorded_and_the_sweep_goes_on(tmp_path):
    table = str(tmp_path / "sweep.csv")
    t0 = time.perf_counter()
    rows = runners.sweep(TINY, frames=4, method=MISBEHAVING, grid=2, tau_range=(0.01, 0.3), table=table, workers=2,
                         processes=False, step_error=False, residual=False, cell_timeout=10)
    assert time.perf_counter() - t0 < 600
    got = {(r["tau_a"], r["tau_e"]): (r["status"], r.get("message") or "") for r in rows}
    assert got[(0.01, 0.01)] == ("ok", "")
    assert got[(0.3, 0.01)][0] == "crashed" and "signal 9 (SIGKILL" in got[(0.3, 0.01)][1]
    assert got[(0.01, 0.3)][0] == "crashed" and "exited with code 3" in got[(0.01, 0.3)][1]
    assert got[(0.3, 0.3)][0] == "timeout" and "10 s" in got[(0.3, 0.3)][1]
    assert len(runners.read_table(table)) == 4
    again = runners.sweep(TINY, frames=4, method=MISBEHAVING, grid=2, tau_range=(0.01, 0.3), table=table,
                          processes=False, step_error=False, residual=False)
    assert [r["status"] for r in again] == [r["status"] for r in rows]  # recorded: not recomputed


@pytest.mark.slow
def test_cells_are_keyed_by_the_scene_files_contents(tmp_path):
    scene = tmp_path / "beam.py"
    scene.write_text("import skfem_affine as sa\n"
                     "def scene(reducer=None, resolution=1, **kw):\n"
                     "    return sa.scenes.cantilever(resolution=resolution, reducer=reducer, **kw)\n")
    spec = runners.SceneSpec.make(str(scene), resolution=1)
    key = spec.key()
    moved = tmp_path / "elsewhere.py"
    moved.write_bytes(scene.read_bytes())
    assert runners.SceneSpec.make(str(moved), resolution=1).key() == key  # the same contents
    assert spec.with_kwargs(resolution=2).key() != key
    table = str(tmp_path / "sweep.csv")
    kwargs = dict(frames=3, grid=1, tau_range=(0.1, 0.1), table=table, workers=1, processes=False,
                  step_error=False, residual=False)
    first = runners.sweep(spec, **kwargs)
    scene.write_text(scene.read_text().replace("resolution=resolution", "resolution=resolution + 1"))
    assert spec.key() != key
    second = runners.sweep(spec, **kwargs)  # the edited scene: a new cell and a new reference
    assert first[0]["elements"] == 24 and second[0]["elements"] == 192
    assert len(runners.read_table(table)) == 2
    assert len([f for f in os.listdir(tmp_path) if f.startswith("reference_")]) == 2


def test_a_bad_cell_timeout_is_refused():
    with pytest.raises(ValueError, match="cell_timeout"):
        runners.sweep(TINY, frames=2, grid=1, cell_timeout=0)


def test_damaged_files_give_one_line_and_exit_code_2(tmp_path, capsys):
    out = tmp_path / "out"
    argv = ["sweep", "cantilever", "--resolution", "1", "--frames", "4", "--grid", "1", "--workers", "1",
            "--threads", "--out", str(out)]
    table = tmp_path / "table.csv"
    table.write_bytes(b"scene,method,tau_a\ncantilever,affin")  # a truncated row
    assert main(argv + ["--table", str(table)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and str(table) in err and "truncated" in err
    table.write_bytes(b"scene,method\n\xff\xfe,x\n")  # not UTF-8
    assert main(argv + ["--table", str(table)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and str(table) in err and "UTF-8" in err
    # a truncated cached reference next to a fresh table
    fresh = tmp_path / "fresh" / "table.csv"
    ref = fresh.parent / f"reference_{TINY.key()}_4.npz"
    fresh.parent.mkdir()
    ref.write_bytes(b"PK\x03\x04 truncated")
    assert main(argv + ["--table", str(fresh)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and str(ref) in err and "delete it" in err
    # a scene file that is not UTF-8 text
    scene = tmp_path / "latin1.py"
    scene.write_bytes(b"# caf\xe9\ndef scene(reducer=None, **kw):\n    pass\n")
    assert main(["run", str(scene), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and str(scene) in err
