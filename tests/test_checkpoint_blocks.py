"""A reduced frame of several bodies factorised body by body resumes bit for bit: each body's
handle's ordering history is in the checkpoint (whether a block's pattern is known decides whether
its touched unknowns go last, and so whether the Delassus operator comes from a Schur complement)."""
import warnings

import numpy as np
import pytest

import skfem_affine as sa
from skfem_affine.lab import scenes
from skfem_affine.reducers.affine.blocks import BodyBlocks
from resuming import resume_bit_identically


def _pills():
    return scenes.pills(n=4, reducer=sa.Rigidification(0.1, 0.2))


def test_pills_under_rigidification_resume_bit_identically(tmp_path):
    sim = _pills()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", sa.SimulationWarning)
        list(sim.run(60))  # resting in the bowl: per-body blocks kept from frame to frame
        assert sim.reducer.blocks.handles  # the path this checks was taken
        resumed = resume_bit_identically(sim, _pills, tmp_path / "pills.npz", frames=3)
    assert sorted(resumed.reducer.blocks.handles) == sorted(sim.reducer.blocks.handles)


def test_body_blocks_refuse_a_damaged_body_list():
    with pytest.raises(ValueError, match="bodies"):
        BodyBlocks().load_state_dict({"bodies": np.array([2, 1])})
