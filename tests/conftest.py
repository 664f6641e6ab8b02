import os

import pytest

SHARED_MESHES = os.path.join(os.path.dirname(__file__), "..", "..", "shared", "meshes")


@pytest.fixture
def shared_meshes():
    """The paper's meshes in ../shared/meshes; tests using it skip when absent."""
    if not os.path.isdir(SHARED_MESHES):
        pytest.skip("../shared/meshes not present")
    return os.path.abspath(SHARED_MESHES)
