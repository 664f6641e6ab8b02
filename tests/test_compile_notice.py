"""The first-run notice: one stderr line when the package's kernels compile (cold cache), none when warm."""
import os
import subprocess
import sys

from skfem_affine._compile_notice import MESSAGE

ROOT = os.path.join(os.path.dirname(__file__), "..")

# a user's own numba function compiles first (no notice: not the package's), then two of the
# package's cached kernels in two modules (one notice for both)
SCRIPT = """
import sys
import numba
import numpy as np
import skfem_affine
from skfem_affine import _kernels
from skfem_affine.reducers.affine import mapping

@numba.njit(cache=False)
def mine(a):
    return a.sum()

mine(np.ones(3))
print("user function compiled", file=sys.stderr, flush=True)
assert np.allclose(_kernels.scatter_add(np.array([0, 1, -1]), np.ones(3), 2), [1.0, 1.0])
assert list(mapping.vertex_clusters(np.array([0]), np.array([[0], [1], [2], [3]]), 5)) == [0, 0, 0, 0, -1]
print("done", file=sys.stderr, flush=True)
"""


def run(cache_dir):
    env = {**os.environ, "NUMBA_CACHE_DIR": str(cache_dir)}
    done = subprocess.run([sys.executable, "-c", SCRIPT], cwd=ROOT, env=env, capture_output=True, text=True,
                          timeout=300)
    assert done.returncode == 0, done.stderr
    return [line for line in done.stderr.splitlines() if line.strip()]


def test_notice_once_when_cold_and_never_when_warm(tmp_path):
    cold = run(tmp_path)
    assert cold == ["user function compiled", MESSAGE, "done"]
    assert os.listdir(tmp_path)  # the kernels are now cached there
    warm = run(tmp_path)
    assert warm == ["user function compiled", "done"]
