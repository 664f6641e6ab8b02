r"""The divergence policy: what each frame is checked for before it is returned as a result.

After every step the :class:`~skfem_affine.Simulation` hands the new state to a :class:`Monitor`
*before* accepting it; a step that fails a check is never returned as a valid state.

**Raised** as :class:`~skfem_affine.SimulationDiverged` (naming the frame and the cause):

* a non-finite position or velocity, a linear solve that fails;
* **energy created by the step.** The total mechanical energy
  :math:`E = \tfrac12 v^T M v + \Psi(x) - f_g^T(x - X) + B(x)` (kinetic, strain, gravity, and the
  contact barrier of the Newton integrators) of an implicit Euler or BDF2 step can only decrease
  apart from the work :math:`W` of external forces other than gravity: both minimise an
  incremental potential whose minimiser dissipates. The step is refused when

  .. math:: E_{t+1} - E_t - W_t > c_E \, S_t, \qquad
            S_t = \max\big(\max_{s \le t} (K_s + \Psi_s),\; |f_g| \ell,\; \Psi_{floor}\big),

  i.e. when one step creates more energy than the largest energy the scene has had in play
  (kinetic plus strain) or than lifting its weight by the scene size :math:`\ell`, times
  ``energy_growth`` :math:`c_E` (default 1). :math:`\Psi_{floor}` is the strain energy of every
  element stretched by a strain of 1e-6 (``energy_floor``): the absolute scale below which
  energies are round-off (a body at rest has 1e-27 J of strain energy from rounding), so that a
  scene starting at rest without gravity is not taken for a blow-up when its first energies move
  by round-off or by a load ramped from zero. A blow-up (energy growing by a factor each frame)
  trips this as soon as a single step gains more than the energy in play; a run that loses or
  keeps its energy never does. The linearized integrator is not an exact minimiser: under a
  fast rotation (:math:`h\omega` not small) its step gains energy, of relative size about
  :math:`(h\omega)^2` per step for a soft body and much more for a stiff one, whose
  linearization of the rotation produces spurious strain; gains below ``energy_growth`` times the
  energy in play pass (and show in ``sim.stats`` as ``energy``), larger ones are refused.
  ``check_energy=False`` switches the check off (it costs one strain-energy pass per frame);
  a gain of more than ``energy_warn`` (5 %) of :math:`S_t` that is not refused is **warned**
  (a :class:`SimulationWarning` naming the frame, once per run; every frame records its gain
  relative to :math:`S_t` as ``energy_gain``): neither scheme creates energy without external
  work, so such a step is wrong even when it is not a blow-up;
* **a step whose state intersects** under the Newton integrators' contact (the barrier's or IPC's
  ``intersection_free``: a vertex on or inside a collider, or, under IPC, two surfaces crossing
  each other): the line search's CCD bound keeps every iterate intersection-free, so such a state
  is never accepted, whatever Newton's convergence;
* **a step that tears a body apart**: a vertex whose displacement in one step, relative to its
  body's mean displacement, exceeds the body's rest diagonal (a rigid motion of a body never
  does unless it turns by more than about 60 degrees in one step).

**Warned or raised, as the user chooses** (``on_inverted``, ``on_nonconvergence``:
``"warn"`` (default: one :class:`SimulationWarning` per kind and run, every frame counted in
``sim.stats``), ``"raise"``, or ``"ignore"`` (only counted; with ``on_inverted="ignore"`` and
``check_energy=False`` the checks need no pass over the elements and cost almost nothing)):

* inverted elements (det F <= 0) in the new state: ``rec["inverted_elements"]`` (None when
  not checked);
* a Newton solve that stopped before its tolerance (``rec["newton_converged"]`` False).

Each frame's record gets ``energy`` (J, when checked), ``inverted_elements`` and, with contact,
``max_penetration``.
"""
import warnings

import numpy as np

from skfem_affine.checks import choice, flag, positive, real

POLICIES = ("warn", "raise", "ignore")


class SimulationWarning(UserWarning):
    """A frame was accepted with a defect the user asked to be warned about (inverted elements,
    a Newton solve that did not converge, energy created by the step), or a body was built whose
    discretisation will be visibly wrong (a near-incompressible material that locks)."""


#: h^2 k / m above which the linearized step's round-off is visible (see :func:`stiffness_ratios`)
STIFF_RATIO = 1e12


def stiffness_ratios(system, dt):
    r"""Per element, :math:`\kappa_e = h^2 (\lambda_e + 2\mu_e) V_e \sum_a |\nabla\phi_a|^2 / \min_a m_a`:
    the element's stiffness against the lightest of its vertex masses, times h^2.

    A solve of :math:`A = M + h^2 K` loses about :math:`\kappa \epsilon` (:math:`\epsilon` the
    machine precision) of a rigid motion, which K should not see but sees through round-off: a
    single sliver tetrahedron of relative volume 1e-8 (E = 1e5, h = 0.01; kappa = 1.4e15) fell 21 %
    too short in 0.5 s under the linearized step, 1e-7 (kappa = 1.4e13) 0.1 %, while a Newton step,
    which iterates to its tolerance, is exact.
    """
    g2 = (system.grads ** 2).sum(axis=(1, 2))
    lightest = system.lumped_mass[system.t.T]  # (m, 4)
    return dt ** 2 * (system._lam + 2.0 * system._mu) * system.volumes * g2 / lightest.min(axis=1)


def warn_stiff_elements(system, dt, stacklevel=3):
    """Warn (:class:`SimulationWarning`) naming the elements whose :func:`stiffness_ratios` exceed
    :data:`STIFF_RATIO` (the linearized step's error on them is then more than about 1e-4);
    returns the largest ratio."""
    kappa = stiffness_ratios(system, dt)
    bad = np.flatnonzero(kappa > STIFF_RATIO)
    if bad.size:
        worst = bad[np.argsort(kappa[bad])[::-1][:5]]
        warnings.warn(f"element(s) {worst.tolist()}{' ...' if bad.size > 5 else ''} ({bad.size} in all) are so "
                      f"thin for their stiffness that the linearized step loses accuracy on them: h^2 k/m = "
                      f"{kappa[worst[0]]:.2g} (above {STIFF_RATIO:g}): an error of about {kappa[worst[0]] * np.finfo(float).eps:.1g} "
                      f"relative to the step's motion (round-off). Use "
                      f"integrator='implicit_euler' (exact here), a smaller dt, or remesh the sliver(s)",
                      SimulationWarning, stacklevel=stacklevel)
    return float(kappa.max(initial=0.0))


class Diverged(Exception):
    """Raised by :meth:`Monitor.check` with the cause; the simulation turns it into SimulationDiverged."""


def _fmt(x):
    return f"{x:.3g}"


class Monitor:
    """Checks of the divergence policy for one run (see the module docstring).

    Parameters
    ----------
    system : ElasticSystem
    f_gravity : (3n,) array
    size : float
        The scene size (rest bounding-box diagonal).
    on_inverted, on_nonconvergence : {"warn", "raise"}
    check_energy : bool
    energy_growth : float
        c_E, > 0.
    energy_warn : float
        Fraction of the energy scale S_t a step may create before it is warned about, > 0.
    """

    FLOOR_STRAIN = 1e-6  # the strain whose strain energy is the absolute floor of the energy scale

    def __init__(self, system, f_gravity, size, on_inverted="warn", on_nonconvergence="warn", check_energy=True,
                 energy_growth=1.0, energy_warn=0.05, method="full space"):
        self.system, self.f_gravity, self.size = system, f_gravity, float(size)
        self.method = method  # named in warnings: a process may step several simulations of one scene
        self.on_inverted = choice(on_inverted, "on_inverted", POLICIES)
        self.on_nonconvergence = choice(on_nonconvergence, "on_nonconvergence", POLICIES)
        self.check_energy = flag(check_energy, "check_energy")
        self.energy_growth = positive(energy_growth, "energy_growth")
        self.energy_warn = positive(energy_warn, "energy_warn")
        self.body_of_vertex = system.body_of_vertex
        self.n_bodies = len(system.bodies)
        counts = np.bincount(self.body_of_vertex, minlength=self.n_bodies)
        self.counts = np.maximum(counts, 1)[:, None]
        p0 = system.p0
        self.body_size = np.array([np.linalg.norm(np.ptp(p0[self.body_of_vertex == b], axis=0))
                                   for b in range(self.n_bodies)])
        self.weight_scale = float(np.linalg.norm(f_gravity.reshape(-1, 3).sum(axis=0))) * self.size
        self.energy_floor = self.floor(system)
        self.energy = None        # total energy of the current state
        self.in_play = 0.0        # max over accepted frames of kinetic + strain
        self.warned = {"inverted": False, "nonconvergence": False, "energy": False}
        self._accepted = None     # (x, v) of the state the last checked step produced
        self._pending = None

    # -------------------------------------------------------------- energy
    @classmethod
    def floor(cls, system):
        """The strain energy (J) of every element stretched by ``FLOOR_STRAIN`` along x: the scale of
        the problem below which energy changes are round-off."""
        F = np.eye(3)
        F[0, 0] += cls.FLOOR_STRAIN
        total = 0.0
        for mat, idx in system.groups:
            Fs = np.broadcast_to(F, (len(idx), 3, 3)).copy()
            total += float(np.dot(system.volumes[idx], mat.energy_density(Fs)))
        return total if np.isfinite(total) and total > 0 else 1e-300

    def energies(self, x, v, barrier=None, F=None):
        """(total, kinetic + strain) of a state; the barrier energy counts as potential.
        ``F``: the deformation gradients at x, if already computed."""
        sysm = self.system
        vf = v.reshape(-1)
        kin = 0.5 * float(vf @ (sysm.M @ vf))
        F = sysm.deformation_gradients(x) if F is None else F
        strain = float(sum(np.dot(sysm.volumes[idx], mat.energy_density(F[idx])) for mat, idx in sysm.groups))
        grav = -float(self.f_gravity @ (x - sysm.p0).reshape(-1))
        bar = 0.0 if barrier is None else float(barrier.energy(x.reshape(-1)))
        return kin + strain + grav + bar, kin + strain

    def start(self, state, barrier=None):
        """Reference values from the state a step starts from: recomputed when it is not the state
        the last step produced (the first step, a loaded or edited state), so that a state changed
        from outside (a kick) is never taken for energy the integrator created."""
        if not self.check_energy:
            return
        ref = self._accepted
        if self.energy is None or ref is None or not (np.array_equal(ref[0], state.x) and
                                                       np.array_equal(ref[1], state.v)):
            self.energy, play = self.energies(state.x, state.v, barrier)
            self.in_play = max(self.in_play, play)

    # -------------------------------------------------------------- the checks
    def check(self, frame, x0, x, v, rec, barrier=None):
        """Check the step x0 -> (x, v) of ``frame``; raises :class:`Diverged` with the cause, warns or
        raises per the policies, and records ``energy`` and ``inverted_elements`` into ``rec``."""
        if barrier is not None and not barrier.intersection_free(x.reshape(-1)):
            raise Diverged("the step's state intersects (surfaces through each other, or a vertex through a "
                           "collider), which contact must never accept; a smaller dt")
        self._tearing(x0, x)
        F = None
        if self.check_energy or self.on_inverted != "ignore":
            F = self.system.deformation_gradients(x)
        if self.check_energy:
            e, play = self.energies(x, v, barrier, F)
            work = float(rec.get("external_work", 0.0))
            scale = max(self.in_play, self.weight_scale, self.energy_floor)
            gain = e - self.energy - work
            rec["energy_gain"] = gain / scale
            if not np.isfinite(e) or gain > self.energy_growth * scale:
                factor = e / self.energy if self.energy > 0 else float("inf")
                grew = f"{_fmt(factor)}x " if np.isfinite(factor) and factor > 1 else ""
                raise Diverged(f"energy grew {grew}in one step (from {_fmt(self.energy)} J to {_fmt(e)} J; "
                               f"external work {_fmt(work)} J, energy in play {_fmt(scale)} J)")
            rec["energy"] = e
            self._pending = (e, play, x.copy(), v.copy())
            if gain > self.energy_warn * scale:
                factor = f" ({_fmt(e / self.energy)}x)" if self.energy > 0 else ""
                self._policy("energy", "warn",
                             f"the step created {_fmt(gain)} J{factor}, {_fmt(100 * gain / scale)} % of the energy in "
                             f"play {_fmt(scale)} J, beyond the external work of {_fmt(work)} J (from {_fmt(self.energy)} J to {_fmt(e)} J; "
                             f"a smaller dt, or integrator='implicit_euler', which cannot create energy)", frame)
        inverted = None if F is None else self.inverted(F)
        rec["inverted_elements"] = inverted
        if inverted:
            self._policy("inverted", self.on_inverted, f"{inverted} inverted element(s) (det F <= 0)", frame)
        if not rec.get("newton_converged", True):
            self._policy("nonconvergence", self.on_nonconvergence,
                         f"Newton stopped after {rec.get('newton_iters')} iteration(s) without reaching its tolerance",
                         frame)

    def accept(self):
        """The checked step became the state: update the energy reference."""
        pending = self._pending
        if pending is not None:
            self.energy = pending[0]
            self.in_play = max(self.in_play, pending[1])
            self._accepted = pending[2:]
            self._pending = None

    @staticmethod
    def inverted(F):
        """Number of elements with det F <= 0, F (m, 3, 3) the deformation gradients."""
        det = (F[:, 0, 0] * (F[:, 1, 1] * F[:, 2, 2] - F[:, 1, 2] * F[:, 2, 1])
               - F[:, 0, 1] * (F[:, 1, 0] * F[:, 2, 2] - F[:, 1, 2] * F[:, 2, 0])
               + F[:, 0, 2] * (F[:, 1, 0] * F[:, 2, 1] - F[:, 1, 1] * F[:, 2, 0]))
        return int(np.count_nonzero(det <= 0))

    def _tearing(self, x0, x):
        d = (x - x0).reshape(-1, 3)
        if self.n_bodies == 1:
            worst = np.sqrt(((d - d.mean(axis=0)) ** 2).sum(axis=1).max(initial=0.0))[None]
        else:
            mean = np.stack([np.bincount(self.body_of_vertex, d[:, k], self.n_bodies) for k in range(3)], axis=1)
            rel = np.sqrt(((d - (mean / self.counts)[self.body_of_vertex]) ** 2).sum(axis=1))
            worst = np.zeros(self.n_bodies)
            np.maximum.at(worst, self.body_of_vertex, rel)
        bad = np.flatnonzero(worst > self.body_size)
        if bad.size:
            b = int(bad[0])
            raise Diverged(f"body {b} was torn apart: a vertex moved {_fmt(worst[b])} m relative to the body in one "
                           f"step, more than its size {_fmt(self.body_size[b])} m")

    def _policy(self, kind, policy, message, frame):
        if policy == "ignore":
            return
        if policy == "raise":
            raise Diverged(message)
        if not self.warned[kind]:
            self.warned[kind] = True
            how = "" if kind == "energy" else f"; on_{kind}='raise' makes this an error"
            warnings.warn(f"{message} at frame {frame} of the {self.method} run (further occurrences are counted in sim.stats, not "
                          f"warned{how})", SimulationWarning, stacklevel=4)

    # -------------------------------------------------------------- checkpoint
    def state_dict(self):
        return {"energy": self.energy, "in_play": self.in_play, "warned_inverted": self.warned["inverted"],
                "warned_nonconvergence": self.warned["nonconvergence"], "warned_energy": self.warned["energy"]}

    def load_state_dict(self, state):
        self.energy = None if state["energy"] is None else real(state["energy"], "energy")
        self.in_play = real(state["in_play"], "in_play", low=0.0)
        self.warned = {"inverted": flag(state["warned_inverted"], "warned_inverted"),
                       "nonconvergence": flag(state["warned_nonconvergence"], "warned_nonconvergence"),
                       "energy": flag(state.get("warned_energy", False), "warned_energy")}
