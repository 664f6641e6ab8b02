"""The order of the gallery: the tutorial path, from a first simulation to the second method."""
import os

TUTORIAL = [
    "cantilever.py",          # a first simulation
    "own_mesh.py",            # your own mesh, a material per region
    "boundaries.py",          # fixed boundaries
    "rotating_clamp.py",      # moving boundaries and pulling forces
    "contact_drop.py",        # contact with the ground
    "contact_stacking.py",    # contact between bodies
    "contact_materials.py",   # stiff against soft
    "affinification.py",      # the speed/accuracy knob
    "compare.py",             # measuring the trade
    "threshold_sweep.py",     # choosing the trade
    "output.py",              # ParaView and a GIF
    "adaptive_subspace.py",   # the second method
    "custom_reducer.py",      # writing your own reducer
    "beam_frequency.py",      # verification against beam theory
    "engineer_beam.py",       # an engineer's check: deflection, frequency, stress, trade
]


class TutorialOrder:
    """Sort key for sphinx-gallery: the position in :data:`TUTORIAL`, unknown files last by name."""

    def __init__(self, src_dir):
        self.src_dir = src_dir

    def __call__(self, filename):
        name = os.path.basename(filename)
        return (TUTORIAL.index(name), "") if name in TUTORIAL else (len(TUTORIAL), name)

    def __repr__(self):
        return f"{type(self).__name__}()"
