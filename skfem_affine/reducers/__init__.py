"""Reducers: the protocol (:mod:`.base`), the full space (:mod:`.full`), affine and rigid bodies
(:mod:`.affine`) and the adaptive subspace (:mod:`.subspace`)."""
