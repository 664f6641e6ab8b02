"""The identity reducer: every frame is solved in full space (``Simulation(reducer=None)``).

With contacts (found before the frame's solve) and MKL Pardiso, the frame is factorised with the
unknowns the contacts touch eliminated last, in the mode whose factorisation also solves the whole
system (:meth:`~skfem_affine.contact.schur.SchurInverse.factorize_on`): the Schur complement it
leaves on them gives the Delassus operator without a second factorisation.
"""
import time

import numpy as np

from skfem_affine.contact.delassus import unknown_bodies
from skfem_affine.integrators.problem import Operator, StepProblem, StepResult
from skfem_affine.reducers.base import Reducer
from skfem_affine.solvers import Pardiso, factorize_and_solve


def touched_unknowns(J):
    """The sorted columns of J (sparse) with a nonzero: the unknowns the contacts touch."""
    J = J.tocsr()
    return np.unique(J.indices[J.data != 0]).astype(np.int64)


def contact_factorization(schur, bodies, solver, contacts, A, G=None, upper=False):
    """A factorised with the unknowns the frame's contacts touch last, or None: factorise plainly.

    Parameters
    ----------
    schur : SchurInverse or None
        Contact's :class:`~skfem_affine.contact.schur.SchurInverse`, as a reducer is given it
        (:meth:`~skfem_affine.reducers.base.Reducer.use_contact`).
    bodies : (n_free,) int array or None
        The body of each free DOF.
    solver : solver object
        The reducer's solver: only a :class:`~skfem_affine.solvers.Pardiso` takes this route.
    contacts : Contacts or None
        The frame's contacts (``J``, free DOFs x 3 rows per contact), found before its solve.
    A : sparse matrix
        The frame's matrix: full A, or A_r = G^T A G (its upper triangle with ``upper=True``).
    G : sparse matrix, optional
        The reduced frame's mapping (free DOFs x reduced unknowns): the touched unknowns are the
        columns of J G with a nonzero, and their bodies those of G's rows.

    Returns
    -------
    (handle, keep, S) or None
        The factorisation (it solves A x = b), the sorted unknowns it eliminated last (the touched
        ones or a kept superset) and their Schur complement S; None when there is no Schur inverse
        (or its ``frame`` setting is off, or no MKL), no contact, another solver, or the Schur
        inverse's rules decline. Contacts on several bodies in full space: A factorised body by
        body, each body's block with its touched unknowns last
        (:meth:`~skfem_affine.contact.schur.SchurInverse.factorize_blocks`; one dense block of all
        their unknowns would be dearer than each body's own), S then the list of the bodies'
        complements in the order of ``keep``; in a reduced frame None.
    """
    if (schur is None or not schur.frame or not schur.available or contacts is None or contacts.J is None
            or not isinstance(solver, Pardiso)):
        return None
    T = touched_unknowns(contacts.J if G is None else contacts.J @ G)
    if bodies is not None and T.size:
        of = unknown_bodies(bodies, G)
        if of is None:
            return None
        if of[T].min() != of[T].max():  # several bodies: each body's block on its own (full space)
            return schur.factorize_blocks(A, T, of) if G is None and not upper else None
    near = getattr(contacts, "near_unknowns", None) if G is None else None
    return schur.factorize_on(A, T, upper=upper, near=None if near is None else np.union1d(near, T))


class FullSpace(Reducer):
    """No reduction: A dv = b with the simulation's solver, or full-space Newton.

    Parameters
    ----------
    solver : solver object
        The simulation's solver (:func:`skfem_affine.solvers.make_solver`).
    schur : SchurInverse, optional
        Contact's :class:`~skfem_affine.contact.schur.SchurInverse`: with a Pardiso ``solver`` and its
        ``frame`` setting, a frame with contacts is factorised with their unknowns last where its
        rules accept (the Schur complement then rides in the :class:`Operator`), else plainly.
    bodies : (n_free,) int array, optional
        The body of each free DOF. A frame whose contacts touch several bodies is factorised body by
        body, each body's block with its touched unknowns last: Pardiso treats a Schur set as one
        dense block, so the whole system's would be dearer than each body's complement on its own
        block (measured in ``docs/contact.md``).
    """

    name = "full"
    integrators = ("linearized", "implicit_euler", "bdf2")
    iterates_linearized = True

    def __init__(self, solver, schur=None, bodies=None):
        self.solver = solver
        self.use_contact(schur, bodies)

    def _frame_schur(self, problem, A, b, stats):
        """dv and the Operator from the factorisation with the contacts' unknowns last, or None."""
        t0 = time.perf_counter()
        out = contact_factorization(self._contact_schur, self._contact_bodies, self.solver, problem.contacts, A)
        if out is None:
            return None
        handle, keep, S = out
        t1 = time.perf_counter()
        dv = handle.solve(b)
        t2 = time.perf_counter()
        stats["factorization"] = stats.get("factorization", 0.0) + t1 - t0
        stats["solve"] = stats.get("solve", 0.0) + t2 - t1
        stats.update(dofs=A.shape[0], solver=self.solver.name, iterations=stats.get("iterations", 0) + 1,
                     frame_schur=int(keep.size))
        return StepResult(dv=dv, operator=Operator(handle, A, schur=(keep, S)), stats=stats)

    def solve(self, problem):
        if isinstance(problem, StepProblem):
            stats = {}
            t0 = time.perf_counter()
            A = problem.matrix()
            b = problem.b
            stats["assembly"] = time.perf_counter() - t0
            result = self._frame_schur(problem, A, b, stats)
            if result is not None:
                return result
            dv = factorize_and_solve(self.solver, A, b, stats)
            return StepResult(dv=dv, operator=Operator(self.solver, A), stats=stats)
        from skfem_affine.integrators.newton import newton_solve  # the Newton integrators' problem
        stats = {}
        x, converged = newton_solve(problem, self.solver, stats)
        return StepResult(x=x, stats=stats)
