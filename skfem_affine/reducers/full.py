"""The identity reducer: every frame is solved in full space (``Simulation(reducer=None)``).

With contacts (found before the frame's solve) and MKL Pardiso, the frame is factorised with the
unknowns the contacts touch eliminated last, in the mode whose factorisation also solves the whole
system (:meth:`~skfem_affine.contact.schur.SchurInverse.factorize_on`): the Schur complement it
leaves on them gives the Delassus operator without a second factorisation.
"""
import time

import numpy as np

from skfem_affine.integrators.problem import Operator, StepProblem, StepResult
from skfem_affine.reducers.base import Reducer
from skfem_affine.solvers import Pardiso, factorize_and_solve


def touched_unknowns(J):
    """The sorted columns of J (sparse) with a nonzero: the unknowns the contacts touch."""
    J = J.tocsr()
    return np.unique(J.indices[J.data != 0]).astype(np.int64)


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
        The body of each free DOF. A frame whose contacts touch several bodies is factorised plainly:
        Pardiso treats the whole Schur set as one dense block, dearer than each body's complement on
        its own block (the Delassus operator's path then; measured in ``docs/contact.md``).
    """

    name = "full"
    integrators = ("linearized", "implicit_euler", "bdf2")
    iterates_linearized = True

    def __init__(self, solver, schur=None, bodies=None):
        self.solver, self.schur, self.bodies = solver, schur, bodies

    def _frame_schur(self, problem, A, b, stats):
        """dv and the Operator from the factorisation with the contacts' unknowns last, or None."""
        schur, contacts = self.schur, problem.contacts
        if (schur is None or not schur.frame or not schur.available or contacts is None or contacts.J is None
                or not isinstance(self.solver, Pardiso)):
            return None
        t0 = time.perf_counter()
        T = touched_unknowns(contacts.J)
        if self.bodies is not None and T.size and self.bodies[T].min() != self.bodies[T].max():
            return None
        out = schur.factorize_on(A, T)
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
