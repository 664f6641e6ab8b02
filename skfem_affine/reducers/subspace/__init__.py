"""The adaptive subspace method (Trusty, Fei, Levin & Kaufman): each Newton iterate is solved in a
small space of modes plus enriched nodes.

:class:`~skfem_affine.reducers.subspace.reducer.AdaptiveSubspace` is the reducer; it draws its
modes from a basis of :mod:`.bases` (affine modes, linear eigenmodes, Skinning Eigenmodes), picks
the nodes to enrich with the error/progress oracle of :mod:`.oracle`, solves on the METIS
subdomains of :mod:`.subdomains` with the Schur-complement PCG of :mod:`.linalg`, and meets an
error or time budget with the controllers of :mod:`.control`. It runs under the Newton
integrators (``integrator="implicit_euler"`` or ``"bdf2"``).
"""
