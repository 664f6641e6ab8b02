"""skfem-affine: fast adaptive elastodynamics (affinification) for scikit-fem.

>>> import numpy as np, skfem, skfem_affine as sa
>>> mesh = skfem.MeshTet.init_tensor(*[np.linspace(0, 1, 3)] * 3)
>>> sim = sa.Simulation(sa.ElasticBody(mesh, sa.NeoHookean(E=1e5, nu=0.35)), dt=0.01, gravity=(0, 0, -9.81))
>>> state = sim.step()
>>> state.frame, state.x.shape
(1, (27, 3))
"""
from . import (assembly, bases, clustering, colliders, contact, io, kinematics, materials, metrics, newton, oracle,
               reduction, runners, scenes, solvers)
from .bases import AffineModes, LinearModes, SkinningEigenmodes
from .body import ElasticBody
from .colliders import Bowl, Box, Capsule, Plane, SDFCollider, Sphere
from .contact import PGS
from .integrator import Rayleigh, Simulation, SimulationDiverged, State, Stats
from .materials import Corotational, Material, NeoHookean, StVK
from .reducers import Affinification, Rigidification
from .subspace import AdaptiveSubspace

__version__ = "0.1.0"

__all__ = ["ElasticBody", "Simulation", "SimulationDiverged", "State", "Stats", "Rayleigh",
           "Material", "StVK", "Corotational", "NeoHookean", "Affinification", "Rigidification",
           "AdaptiveSubspace", "AffineModes", "LinearModes", "SkinningEigenmodes", "bases", "newton",
           "Plane", "Sphere", "Box", "Capsule", "Bowl", "SDFCollider", "PGS", "colliders", "contact",
           "assembly", "clustering", "io", "kinematics", "materials", "metrics", "oracle", "reduction", "runners",
           "scenes", "solvers"]
