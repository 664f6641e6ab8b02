"""skfem_affine.threads: the per-process worker pool, chunked runs, BLAS/MKL limits that restore."""
import importlib
import os
import pkgutil
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

import skfem_affine
from skfem_affine import threads
from forking import exit_code_of


@pytest.fixture
def n_threads():
    """Set the thread count for one test, and put the default back."""
    yield threads.set_num_threads
    threads.set_num_threads(None)


def package_modules():
    for info in pkgutil.walk_packages(skfem_affine.__path__, "skfem_affine."):
        if info.name.endswith("__main__"):
            continue
        yield importlib.import_module(info.name)


def test_no_compiled_kernel_uses_numba_parallel_regions():
    """Fork safety must not depend on numba's threading layer: no kernel may use parallel=True."""
    from numba.core.registry import CPUDispatcher
    kernels = [(m.__name__, name, obj) for m in package_modules() for name, obj in vars(m).items()
               if isinstance(obj, CPUDispatcher)]
    assert len(kernels) > 20  # the package's kernels were found
    parallel = [f"{mod}.{name}" for mod, name, k in kernels if k.targetoptions.get("parallel")]
    assert parallel == []


@pytest.mark.slow
def test_a_simulation_never_launches_numba_threading_layer():
    """In a fresh process: full-space and affinification frames, the forces' pass, the oracle."""
    code = ("import numpy as np\n"
            "import skfem_affine as sa\n"
            "from numba.np.ufunc import parallel\n"
            "from skfem_affine.materials import project_psd\n"
            "for reducer in (None, sa.Affinification(tau_a=1.0, tau_e=2.0),\n"
            "                sa.Rigidification(tau_r=1.0, tau_e=2.0, warmup_frames=1)):\n"
            "    sim = sa.scenes.cantilever(resolution=2, reducer=reducer)\n"
            "    for _ in range(3): sim.step()\n"
            "C = np.random.default_rng(0).standard_normal((50, 9, 9))\n"
            "project_psd(C, np.tile(np.eye(3), (50, 1, 1)))\n"
            "print('launched', parallel._is_initialized)\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600,
                         cwd=os.path.dirname(os.path.dirname(skfem_affine.__file__)))
    assert out.returncode == 0, out.stderr[-2000:]
    assert "launched False" in out.stdout


def test_run_chunks_covers_every_unit_once_on_several_threads(n_threads):
    for n in (1, 2, 3, 5):
        n_threads(n)
        seen = np.zeros(64, int)
        names = set()
        lock = threading.Lock()

        def kernel(c0, c1, out):
            with lock:
                names.add(threading.current_thread().name)
            out[c0:c1] += 1

        threads.run_chunks(kernel, 64, seen)
        assert np.all(seen == 1)
        assert len(names) == n if n <= 2 else len(names) >= 2  # the caller and the workers share
        assert threading.current_thread().name in names


def test_run_chunks_raises_a_workers_error_after_all_finish(n_threads):
    n_threads(2)
    done = []

    def kernel(c0, c1):
        if c0 > 0:
            raise ValueError("from a worker")
        time.sleep(0.05)
        done.append(c0)

    with pytest.raises(ValueError, match="from a worker"):
        threads.run_chunks(kernel, 8)
    assert done == [0]


def test_pool_is_made_lazily_per_process_and_again_in_a_forked_child(n_threads):
    n_threads(2)
    parent = threads.pool()
    assert parent is threads.pool()  # one pool per process
    assert parent._max_workers == 1
    n_threads(3)
    assert threads.pool() is not parent and threads.pool()._max_workers == 2  # a new count, a new pool
    if not hasattr(os, "fork"):
        return
    parent = threads.pool()
    pid = os.fork()
    if pid == 0:
        try:
            child = threads.pool()
            out = np.zeros(16)
            threads.run_chunks(lambda c0, c1: out.__setitem__(slice(c0, c1), 1.0), 16)
            os._exit(0 if child is not parent and np.all(out == 1) else 1)
        except BaseException:
            os._exit(2)
    assert exit_code_of(pid, "the forked child hung on its pool") == 0


def test_one_thread_means_no_pool(n_threads):
    n_threads(1)
    assert threads.pool() is None
    out = np.zeros(4)
    threads.run_chunks(lambda c0, c1: out.__setitem__(slice(c0, c1), 1.0), 4)
    assert np.all(out == 1)


def test_set_num_threads_checks_its_argument(n_threads):
    for bad in (0, -1, 1.5, True, "2"):
        with pytest.raises((ValueError, TypeError), match="n must be"):
            n_threads(bad)
    n_threads(None)
    import numba
    assert threads.num_threads() == numba.config.NUMBA_NUM_THREADS


def blas_counts(api):
    from threadpoolctl import threadpool_info
    return [lib["num_threads"] for lib in threadpool_info() if lib["internal_api"] == api]


def test_serial_blas_and_blas_threads_restore_the_counts():
    np.ones(4) @ np.ones(4)  # OpenBLAS is loaded
    before = blas_counts("openblas")
    assert before
    with threads.serial_blas():
        assert blas_counts("openblas") == [1] * len(before)
    assert blas_counts("openblas") == before
    with threads.blas_threads(1):
        assert blas_counts("openblas") == [1] * len(before)
    assert blas_counts("openblas") == before
    with threads.blas_threads(None):
        assert blas_counts("openblas") == before


def test_serial_blas_limits_scipys_openblas_loaded_after_numpys():
    """numpy and scipy each bring an OpenBLAS; serial_blas first used before scipy.linalg is imported
    (numpy's alone loaded) still limits scipy's, which runs scipy.linalg's solves."""
    code = ("import numpy as np\n"
            "from skfem_affine import threads\n"
            "np.ones(4) @ np.ones(4)\n"
            "with threads.serial_blas():\n"
            "    pass\n"
            "import scipy.linalg\n"
            "from threadpoolctl import threadpool_info\n"
            "with threads.serial_blas():\n"
            "    inside = [lib['num_threads'] for lib in threadpool_info() if lib['internal_api'] == 'openblas']\n"
            "print('libraries', len(inside), 'threads', max(inside))\n")
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "2"}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=300,
                         cwd=os.path.dirname(os.path.dirname(skfem_affine.__file__)))
    assert out.returncode == 0, out.stderr[-2000:]
    words = out.stdout.split()
    assert int(words[1]) >= 1 and words[3] == "1", out.stdout


def test_mkl_threads_restore_and_leave_openblas_alone():
    pytest.importorskip("pypardiso")
    from skfem_affine.solvers import Pardiso
    Pardiso()  # loads MKL
    before, openblas = threads.mkl_max_threads(), blas_counts("openblas")
    assert before >= 1
    with threads.mkl_threads(1):
        assert threads.mkl_max_threads() == 1
        assert blas_counts("openblas") == openblas
    assert threads.mkl_max_threads() == before
    with threads.mkl_threads(None):
        assert threads.mkl_max_threads() == before


def test_importing_writes_no_environment_and_starts_no_thread():
    code = ("import os, threading\n"
            "env = dict(os.environ)\n"
            "n = threading.active_count()\n"
            "import skfem_affine, skfem_affine.threads, skfem_affine.solvers\n"
            "assert dict(os.environ) == env, set(os.environ.items()) ^ set(env.items())\n"
            "assert threading.active_count() == n\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300,
                         cwd=os.path.dirname(os.path.dirname(skfem_affine.__file__)))
    assert out.returncode == 0, out.stderr[-2000:]


@pytest.mark.slow
@pytest.mark.skipif(not skfem_affine.solvers.has_pardiso(), reason="pypardiso (MKL, Intel OpenMP) not installed")
def test_pardiso_leaves_intel_openmp_threads_sleeping_unless_the_user_set_blocktime():
    code = ("import ctypes, skfem_affine as sa\n"
            "sa.scenes.cantilever(resolution=1, solver='pardiso').step()\n"
            "print(ctypes.CDLL('libiomp5.so').kmp_get_blocktime())\n")
    env = {k: v for k, v in os.environ.items() if k != "KMP_BLOCKTIME"}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    assert out.stdout.split()[-1] == "0"  # not the default 200 ms of spinning after each solve
    env["KMP_BLOCKTIME"] = "50"
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    assert out.stdout.split()[-1] == "50"  # the user's setting is kept


def test_ipctk_threads_sets_the_count_and_restores_the_previous_one():
    ipctk = pytest.importorskip("ipctk")
    before = ipctk.get_num_threads()
    ipctk.set_num_threads(2)
    try:
        with threads.ipctk_threads():
            assert ipctk.get_num_threads() == threads.IPCTK_THREADS == 1
            with threads.ipctk_threads(2):
                assert ipctk.get_num_threads() == 2
            assert ipctk.get_num_threads() == 1
        assert ipctk.get_num_threads() == 2
        with pytest.raises(RuntimeError), threads.ipctk_threads():
            raise RuntimeError("restored on the way out")
        assert ipctk.get_num_threads() == 2
    finally:
        ipctk.set_num_threads(before)
