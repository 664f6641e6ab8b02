"""A checkpoint's resume checked bit for bit against the run that was saved."""
import numpy as np


def resume_bit_identically(sim, build, path, frames=8):
    """Save ``sim`` to ``path``, step it ``frames`` frames, step as many a fresh ``build()`` loaded from the
    file, assert equal states bit for bit and return the resumed simulation."""
    sim.save(path)
    ahead = [(s.x, s.v) for s in sim.run(frames)]
    resumed = build()
    resumed.load_state(path)
    after = [(s.x, s.v) for s in resumed.run(frames)]
    for (xa, va), (xb, vb) in zip(ahead, after):
        assert np.array_equal(xa, xb) and np.array_equal(va, vb)
    return resumed
