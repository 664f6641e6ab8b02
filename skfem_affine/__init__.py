"""skfem-affine: fast adaptive elastodynamics (affinification) for scikit-fem.

>>> import numpy as np, skfem, skfem_affine as sa
>>> mesh = skfem.MeshTet.init_tensor(*[np.linspace(0, 1, 3)] * 3)
>>> sim = sa.Simulation(sa.ElasticBody(mesh, sa.NeoHookean(E=1e5, nu=0.35)), dt=0.01, gravity=(0, 0, -9.81))
>>> state = sim.step()
>>> state.frame, state.x.shape
(1, (27, 3))

The package is laid out by idea: the elastic core (:mod:`materials`, :mod:`kinematics`,
:mod:`body`, :mod:`assembly`, :mod:`solvers`), :mod:`integrators`, :mod:`reducers`
(``affine/`` and ``subspace/``), :mod:`contact`, and the measuring tools in :mod:`lab`.
"""
from skfem_affine import _compile_notice  # noqa: F401 (one stderr line when the kernels compile)
from skfem_affine import assembly, kinematics, materials, solvers, stress
from skfem_affine.body import ElasticBody
from skfem_affine.contact import colliders
from skfem_affine.contact.colliders import Bowl, Box, Capsule, Plane, SDFCollider, Sphere
from skfem_affine.contact.ipc import IPC
from skfem_affine.contact.pgs import PGS
from skfem_affine.materials import Corotational, Material, NeoHookean, StVK
from skfem_affine.motion import Prescribed, VertexForce
from skfem_affine.reducers.affine.affinification import Affinification
from skfem_affine.reducers.affine.rigidification import Rigidification
from skfem_affine.reducers.subspace import bases
from skfem_affine.reducers.subspace.bases import AffineModes, LinearModes, SkinningEigenmodes
from skfem_affine.reducers.subspace.reducer import AdaptiveSubspace
from skfem_affine.vertex_sets import vertices_of
from skfem_affine.simulation import Rayleigh, Simulation, SimulationDiverged, SimulationWarning, State, Stats
from skfem_affine.lab import io, metrics, runners, scenes

__version__ = "0.1.0"

__all__ = ["ElasticBody", "Prescribed", "VertexForce", "vertices_of", "Simulation", "SimulationDiverged", "SimulationWarning", "State", "Stats", "Rayleigh",
           "Material", "StVK", "Corotational", "NeoHookean", "Affinification", "Rigidification",
           "AdaptiveSubspace", "AffineModes", "LinearModes", "SkinningEigenmodes", "bases",
           "Plane", "Sphere", "Box", "Capsule", "Bowl", "SDFCollider", "PGS", "IPC", "colliders",
           "assembly", "io", "kinematics", "materials", "metrics", "runners", "scenes", "solvers", "stress"]
