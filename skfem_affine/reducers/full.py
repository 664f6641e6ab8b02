"""The identity reducer: every frame is solved in full space (``Simulation(reducer=None)``)."""
import time

from skfem_affine.integrators.problem import Operator, StepProblem, StepResult
from skfem_affine.reducers.base import Reducer
from skfem_affine.solvers import factorize_and_solve


class FullSpace(Reducer):
    """No reduction: A dv = b with the simulation's solver, or full-space Newton.

    Parameters
    ----------
    solver : solver object
        The simulation's solver (:func:`skfem_affine.solvers.make_solver`).
    """

    name = "full"
    integrators = ("linearized", "implicit_euler", "bdf2")
    iterates_linearized = True

    def __init__(self, solver):
        self.solver = solver

    def solve(self, problem):
        if isinstance(problem, StepProblem):
            stats = {}
            t0 = time.perf_counter()
            A = problem.matrix()
            b = problem.b
            stats["assembly"] = time.perf_counter() - t0
            dv = factorize_and_solve(self.solver, A, b, stats)
            return StepResult(dv=dv, operator=Operator(self.solver, A), stats=stats)
        from skfem_affine.integrators.newton import newton_solve  # the Newton integrators' problem
        stats = {}
        x, converged = newton_solve(problem, self.solver, stats)
        return StepResult(x=x, stats=stats)
