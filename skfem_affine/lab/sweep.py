"""A tau_a x tau_e grid of runs against one shared reference, on Dask (paper Fig. 6): :func:`sweep`.

Cells are keyed by the scene's *contents* (:meth:`SceneSpec.key`: a file scene's bytes and the
keyword overrides), the frames, the method, the thresholds and the timing, so that a finished
cell is never recomputed and an edited scene never reuses old cells or an old reference.

Each cell runs in a child process of its Dask worker (:mod:`skfem_affine.lab.cells`): a cell
that crashes its process (segfault, out of memory) is recorded with ``status="crashed"`` and the
reason, one that gives no result within the cell timeout with ``status="timeout"``; the sweep
goes on. Rows are merged into the table under a lock as cells finish (:func:`tables.merge_rows`),
so that two sweeps writing one table lose no cell.
"""
import contextlib
import os
import signal
import threading
import time

import numpy as np

from skfem_affine._extras import require
from skfem_affine.checks import integer
from skfem_affine.lab import cells
from skfem_affine.lab.methods import get_method
from skfem_affine.lab.runs import Reference, _bar, reference_run, run, warm_up
from skfem_affine.lab.scene_spec import default_frames
from skfem_affine.lab.tables import merge_rows, read_table

#: Default cell timeout: this many times the reference's wall time, and at least MIN_CELL_TIMEOUT s.
CELL_TIMEOUT_FACTOR = 10.0
MIN_CELL_TIMEOUT = 300.0


def sweep_taus(grid=9, tau_range=(1e-3, 1.0)):
    """``grid`` thresholds log-spaced over ``tau_range`` (the axes of paper Fig. 6)."""
    lo, hi = map(float, tau_range)
    if not 0 < lo <= hi:
        raise ValueError(f"tau range must satisfy 0 < lo <= hi, got {tau_range}")
    grid = integer(grid, "grid", low=1)
    return np.array([float(f"{t:.6g}") for t in np.logspace(np.log10(lo), np.log10(hi), grid)])


def cell_key(row):
    """What identifies a sweep cell: scene contents and overrides, frames asked, method, thresholds, timing."""
    return (str(row["scene_key"]), int(float(row["frames_asked"])), str(row["method"]),
            f"{float(row['tau_a']):.6g}", f"{float(row['tau_e']):.6g}", str(row.get("timing_asked") or "reference"))


def _base(spec, method, frames, tau_a, tau_e, paired_timing, scene_key):
    return {"scene": spec.label, "scene_key": scene_key or spec.key(), "frames_asked": int(frames),
            "method": get_method(method).name, "tau_a": float(tau_a), "tau_e": float(tau_e),
            "timing_asked": "paired" if paired_timing else "reference"}


def sweep_cell(spec, method, frames, tau_a, tau_e, reference, step_error=True, residual=True, paired_timing=False,
               scene_key=None):
    """One sweep cell, in this process: a measured run as a flat table row. Never raises for a failed simulation."""
    base = _base(spec, method, frames, tau_a, tau_e, paired_timing, scene_key)
    t0 = time.perf_counter()
    try:
        result = run(spec, method, frames, tau_a, tau_e, reference=reference, step_error=step_error,
                     residual=residual, paired_timing=paired_timing)
        row = {**result.summary, **base}
    except Exception as err:  # recorded, so that one bad cell neither stops nor hides in the sweep
        row = {**base, "status": "error", "message": f"{type(err).__name__}: {err}"}
    row["cell_s"] = time.perf_counter() - t0
    return row


_WARM = set()

#: Seconds a child's warm-up may take (a couple of frames, plus loading compiled kernels).
WARM_UP_TIMEOUT = 300.0


def _warm_up_once(spec, method):
    """In the child process: warm the scene's methods up once per process (see :func:`warm_up`)."""
    warmed = (repr(spec), get_method(method).name)
    if warmed not in _WARM:
        warm_up(spec, ("full", method))
        _WARM.add(warmed)


def isolated_cell(spec, method, frames, tau_a, tau_e, reference, step_error=True, residual=True,
                  paired_timing=False, scene_key=None, timeout=None):
    """:func:`sweep_cell` in this worker's child process; a crash or a timeout is the row's status.

    Returns a row with ``status`` "crashed" (the process died: the signal or exit code in
    ``message``) or "timeout" (no result within ``timeout`` seconds) instead of raising.
    """
    base = _base(spec, method, frames, tau_a, tau_e, paired_timing, scene_key)
    t0 = time.perf_counter()
    try:
        cells.call(_warm_up_once, (spec, method), max(timeout or 0.0, WARM_UP_TIMEOUT) if timeout else None)
        return cells.call(sweep_cell, (spec, method, frames, tau_a, tau_e, reference, step_error, residual,
                                       paired_timing, base["scene_key"]), timeout)
    except cells.CellCrashed as err:
        row = {**base, "status": "crashed", "message": str(err)}
    except cells.CellTimedOut as err:
        row = {**base, "status": "timeout", "message": f"{err} (cell timeout {timeout:g} s)"}
    except RuntimeError as err:  # an error outside the simulation, e.g. the scene file cannot be loaded
        row = {**base, "status": "error", "message": str(err)}
    row["cell_s"] = time.perf_counter() - t0
    return row


def default_cell_timeout(reference):
    """:data:`CELL_TIMEOUT_FACTOR` times the reference's wall time, at least :data:`MIN_CELL_TIMEOUT` s.

    A cell runs the method (faster than full space) plus, at most, a full-space twin and a
    full-space solve and assembly per frame for its measurements.
    """
    return max(MIN_CELL_TIMEOUT, CELL_TIMEOUT_FACTOR * float(np.sum(reference.wall)))


def local_workers(workers=None):
    """The worker count of an embedded LocalCluster: ``workers``, at most the machine's cores (default: all).

    More workers than cores only share the cores (each cell then runs slower than alone, and
    hundreds of worker processes take minutes to start), so a larger count is refused.
    """
    cores = os.cpu_count() or 1
    if workers is None:
        return cores
    workers = integer(workers, "workers", low=1)
    if workers > cores:
        raise ValueError(f"workers={workers} is more than this machine's {cores} cores: give at most {cores} "
                         f"(or a --scheduler for a cluster of machines)")
    return workers


def connect(scheduler=None, workers=None, processes=True):
    """A dask Client on ``scheduler`` (an address), or on an embedded LocalCluster.

    Returns ``(client, cluster)``; ``cluster`` is None for an external scheduler.
    ``workers`` (LocalCluster only) is checked by :func:`local_workers`.
    """
    import logging

    distributed = require("dask.distributed", "skfem-affine sweep (dask)", "lab")
    Client, LocalCluster = distributed.Client, distributed.LocalCluster
    if scheduler:
        return Client(scheduler), None
    with _interrupts_ignored_by_children():
        cluster = LocalCluster(n_workers=local_workers(workers), threads_per_worker=1,
                               processes=processes, dashboard_address=":0", silence_logs=logging.ERROR)
    return Client(cluster), cluster


@contextlib.contextmanager
def _interrupts_ignored_by_children():
    """SIGINT ignored while the worker processes start, so that they ignore it for good.

    An ignored signal stays ignored in a child, across ``exec`` too, and Python then installs
    no KeyboardInterrupt handler. So Ctrl-C, which a terminal sends to every process of the
    foreground group, reaches only this process: the sweep stops and closes its workers,
    instead of each worker printing its own traceback. (A Ctrl-C during these seconds of
    start-up is lost.)
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


def sweep(spec, frames=None, method="affinification", grid=9, tau_range=(1e-3, 1.0), table="out/sweep.csv",
          scheduler=None, workers=None, processes=True, step_error=True, residual=True, retry_failed=False,
          progress=False, paired_timing=False, cell_timeout=None, isolate=True):
    """A tau_a x tau_e grid of runs against one shared reference, on Dask (paper Fig. 6).

    Rows are merged into ``table`` (.csv, or .parquet with pyarrow) as cells finish;
    cells already in the table are not recomputed (failed ones neither, unless
    ``retry_failed``). The reference is cached next to the table. Cells share cores,
    so their speedups over the reference (timed alone) are pessimistic on a busy
    machine; ``paired_timing`` times a full-space twin in each cell instead (see
    :func:`~skfem_affine.lab.runs.run`).

    Parameters
    ----------
    cell_timeout : float, optional
        Seconds a cell may take before its process is killed and it is recorded as
        "timeout" (default :func:`default_cell_timeout`).
    isolate : bool
        Run each cell in a child process of its worker (default), so that a crash or a
        timeout is recorded rather than fatal; False runs cells in the workers themselves.

    Notes
    -----
    Returns the rows of this sweep's cells.
    """
    method = get_method(method)
    taus = sweep_taus(grid, tau_range)
    if cell_timeout is not None and not float(cell_timeout) > 0:
        raise ValueError(f"cell_timeout must be > 0 seconds, got {cell_timeout}")
    if frames is None:
        frames = default_frames(spec.build())
    frames = integer(frames, "frames", low=0)
    key = spec.key()
    base = {"scene_key": key, "frames_asked": frames, "method": method.name,
            "timing_asked": "paired" if paired_timing else "reference"}
    grid_cells = [(ta, te) for te in taus for ta in taus]
    keys = [cell_key({**base, "tau_a": ta, "tau_e": te}) for ta, te in grid_cells]
    rows = read_table(table) if os.path.exists(table) else []
    done = {cell_key(r) for r in rows if r.get("status") == "ok" or not retry_failed}
    todo = [c for c, k in zip(grid_cells, keys) if k not in done]
    if todo:
        ref_path = os.path.join(os.path.dirname(os.path.abspath(table)), f"reference_{key}_{frames}.npz")
        cached = Reference.load(ref_path) if os.path.exists(ref_path) else None
        client, cluster = connect(scheduler, workers, processes)
        try:
            client.run(warm_up, spec, ("full", method))
            if cached is None:
                cached = client.submit(_reference_only, spec, frames, pure=False).result()
                cached.save(ref_path)
            timeout = float(cell_timeout) if cell_timeout is not None else default_cell_timeout(cached)
            reference = client.scatter(cached, broadcast=True)
            if isolate:
                futures = {client.submit(isolated_cell, spec, method, frames, ta, te, reference, step_error, residual,
                                         paired_timing, key, timeout, pure=False): (ta, te) for ta, te in todo}
            else:
                futures = {client.submit(sweep_cell, spec, method, frames, ta, te, reference, step_error, residual,
                                         paired_timing, key, pure=False): (ta, te) for ta, te in todo}
            from dask.distributed import as_completed
            bar = _bar(len(futures), f"{spec.label} sweep cells", progress)
            for future in as_completed(futures):
                try:
                    row = future.result()
                except Exception as err:  # the worker died (KilledWorker) or the task failed outside the cell
                    ta, te = futures[future]
                    row = {**_base(spec, method, frames, ta, te, paired_timing, key), "status": "crashed",
                           "message": f"{type(err).__name__}: {err}"}
                merge_rows(table, [row], cell_key)
                bar.update(1)
            bar.close()
        finally:
            if isolate:
                try:
                    client.run(cells.close_idle)
                except Exception:  # a worker that is gone has no children to end
                    pass
            client.close()
            if cluster is not None:
                cluster.close()
        rows = read_table(table)
    wanted = set(keys)
    mine = {cell_key(r): r for r in rows if cell_key(r) in wanted}
    return [mine[k] for k in keys if k in mine]


def _reference_only(spec, frames):
    return reference_run(spec, frames)[0]
