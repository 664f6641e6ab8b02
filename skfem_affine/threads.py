"""Every thread control of the package in one place: the worker pool, BLAS and MKL limits.

Decisions:

* **Compiled passes run on a plain worker pool, not on numba's threading layer.** The
  element kernels are ``nogil`` and split into chunks; :func:`run_chunks` hands the chunks
  to :func:`pool` and to the calling thread. No kernel uses ``parallel=True``, so numba's
  threading layer (TBB, OpenMP or workqueue, whichever numba finds) is never launched: GNU
  OpenMP, numba's fallback without TBB, kills a forked child that enters a parallel
  region, and workqueue aborts when two threads enter one at once.
* **The pool is per process**, created lazily and remembered with the pid that made it: a
  forked child (Linux ``multiprocessing`` forks by default) gets its own workers instead of
  waiting on its parent's, which do not exist in the child.
* **Thread count**: :func:`num_threads`, by default ``numba.config.NUMBA_NUM_THREADS``
  (the ``NUMBA_NUM_THREADS`` environment variable, else every core), or what
  :func:`set_num_threads` set. The pool has one worker fewer: the caller takes a share.
* **BLAS and MKL limits are context managers that restore the previous counts on exit**
  (threadpoolctl): :func:`serial_blas` (OpenBLAS on one thread, MKL untouched: a frame
  interleaves small BLAS calls with the compiled passes and Pardiso, and idle OpenBLAS
  workers spin on the cores those need), :func:`blas_threads` (every BLAS, MKL included),
  :func:`mkl_threads` (MKL alone, for Pardiso; thread-local, so other threads keep theirs).
  Each is a no-op when the library is not loaded.
* **Intel OpenMP's threads sleep as soon as Pardiso returns** (:func:`no_spin_wait`): by default
  they spin for 200 ms after each parallel region (``KMP_BLOCKTIME``), and on a machine with
  few cores they take the cores from the compiled passes that follow the solve (the element
  evaluation, the checks, a reduced frame after a shadow frame's full solve). A
  ``KMP_BLOCKTIME`` the user set is kept.
* **ipctk (IPC contact) runs on one thread** inside the package (:func:`ipctk_threads`, a context
  manager that restores the previous count on exit): its parallel loops (broad phase, barrier
  and friction assembly) split their work as the threads come free, so the sums come out in a
  different order from run to run, and contact amplifies that round-off into visibly different
  trajectories. One thread makes repeated runs and resumes bit-identical.
* Nothing here writes the environment or starts a thread at import.

The measurements behind these choices are in ``docs/threads.md``.
"""
import contextlib
import os
import sys
import threading
from concurrent.futures import ThreadPoolExecutor

import numba

_STATE = {"threads": None, "pool": None, "workers": 0, "pid": None, "openblas": None, "mkl": None,
          "background": None, "background_pid": None}
_LOCK = threading.Lock()


def num_threads():
    """Threads of the compiled passes (the calling thread and the pool's workers)."""
    n = _STATE["threads"]
    return int(numba.config.NUMBA_NUM_THREADS) if n is None else n


def set_num_threads(n):
    """Use n threads for the compiled passes from now on (None: back to the default).

    Examples
    --------
    >>> from skfem_affine import threads
    >>> threads.set_num_threads(1)
    >>> threads.num_threads(), threads.pool()
    (1, None)
    >>> threads.set_num_threads(None)
    """
    if n is not None and (isinstance(n, bool) or int(n) != n or n < 1):
        raise ValueError(f"n must be a positive integer or None, got {n!r}")
    _STATE["threads"] = None if n is None else int(n)


def pool():
    """This process's worker pool (``num_threads() - 1`` workers), or None for one thread."""
    n = num_threads() - 1
    if n < 1:
        return None
    with _LOCK:
        executor = _STATE["pool"]
        if executor is None or _STATE["workers"] != n or _STATE["pid"] != os.getpid():
            executor = ThreadPoolExecutor(max_workers=n, thread_name_prefix="skfem-affine")
            _STATE["pool"], _STATE["workers"], _STATE["pid"] = executor, n, os.getpid()
        return executor


def _after_fork_in_child():
    """The parent's workers and lock state do not survive a fork: forget them."""
    global _LOCK
    _LOCK = threading.Lock()
    _STATE["pool"] = _STATE["pid"] = None


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_after_fork_in_child)


def run_chunks(kernel, chunks, *args):
    """``kernel(c0, c1, *args)`` over the work units ``range(chunks)``, split across threads.

    The units are divided into contiguous shares, one per thread; the calling thread runs the
    first share and waits for the others. ``kernel`` should release the GIL (numba ``nogil``).
    """
    executor = pool()
    if executor is None:
        kernel(0, chunks, *args)
        return
    n = _STATE["workers"] + 1
    bounds = [chunks * i // n for i in range(n + 1)]
    jobs = [executor.submit(kernel, bounds[i], bounds[i + 1], *args) for i in range(1, n)]
    try:
        kernel(bounds[0], bounds[1], *args)
    finally:
        for job in jobs:
            job.result()


_LOCAL = threading.local()


def no_spin_wait():
    """Intel OpenMP (MKL, Pardiso) threads started from this thread sleep at once after a parallel
    region instead of spinning (``kmp_set_blocktime(0)``, per calling thread; once per thread).

    A no-op when Intel OpenMP is not loaded or ``KMP_BLOCKTIME`` is set in the environment.
    """
    if getattr(_LOCAL, "blocktime", False):
        return
    _LOCAL.blocktime = True
    if "KMP_BLOCKTIME" in os.environ:
        return
    import ctypes
    try:  # RTLD_NOLOAD: only a library already loaded (by MKL), never a new one
        lib = ctypes.CDLL("libiomp5.so", mode=getattr(os, "RTLD_NOLOAD", 0) | ctypes.RTLD_GLOBAL)
        lib.kmp_set_blocktime(ctypes.c_int(0))
    except (OSError, AttributeError):
        pass


def _controller(api):
    """The threadpoolctl controller of one library (``"openblas"`` or ``"mkl"``), or None."""
    found = _STATE[api]
    if found is None:
        try:
            # numpy and scipy each bring an OpenBLAS of their own, and a selection limits only the libraries
            # loaded when it is made: scipy's (scipy.linalg's solves) is loaded first
            import scipy.linalg  # noqa: F401
            from threadpoolctl import ThreadpoolController
            found = ThreadpoolController().select(internal_api=api)
        except Exception:  # threadpoolctl missing, or an unusual library set-up
            found = False
        if found:  # not found yet: the library may be loaded later (MKL comes with pypardiso)
            _STATE[api] = found
    return found or None


def serial_blas():
    """Context in which numpy's and scipy's OpenBLAS (each its own library) run on one thread (MKL untouched)."""
    openblas = _controller("openblas")
    return openblas.limit(limits=1) if openblas else contextlib.nullcontext()


def blas_threads(n):
    """Context in which every BLAS library (OpenBLAS, MKL, ...) runs on n threads; None: no change."""
    if n is None:
        return contextlib.nullcontext()
    from threadpoolctl import threadpool_limits
    return threadpool_limits(limits=int(n), user_api="blas")


def mkl_threads(n):
    """Context in which MKL (Pardiso) runs on n threads in the calling thread; None: no change."""
    mkl = _controller("mkl") if n is not None else None
    return mkl.limit(limits=int(n)) if mkl else contextlib.nullcontext()


def mkl_max_threads():
    """MKL's thread count in the calling thread (its default: every core), or None without MKL."""
    mkl = _controller("mkl")
    if not mkl:
        return None
    counts = [lib.num_threads for lib in mkl.lib_controllers]
    return max(counts) if counts else None


#: Threads of ipctk's loops inside the package (one: see the module docstring).
IPCTK_THREADS = 1


@contextlib.contextmanager
def ipctk_threads(n=IPCTK_THREADS):
    """Context in which ipctk runs on n threads; the previous count is restored on exit.

    A no-op when ipctk has not been imported (the IPC contact model imports it).
    """
    ipctk = sys.modules.get("ipctk")
    if ipctk is None:
        yield
        return
    before = ipctk.get_num_threads()
    ipctk.set_num_threads(int(n))
    try:
        yield
    finally:
        ipctk.set_num_threads(before)


def background(fn, *args):
    """Run ``fn(*args)`` on this process's one background thread; returns a Future.

    For work off a frame's critical path (a preconditioner rebuilt at a new pose,
    :class:`~skfem_affine.reducers.affine.clustered.ClusteringReducer`): one worker, so
    background jobs queue rather than compete with each other and the worker pool.
    """
    with _LOCK:
        executor = _STATE.get("background")
        if executor is None or _STATE.get("background_pid") != os.getpid():
            executor = ThreadPoolExecutor(max_workers=1, thread_name_prefix="skfem-affine-background")
            _STATE["background"], _STATE["background_pid"] = executor, os.getpid()
    return executor.submit(fn, *args)
