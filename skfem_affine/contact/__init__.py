"""Contact: static colliders, detection geometry, the Delassus operator, projected Gauss-Seidel
(linearized integrator) and the IPC barrier (Newton integrators)."""
