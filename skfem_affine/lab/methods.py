"""The methods the lab measures: a name and a reducer factory (:class:`Method`, :data:`METHODS`).

A method is ``factory(tau_a, tau_e) -> reducer or None`` (None: full space) with default
thresholds; adding one is one line in :data:`METHODS` or ``register(Method(...))``, and every
runner and the command line know it by name.
"""
from dataclasses import dataclass


@dataclass(frozen=True)
class Method:
    """A way to run a scene: ``factory(tau_a, tau_e)`` returns a fresh reducer (None: full space).

    ``taus`` are the default thresholds, used when the caller gives none.
    """

    name: str
    factory: object
    taus: tuple = (None, None)

    def reducer(self, tau_a=None, tau_e=None):
        return self.factory(self.taus[0] if tau_a is None else tau_a, self.taus[1] if tau_e is None else tau_e)


def _affinification(**kwargs):
    from skfem_affine.reducers.affine.affinification import Affinification
    return Affinification(**kwargs)


def _rigidification(**kwargs):
    from skfem_affine.reducers.affine.rigidification import Rigidification
    return Rigidification(**kwargs)


def _subspace(**kwargs):
    from skfem_affine.reducers.subspace.reducer import AdaptiveSubspace
    return AdaptiveSubspace(**kwargs)


# the reducers are imported when a method first builds one, so that listing the methods (the command
# line's --help) imports none of them
METHODS = {m.name: m for m in [
    Method("full", lambda tau_a, tau_e: None),
    Method("affinification", lambda tau_a, tau_e: _affinification(tau_a=tau_a, tau_e=tau_e), (0.1, 0.2)),
    Method("rigidification", lambda tau_a, tau_e: _rigidification(tau_r=tau_a, tau_e=tau_e), (1e-2, 2e-2)),
    # the default reducer: thresholds chosen by its 1 % error budget (tau_a, tau_e unused)
    Method("affinification-budget", lambda tau_a, tau_e: _affinification()),
    # needs a Newton integrator: run the scene with integrator="implicit_euler" (--set integrator=implicit_euler),
    # so that "full" is the full-space Newton reference it converges to; tau_a, tau_e = eps_nodal, eps_modal
    Method("subspace", lambda tau_a, tau_e: _subspace(eps_nodal=tau_a, eps_modal=tau_e), (1e-3, 3e-3)),
]}

#: The methods ``compare`` runs by default (the first is the reference).
COMPARED = ("full", "affinification", "rigidification")


def register(method):
    """Add (or replace) a method by name: ``register(Method("mine", lambda a, e: Mine(a, e), (0.1, 0.2)))``."""
    if not isinstance(method, Method):
        raise TypeError(f"register needs a runners.Method, got {type(method).__name__}")
    METHODS[method.name] = method
    return method


def get_method(method):
    """The :class:`Method` of a name in :data:`METHODS` (a Method is returned as it is)."""
    if isinstance(method, Method):
        return method
    if method not in METHODS:
        raise ValueError(f"unknown method {method!r}; known: {', '.join(METHODS)}")
    return METHODS[method]
