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
import importlib

#: Where each public name lives: imported on first use (``sa.Simulation``, ``from skfem_affine import
#: Affinification``), so that ``import skfem_affine`` and the command line's ``--help`` stay fast.
_LAZY = {
    "skfem_affine.body": ("ElasticBody",),
    "skfem_affine.contact.colliders": ("Bowl", "Box", "Capsule", "Plane", "SDFCollider", "Sphere"),
    "skfem_affine.contact.ipc": ("IPC",),
    "skfem_affine.contact.pgs": ("PGS",),
    "skfem_affine.materials": ("Corotational", "Material", "NeoHookean", "StVK"),
    "skfem_affine.motion": ("Prescribed", "VertexForce"),
    "skfem_affine.reducers.affine.affinification": ("Affinification",),
    "skfem_affine.reducers.affine.rigidification": ("Rigidification",),
    "skfem_affine.reducers.subspace.bases": ("AffineModes", "LinearModes", "SkinningEigenmodes"),
    "skfem_affine.reducers.subspace.reducer": ("AdaptiveSubspace",),
    "skfem_affine.vertex_sets": ("vertices_of",),
    "skfem_affine.simulation": ("Rayleigh", "Simulation", "SimulationDiverged", "SimulationWarning", "State",
                                "Stats"),
}
_WHERE = {name: module for module, names in _LAZY.items() for name in names}
#: Public submodules, by the name they are reached under.
_MODULES = {"assembly": "skfem_affine.assembly", "kinematics": "skfem_affine.kinematics",
            "materials": "skfem_affine.materials", "solvers": "skfem_affine.solvers",
            "stress": "skfem_affine.stress",
            "colliders": "skfem_affine.contact.colliders", "bases": "skfem_affine.reducers.subspace.bases",
            "io": "skfem_affine.lab.io", "metrics": "skfem_affine.lab.metrics",
            "runners": "skfem_affine.lab.runners", "scenes": "skfem_affine.lab.scenes"}


def __getattr__(name):
    if name in _WHERE:
        value = getattr(importlib.import_module(_WHERE[name]), name)
    elif name in _MODULES:
        value = importlib.import_module(_MODULES[name])
    else:
        raise AttributeError(f"module 'skfem_affine' has no attribute {name!r}")
    globals()[name] = value  # later look-ups skip this function
    return value


def __dir__():
    return sorted(set(globals()) | set(__all__))


__version__ = "0.1.0"

__all__ = ["ElasticBody", "Prescribed", "VertexForce", "vertices_of", "Simulation", "SimulationDiverged", "SimulationWarning", "State", "Stats", "Rayleigh",
           "Material", "StVK", "Corotational", "NeoHookean", "Affinification", "Rigidification",
           "AdaptiveSubspace", "AffineModes", "LinearModes", "SkinningEigenmodes", "bases",
           "Plane", "Sphere", "Box", "Capsule", "Bowl", "SDFCollider", "PGS", "IPC", "colliders",
           "assembly", "io", "kinematics", "materials", "metrics", "runners", "scenes", "solvers", "stress"]
