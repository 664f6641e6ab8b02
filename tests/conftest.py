import importlib.util
import os
import sys

import pytest

# ../shared/meshes beside the checkout, or wherever SKFEM_AFFINE_MESHES points (e.g. from a git worktree)
SHARED_MESHES = os.environ.get("SKFEM_AFFINE_MESHES") or os.path.join(os.path.dirname(__file__), "..", "..",
                                                                        "shared", "meshes")


@pytest.fixture
def shared_meshes():
    """The paper's meshes (../shared/meshes or $SKFEM_AFFINE_MESHES); tests using it skip when absent."""
    if not os.path.isdir(SHARED_MESHES):
        pytest.skip("../shared/meshes not present")
    return os.path.abspath(SHARED_MESHES)


BENCHMARKS = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "benchmarks")


@pytest.fixture
def benchmark_script():
    """``load(name)``: the module of benchmarks/NAME.py, run with benchmarks/ importable (the scripts
    import their neighbours)."""
    def load(name):
        sys.path.insert(0, BENCHMARKS)
        try:
            spec = importlib.util.spec_from_file_location(name, os.path.join(BENCHMARKS, f"{name}.py"))
            module = importlib.util.module_from_spec(spec)
            spec.loader.exec_module(module)
        finally:
            sys.path.remove(BENCHMARKS)
        return module
    return load
