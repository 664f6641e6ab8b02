"""TEMPORARY stand-in for ``skfem_affine.integrators.problem.StepResult`` (owner: helper `frame`).

Delete at the merge of issue #11 and import ``StepResult`` from ``skfem_affine.integrators.problem``
in ``integrators/newton_integrator.py`` and ``reducers/subspace/reducer.py`` (the only users).
"""
from dataclasses import dataclass, field

import numpy as np


@dataclass
class StepResult:
    dv: np.ndarray = None
    x: np.ndarray = None
    operator: object = None
    mapping: object = None
    clusters: np.ndarray = None
    stats: dict = field(default_factory=dict)
