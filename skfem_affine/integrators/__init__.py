"""Time integrators: one frame as data (:mod:`.problem`), the linearized backward Euler step
(:mod:`.linearized`) and Newton on the incremental potential (:mod:`.newton`)."""
