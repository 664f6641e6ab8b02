"""The reducer protocol: the one place where the methods differ (paper Algorithm 1).

A reducer decides, frame by frame, in which subspace the step is solved. It is attached once
to the :class:`~skfem_affine.integrators.problem.Model` of a run, then asked to solve each
frame. It never sees the :class:`~skfem_affine.Simulation`: everything it may use comes in the
problem, and everything the integrator and contact need goes back in the
:class:`~skfem_affine.integrators.problem.StepResult`.

A minimal reducer (see ``examples/custom_reducer.py`` for one that builds affine bodies)::

    class Full(Reducer):
        name = "my-full"
        integrators = ("linearized",)

        def _setup(self, model):
            self.solver = make_solver("direct")

        def solve(self, problem):
            A = problem.matrix()
            self.solver.factorize(A)
            return StepResult(dv=self.solver.solve(problem.b), operator=Operator(self.solver, A))
"""
import abc
import copy
import time

import numpy as np


class Reducer(abc.ABC):
    """Base of every reducer.

    Attributes
    ----------
    name : str
        Label in tables and plots.
    integrators : tuple of str
        The integrators the reducer runs under: ``"linearized"`` (it is given a
        :class:`~skfem_affine.integrators.problem.StepProblem`) and/or ``"implicit_euler"``,
        ``"bdf2"`` (it is given an incremental potential,
        :class:`~skfem_affine.integrators.newton.IncrementalPotential`). The simulation refuses
        any other combination with a ValueError.
    iterates_linearized : bool
        Whether the reducer supports the linearized integrator's ``newton_iters > 1`` (a full
        Newton solve of implicit Euler); only the full space does.
    setup_time : float
        Seconds spent in :meth:`attach` (set by it).
    model : Model or None
        The run the reducer is attached to (set by :meth:`attach`); a reducer serves one
        simulation, and a second one refuses it.
    newton_tol, max_newton : float or int, optional
        A reducer's own Newton settings (None: the Simulation's); a Simulation given others refuses
        the pair (:func:`~skfem_affine.integrators.newton.resolve_newton_settings`).
    default_newton_tol, default_max_newton : float or int, optional
        The Newton settings a reducer recommends when nobody gives any (None: the integrator's).
    _state_keys : tuple of str
        Attributes that carry state from one frame to the next (arrays, numbers, None, or
        JSON-like values); :meth:`state_dict` saves them for a checkpoint
        (:mod:`skfem_affine.checkpoint`). A subclass extends the tuple of its base.
    _contact_schur, _contact_bodies : SchurInverse and int array, or None
        What contact gives the reducer (:meth:`use_contact`); None without contact.
    """

    name = "reducer"
    integrators = ("linearized",)
    iterates_linearized = False
    setup_time = 0.0
    model = None
    newton_tol = max_newton = default_newton_tol = default_max_newton = None
    _state_keys = ()
    _contact_schur = _contact_bodies = None

    def state_dict(self):
        """The state later frames depend on: ``{key: copy of self.key}`` over :attr:`_state_keys`
        (after :meth:`attach`)."""
        return {key: copy.deepcopy(getattr(self, key)) for key in self._state_keys}

    def load_state_dict(self, state):
        """Restore what :meth:`state_dict` saved (after :meth:`attach`); ValueError on missing keys."""
        missing = [key for key in self._state_keys if key not in state]
        if missing:
            raise ValueError(f"{type(self).__name__} state is missing {missing}")
        for key in self._state_keys:
            value, current = state[key], getattr(self, key, None)
            if isinstance(current, np.ndarray) and isinstance(value, np.ndarray) and value.shape != current.shape \
                    and current.shape[:1] in ((self.model.system.n,), (self.model.system.m,)):
                raise ValueError(f"{type(self).__name__} {key} must have shape {current.shape} (one entry per "
                                 f"{'vertex' if current.shape[0] == self.model.system.n else 'element'}), "
                                 f"got {value.shape}")
            try:  # a property may check or rebuild from the value
                setattr(self, key, value.copy() if isinstance(value, np.ndarray) else copy.deepcopy(value))
            except Exception as err:
                raise ValueError(f"{type(self).__name__} {key}: {type(err).__name__}: {err}") from None

    def use_contact(self, schur, bodies):
        """Take contact's Schur inverse and the body of each free DOF, once, before :meth:`attach`.

        Parameters
        ----------
        schur : SchurInverse or None
            The contact model's :class:`~skfem_affine.contact.schur.SchurInverse`: a reducer that
            factorises its frame with a Pardiso solver may do so with the unknowns the contacts touch
            last (:func:`~skfem_affine.reducers.full.contact_factorization`), so that the Delassus
            operator takes their Schur complement from the frame's factorisation.
        bodies : (n_free,) int array or None
            The body of each free DOF: a frame whose contacts touch several bodies factorises plainly.
        """
        self._contact_schur, self._contact_bodies = schur, bodies

    def attach(self, model):
        """Rest-state set-up, once per run, before the first frame.

        Parameters
        ----------
        model : Model
            The system, time step, damping, gravity and scene size of the run.

        Notes
        -----
        Subclasses extend :meth:`_setup` (timed into :attr:`setup_time`) rather than this method.
        """
        t0 = time.perf_counter()
        self.model = model
        self._setup(model)
        self.setup_time = time.perf_counter() - t0

    def _setup(self, model):
        """Per-run set-up of the subclass (caches, preconditioners, solvers)."""

    @abc.abstractmethod
    def solve(self, problem):
        """Solve one frame.

        Parameters
        ----------
        problem : StepProblem or IncrementalPotential
            Under ``"linearized"``, the frame's linear system (eq. 1-2) at x_t with the
            contacts and the oracle's contact impulses; under a Newton integrator, the incremental
            potential of the step.

        Returns
        -------
        StepResult
            ``dv`` (free-DOF velocity change) under ``"linearized"``, ``x`` (flat positions)
            under a Newton integrator; ``operator`` when contact must resolve with the frame's
            factorisation; ``mapping`` and ``clusters`` of a reduced frame; ``stats`` for the
            frame's record.
        """

    def end_frame(self, rec):
        """Called by the simulation after each frame with the frame's record (``rec["wall"]`` set).

        A reducer that budgets time reads the frame's wall time here and may add to ``rec``;
        the default does nothing.
        """

    def check_integrator(self, integrator, newton_iters=1):
        """Raise a ValueError unless this reducer runs under ``integrator`` (with ``newton_iters``)."""
        if integrator not in self.integrators:
            raise ValueError(f"{type(self).__name__} runs with integrator in {self.integrators}, "
                             f"not integrator={integrator!r}")
        if integrator == "linearized" and newton_iters > 1 and not self.iterates_linearized:
            raise ValueError(f"{type(self).__name__} solves the linearized step once: newton_iters must be 1 "
                             f"with a reducer, got newton_iters={newton_iters}")
