import os

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
