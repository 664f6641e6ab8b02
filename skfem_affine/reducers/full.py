"""The identity reducer: every frame is solved in full space (``Simulation(reducer=None)``)."""
import time

from skfem_affine.integrators.problem import Operator, StepProblem, StepResult
from skfem_affine.reducers.base import Reducer


def factorize_and_solve(solver, A, b, stats):
    """Factorise A, solve A x = b; record the timings, DOFs, solver and iterations in ``stats``."""
    t0 = time.perf_counter()
    solver.factorize(A)
    t1 = time.perf_counter()
    x = solver.solve(b)
    t2 = time.perf_counter()
    stats["factorization"] = stats.get("factorization", 0.0) + t1 - t0
    stats["solve"] = stats.get("solve", 0.0) + t2 - t1
    stats["dofs"] = A.shape[0]
    stats["solver"] = solver.name
    stats["iterations"] = stats.get("iterations", 0) + solver.last_iterations
    return x


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
