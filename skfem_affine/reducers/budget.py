r"""The trade in the user's terms: an error budget, a time budget, and never slower than full space.

Three small controllers a reducer consults once per frame. None of them knows what a body or
a threshold means: a reducer hands them measurements (a velocity error, phase times, the
frame's wall time) and reads back a scale for its threshold, a forced reduced fraction, and
whether to solve the frame in full space. Their state is plain numbers, so a checkpoint can
save it (``vars(controller)``).

**Error budget** (:class:`ErrorBudget`). The user states the largest vertex distance to the
full-space run they accept, in one of three units (``relative_to``, :data:`ERROR_UNITS`):

* ``"response"`` (the default): relative to the response R, the largest displacement of a vertex
  from the rest pose so far in the run (a beam's tip deflection, a body's fall). Online the reducer
  knows only its own run: R is the running maximum over the frames stepped of
  :math:`\max_i \|x_i - X_i\|`, floored at :data:`RESPONSE_FLOOR` times the scene size so that a
  scene at rest does not divide by zero. R only grows, so the estimate is measured against the
  response so far, never against a larger one to come: the run's final amplitude (what the
  reports divide by) gives a smaller relative error. When R grows by a factor r, so does the
  threshold (the velocity error allowed grows with R): a motion that starts from rest is not held
  to the small response of its first frames;
* ``"size"``: relative to the scene size L (the diagonal of the rest bounding box);
* ``"metre"``: absolute, in metres.

What is estimated:

* the *local* error of a reduced frame, the largest vertex norm of
  :math:`\delta = \Delta v_{red} - \Delta v_{full}` (m/s), where both solve the same frame
  from the same state. On *shadow* frames the reducer also solves the full system
  :math:`A\,\Delta v = b` and measures :math:`\delta` exactly; on the other frames it is
  estimated from the full-space residual :math:`r = b - A\,\Delta v_{red}` by one
  preconditioned CG step on :math:`A\,e = r` (the oracle's), scaled by a calibration factor
  that the shadow frames keep up to date (:meth:`ErrorBudget.local`);
* the *global* position error, accumulated as

  .. math:: D_{t+1} = \rho\,D_t + W\,h\,\|\delta_t\|_\infty,
            \qquad \rho = e^{-h/T}, \qquad E_t = D_t / U_t,

  a velocity error moving the vertices by h delta in its frame, forgotten over the memory time T
  (an error in an oscillating scene comes back rather than growing without bound). The frames
  after it carry a velocity error on: it grows to G h delta (the *amplification*), and W, the
  *carry*, is how much of that it keeps over T. Both are measured on shadow frames by following
  the measured delta through the frame's linearized step (:func:`kick_response`): W = 1 where
  elastic forces turn the error back within a few frames, several where it keeps drifting
  (a soft, slow or free scene). Shadow frames return the full
  solution, so they add no error. D is in metres; U_t is the unit of the budget (R_t, L or 1 m).
  A reduced frame whose estimated G h ||delta|| / U alone is over a quarter of the budget, or
  that would take E over the budget, is solved again in full space (:meth:`ErrorBudget.breaks`).

The controller keeps the *steady-state* contribution of the current local error,
S = T W ||delta|| / U (what E would settle at), at ``safety`` times the budget: each reduced frame
the threshold is multiplied by (goal / S)^(1/2), clipped to [``shrink``, ``grow``]; when the
accumulated E itself is over the goal it shrinks by at least ``shrink_over``. How well the
estimate follows the measured error is in ``docs/budget.md``.

**Time budget** (:class:`TimeBudget`): seconds per frame. After each frame the forced reduced
fraction (resource limiting, paper sec. 3.5) rises in proportion to how far the frame came
near the budget, and falls slowly while frames are well under, so that as many elements stay
elastic as the budget allows with a margin for the scatter of frame times. A frame solved in
full space costs a full solve whatever the fraction, so under a time budget the reducer takes
a shadow frame only when it fits (:meth:`TimeBudget.fits`). The frame's wall time is what
``Simulation.step`` measured (:meth:`Reducer.end_frame`), so that tests can feed it any clock.

**Never slower** (:class:`PaysOff`): the reducer hands it the costs of reduced frames and of
full-space ones (the affine reducers: the CPU time of whole frames, which load from other
processes does not stretch as it stretches their wall time; the subspace reducer: Newton
steps); when the reduced frames, shadows included, cost more than a full one, or keep nearly
every DOF, it solves the next frames in full space, and probes reduction again after
``probe_every`` frames (doubling while probes keep failing). A probe is a shadow frame: it
returns the full solution, so a run that never reduces equals the full-space run. A probe that
reduced is judged by the reduced frames after it, a *trial* (:meth:`PaysOff.await_trial`): a
shadow frame solves its contact in full space, which a reduced frame does not. With
``confirm``, a full-space frame solved right after the reduced frames that seemed too costly
decides every fall-back: the two are measured a frame apart, under the same load from elsewhere.
"""
import math
import warnings

import numpy as np

from skfem_affine.checks import positive, real
from skfem_affine.monitor import SimulationWarning

#: The error budget of a reducer given no threshold: 1 % of the response.
DEFAULT_TARGET_ERROR = 0.01
#: What an error budget is relative to: the response (largest displacement from rest), the scene
#: size, or a metre (absolute).
ERROR_UNITS = ("response", "size", "metre")
#: The default unit of an error budget.
DEFAULT_RELATIVE_TO = "response"
#: The response an error budget measures against is at least this fraction of the scene size.
RESPONSE_FLOOR = 1e-3
#: A reduced frame whose own estimated position error (G h ||delta|| / U) exceeds this fraction of
#: the budget is solved again in full space (:meth:`ErrorBudget.breaks`).
KICK = 0.25
#: While a run falls back to full space, the threshold rises by ``grow`` per frame up to this factor
#: over its value at the fall-back (:meth:`ErrorBudget.idle`).
IDLE_RISE = 16.0

#: The shadow frames whose measured (G, W) :meth:`ErrorBudget.propagated` keeps.
RECENT = 4
#: Frames a shadow frame follows its measured velocity error through the linearized step
#: (:func:`kick_response`); it stops earlier once the velocity error has died out or turned back.
PROPAGATION_STEPS = 24


class BudgetWarning(SimulationWarning):
    """A run's estimated error passed its error budget (:meth:`ErrorBudget.warn_passed`): the frames
    after it are not within the promise."""


def error_unit(relative_to):
    """``relative_to`` checked: one of :data:`ERROR_UNITS` (None: the default), or a ValueError naming it."""
    if relative_to is None:
        return DEFAULT_RELATIVE_TO
    if not isinstance(relative_to, str) or relative_to not in ERROR_UNITS:
        raise ValueError(f"relative_to must be one of {', '.join(map(repr, ERROR_UNITS))} (the response: the "
                         f"largest displacement from rest; the scene size; or metres), got {relative_to!r}")
    return relative_to


def target_error(value, relative_to):
    """A budget checked for its unit: in (0, 1] relative to the response or the size, > 0 in metres."""
    if relative_to == "metre":
        return real(value, "target_error", low=0.0, include_low=False)
    return real(value, "target_error", low=0.0, high=1.0, include_low=False)


def largest_displacement(x, rest):
    """max_i ||x_i - X_i|| of positions ``x`` from ``rest`` (flat 3n or (n, 3) arrays; ``x`` may hold
    several frames, (frames, n, 3)), in metres."""
    rest = np.asarray(rest, float).reshape(-1, 3)
    if not rest.size:
        return 0.0
    d = np.asarray(x, float).reshape(-1, rest.shape[0], 3) - rest
    return float(np.sqrt(np.max(np.einsum("...j,...j->...", d, d))))


def vertex_max_norm(free_values, free, n):
    """Largest vertex norm of a free-DOF vector (fixed DOFs count as zero)."""
    full = np.zeros(3 * n)
    full[free] = free_values
    return float(np.sqrt(np.max(np.einsum("ij,ij->i", full.reshape(n, 3), full.reshape(n, 3))))) if n else 0.0


def kick_response(solve, M, H, delta, dt, free, n, memory, steps=PROPAGATION_STEPS):
    r"""How far a velocity error keeps moving the vertices after the frame that made it.

    A reduced frame's velocity error delta (m/s, free DOFs) moves the vertices by h delta in its
    frame; the frames after it carry it on. Linearizing backward Euler about the run, a position
    error e_x and velocity error e_v become, one frame later (no new error),

    .. math:: A\,e_v' = M e_v - h H e_x, \qquad e_x' = e_x + h e_v',

    with the frame's A = c_M M + c_K H (damping included). Starting from e_v = delta,
    e_x = h delta, the response is g_k = ||e_x^(k)||_inf / (h ||delta||_inf), g_0 = 1, followed
    for at most ``steps`` frames: until e_v is under 5 % of delta (the error then stays where it
    is) or e_x has come back to half its peak (elastic forces turn it back: an oscillation).

    Returns two numbers, both >= 1:

    * G, the peak of g: the position error one frame's velocity error grows to, in units of what
      it adds in its own frame (a stiff scene about 1-3, a soft or slow one several);
    * W, g averaged over the memory time T with the estimate's own forgetting weights,
      W = (1 - rho) sum_k rho^k g_k (rho = exp(-h / T)), g taken on at its last value past the
      frames followed, or as 0 once it has turned back: what the estimate D must add per frame,
      in units of h ||delta||, to carry the error as long as it lasts. An error that elastic
      forces turn back within a few frames gives W = 1 (the estimate's memory T covers it); one
      that keeps drifting gives W near G.

    Parameters
    ----------
    solve : callable
        r -> A^-1 r with the frame's factorised full-space A (free DOFs).
    M, H : sparse matrices
        Mass and stiffness on the free DOFs.
    delta : (n_free,) array
        The measured velocity error of a shadow frame.
    dt : float
        The time step h (s).
    free : int array
        The free DOFs (of the 3 n).
    n : int
        The number of vertices.
    memory : float
        The estimate's memory time T (s).
    steps : int
        The most frames followed.

    Returns
    -------
    (float, float)
        (G, W); (1, 1) for a zero ``delta``.
    """
    h = float(dt)
    first = vertex_max_norm(delta, free, n)
    if not first > 0:
        return 1.0, 1.0
    rho = math.exp(-h / float(memory))
    ev = np.asarray(delta, float)
    ex = h * ev
    peak = now = h * first
    area, weight, tail = now, 1.0, True
    for _ in range(int(steps)):
        ev = np.asarray(solve(M @ ev - h * (H @ ex)), float).ravel()
        ex = ex + h * ev
        now = vertex_max_norm(ex, free, n)
        weight *= rho
        area += weight * now
        peak = max(peak, now)
        if now < 0.5 * peak:
            tail = False  # turned back: an oscillation, which the memory time covers
            break
        if vertex_max_norm(ev, free, n) < 0.05 * first:
            break  # the velocity error has died out: the position error stays
    if tail:
        area += now * weight * rho / (1.0 - rho)
    return peak / (h * first), max(1.0, (1.0 - rho) * area / (h * first))


def controllers_state(owner, names):
    """{name: {attribute: value}} of the controllers ``owner`` holds under ``names`` (checkpoints); an
    attribute whose name starts with ``_`` is a setting given to the constructor, not state."""
    return {name: {k: v for k, v in vars(obj).items() if not k.startswith("_")}
            for name in names if (obj := getattr(owner, name, None)) is not None}


def restore_controllers(owner, state, own):
    """Set what :func:`controllers_state` returned; the entry named ``own`` holds ``owner``'s own attributes."""
    for name, values in state.items():
        target = owner if name == own else getattr(owner, name, None)
        if target is None:
            raise ValueError(f"this reducer has no controller {name!r} to restore")
        for key, value in values.items():
            setattr(target, key, value)


class ErrorBudget:
    """Estimator of the distance error and multiplicative controller of one threshold.

    Parameters
    ----------
    target : float
        The accepted max vertex distance to the full-space run, in the unit ``relative_to``.
    tau : float
        The threshold to start from (the reducer's unit; small: the first frames reduce little).
    memory : float
        T (s): how long a velocity error keeps moving the vertices (module docstring).
    safety : float
        The controller keeps the estimate at ``safety * target``.
    tau_min, tau_max : float
        Bounds of the threshold.
    shrink, grow : float
        Bounds of the threshold's factor per frame.
    shrink_over : float
        The largest factor while the estimate is over the goal.
    ramp_grow : float, optional
        The factor per frame (default ``grow``) while the threshold rises from its small start and
        the error has not shown yet (:attr:`ramping`): the first frames, which keep most DOFs
        elastic, cost more than a full solve.
    relative_to : {"response", "size", "metre"}
        The unit of ``target`` and of the estimate (module docstring).

    Attributes
    ----------
    drift : float
        D, the accumulated position error estimate in metres.
    estimate : float
        E = D / U, the estimate in the budget's unit.
    unit : float
        U (m): the response so far (floored), the scene size, or 1.
    response : float
        The largest displacement from rest seen so far (m), with ``relative_to="response"``.
    calibration : float
        Measured / proxy local error of the latest shadow frames (>= 1 is typical: one CG step
        underestimates the smooth part of the error).
    local_rate : float
        The latest local error ||delta|| / U (1/s).
    amplification : float
        G >= 1: the position error a frame's velocity error grows to in the frames after it, in
        units of h ||delta|| (:func:`kick_response`, measured on shadow frames; the larger of the
        newest and a slowly forgotten history, as the calibration, which the first reading does
        not seed). :meth:`breaks` counts a frame's position error as G h ||delta||.
    carry : float
        W >= 1: how much of that the error keeps over the memory time (:func:`kick_response`,
        the mean of the latest :data:`RECENT` shadow frames'). A reduced frame adds W h ||delta|| to D.
    ramping : bool
        The threshold has only risen, at ``ramp_grow``, since the start.
    idle_from : float
        The threshold when the run last fell back to full space (0: it reduces), :meth:`idle`.
    """

    def __init__(self, target, tau, memory=0.5, safety=0.5, tau_min=1e-8, tau_max=1e3,
                 shrink=0.5, grow=2.0, shrink_over=0.7, ramp_grow=None, relative_to="size"):
        self._relative_to = error_unit(relative_to)
        self.target = target_error(target, self._relative_to)
        self.tau = positive(tau, "tau")
        self.memory = positive(memory, "memory")
        self.safety = real(safety, "safety", low=0.0, high=1.0, include_low=False)
        self.tau_min, self.tau_max = float(tau_min), float(tau_max)
        self.shrink, self.grow, self.shrink_over = float(shrink), float(grow), float(shrink_over)
        self.ramp_grow = self.grow if ramp_grow is None else float(ramp_grow)
        self.ramping = True  # tau rises by ramp_grow per frame from the small start until the error shows
        self.idle_from = 0.0  # tau at the fall-back to full space (0: reducing)
        self.drift = 0.0
        self.estimate = 0.0
        self.unit = 0.0  # set by scale() (or advance(): the scene size)
        self.response = 0.0
        self.calibration = 1.0
        self.calibrated = 0  # shadow frames that measured a nonzero proxy
        self.local_rate = 0.0
        self.amplification = 1.0
        self.carry = 1.0
        self.readings = []  # W of the latest shadow frames, newest last, at most RECENT
        self.propagations = 0  # shadow frames that measured (G, W)
        self.stable = False  # the latest shadow frame confirmed the calibration
        self.warned = False  # the estimate passed the budget and the run said so (:meth:`warn_passed`)

    @property
    def goal(self):
        return self.safety * self.target

    def local(self, proxy, measured=None):
        """The local velocity error (m/s) of this frame; calibrates the proxy when ``measured``.

        Parameters
        ----------
        proxy : float
            ||e||_inf of one preconditioned CG step on A e = b - A dv_red.
        measured : float, optional
            ||dv_red - dv_full||_inf of a shadow frame.
        """
        if measured is None:
            return self.calibration * proxy
        self.stable = False
        if proxy > 0 and measured > 0:
            ratio = measured / proxy
            self.stable = bool(self.calibrated) and 0.7 <= ratio / self.calibration <= 1.4
            # the larger of the newest ratio and a slowly forgotten history: a safe side estimate
            self.calibration = ratio if not self.calibrated else max(ratio, math.sqrt(self.calibration * ratio))
            self.calibrated += 1
        return measured

    def propagated(self, peak, carry):
        """Take a shadow frame's measured :func:`kick_response` (G, W); returns the new (G, W).

        G, which guards single frames (:meth:`breaks`), keeps a slowly forgotten history, as the
        calibration; W, which sets the level of every frame's estimate, is the mean of the latest
        :data:`RECENT` readings (one frame's reading scatters). The first reading holds only until
        the next one replaces it: the response of a run's first frame (a start from rest) does
        not hold its thresholds down for the frames after."""
        peak, carry = max(float(peak), 1.0), max(float(carry), 1.0)
        restart = self.propagations < 2  # the first reading, or the second, which replaces it
        self.amplification = peak if restart else max(peak, math.sqrt(self.amplification * peak))
        self.readings = [carry] if restart else (list(self.readings) + [carry])[-RECENT:]
        self.propagations += 1
        self.carry = sum(self.readings) / len(self.readings)
        return self.amplification, self.carry

    @property
    def relative_to(self):
        """The unit of the target and the estimate: "response", "size" or "metre"."""
        return self._relative_to

    def scale(self, size, displacement=None):
        """Set the unit U (m) of the coming frame from the scene ``size`` and, for a budget relative to
        the response, the frame's largest ``displacement`` from rest (the running maximum is kept)."""
        if self.relative_to == "size":
            self.unit = float(size)
        elif self.relative_to == "metre":
            self.unit = 1.0
        else:
            if displacement is not None:
                self.response = max(self.response, float(displacement))
            unit = max(self.response, RESPONSE_FLOOR * float(size))
            if self.unit > 0 and unit > self.unit:
                # the velocity error allowed grows with the response, and the threshold with it: a
                # motion that starts from rest is not held to the small response of its first frames
                self.tau = min(self.tau * unit / self.unit, self.tau_max)
            self.unit = unit
        return self.unit

    def advance(self, delta, dt, size, introduced=True):
        """D <- rho D + W h delta (``introduced=False``: the frame returned the full solution); E = D / U.

        ``size`` is the scene size; the unit is the one :meth:`scale` set (the scene size if never set).
        """
        if self.relative_to != "response" or not self.unit > 0:
            self.scale(size)
        rho = math.exp(-dt / self.memory)
        self.local_rate = delta / self.unit
        self.drift = rho * self.drift + (self.carry * dt * delta if introduced else 0.0)
        self.estimate = self.drift / self.unit
        return self.estimate

    def breaks(self, delta, dt):
        """Whether a reduced frame of local error ``delta`` (m/s) would break the promise: its own
        position error G h delta / U is over :data:`KICK` budgets, or it would take the estimate over
        the budget. Such a frame is solved again in full space (a shadow frame: it adds no error and
        calibrates the estimate). The controller keeps the estimate near half the budget, where a
        frame adds about h / T of it, so only a sudden jump of the error (a threshold grown while
        nothing could reduce, then everything does) is refused."""
        if not self.unit > 0:
            return False
        step = dt * float(delta) / self.unit
        kick = self.amplification * step
        # the estimate after the frame adds W h delta (advance); G, a slow history, may be under the latest W
        after = math.exp(-dt / self.memory) * self.estimate + max(kick, self.carry * step)
        return kick > KICK * self.target or after > self.target

    def warn_passed(self, frame):
        """After a frame: a :class:`BudgetWarning` naming ``frame`` the first time the estimate is over
        the budget (once per run). Reduced frames that would pass it are refused (:meth:`breaks`), so
        the estimate passes it only through error it cannot take back: error that earlier frames set
        moving and that keeps growing after them, or frames a time budget kept reduced."""
        if self.warned or not self.estimate > self.target:
            return False
        self.warned = True
        warnings.warn(BudgetWarning(
            f"frame {frame}: the estimated error {self.estimate:.3g} is over the error budget {self.target:.3g} "
            f"(relative to the {self.relative_to}, unit {self.unit:.3g} m); the frames from here on are not "
            f"within the budget"), stacklevel=3)
        return True

    def decay(self, dt):
        """A frame solved in full space: D only decays."""
        self.drift *= math.exp(-dt / self.memory)
        self.estimate = self.drift / self.unit if self.unit > 0 else 0.0
        return self.estimate

    def idle(self):
        """A frame the fall-back solved in full space: the threshold rises by ``grow``, up to
        :data:`IDLE_RISE` times its value at the fall-back; returns the new tau.

        A run falls back where reduction does not pay, often while its bodies settle and the
        budget has shrunk the threshold; without this, the probe after the bodies came to rest
        would run at that small threshold, reduce little, fail, and keep the run in full space for
        twice as long. A probe is a shadow frame, so a threshold too large for it adds no error:
        the probe measures the error and the threshold shrinks from there; the trial after it is
        refused (solved in full space) if its estimate breaks the budget."""
        if not self.idle_from:
            self.idle_from = self.tau
        self.tau = min(self.tau * self.grow, self.idle_from * IDLE_RISE, self.tau_max)
        return self.tau

    @property
    def steady(self):
        """S = T W ||delta|| / U: where the estimate would settle at the latest frame's local error."""
        return self.memory * self.carry * self.local_rate

    def adapt(self, saturated=False):
        """Scale the threshold from the latest local error and the estimate; returns the new tau.

        ``saturated``: the frame reduced every element it may, so a larger threshold would
        gain nothing and only let the next event (an impact) find everything reduced; tau
        does not grow then.
        """
        self.idle_from = 0.0
        steady = self.steady
        upper = self.ramp_grow if self.ramping else self.grow
        ratio = self.goal / steady if steady > 0 else upper ** 2
        factor = min(max(math.sqrt(ratio), self.shrink), upper)
        if saturated:
            factor = min(factor, 1.0)
        if self.estimate > self.goal:
            factor = min(factor, self.shrink_over)
        self.ramping = self.ramping and factor >= upper
        self.tau = min(max(self.tau * factor, self.tau_min), self.tau_max)
        return self.tau


class ShadowClock:
    """Every ``every``-th reduced frame is a shadow frame (also solved in full space); the ``first`` ones are.

    Parameters
    ----------
    every : int
        Reduced frames per shadow frame (>= 1).
    """

    def __init__(self, every=10, first=2, longest=4):
        self.every = int(every)
        if self.every < 1:
            raise ValueError(f"shadow_every must be >= 1, got {every}")
        self.shortest, self.longest = self.every, self.every * int(longest)
        self.since = self.every
        self.first = int(first)  # the first frames are all shadows: the first full solve pays the analysis

    def settled(self, stable):
        """After a shadow frame: a calibration that held (``stable``) doubles the period, up to
        ``longest`` times ``every``; one that moved brings it back to ``every``."""
        self.every = min(2 * self.every, self.longest) if stable else self.shortest

    def due(self):
        """Whether the coming reduced frame is a shadow frame (counts it)."""
        if self.first > 0:
            self.first -= 1
            self.since = 1
            return True
        if self.since >= self.every:
            self.since = 1
            return True
        self.since += 1
        return False


class TimeBudget:
    """Controller of the forced reduced fraction from measured frame wall times.

    Frame times on a shared machine scatter by tens of percent from frame to frame, so the
    controller keeps them in a band under the budget rather than at it, and its steps are
    asymmetric: a miss raises the forced fraction by at least ``miss_step``, a frame under
    ``low`` budgets lowers it by ``fall``. Where the fraction settles, misses times their rise
    balance the falls, so at most ``fall / miss_step`` of the frames miss (5 %) whatever
    the scatter, as long as forcing more elements into bodies can still shorten a frame.

    Parameters
    ----------
    budget : float
        Seconds per frame.
    fraction : float
        The forced fraction to start from.
    gain : float
        A frame over ``high`` budgets raises the fraction by ``gain * (wall / budget - high)``,
        at least ``step``, at least ``miss_step`` when over the budget.
    step, miss_step : float
        Smallest rises of the fraction.
    fall : float
        The fall per frame under ``low`` budgets.
    low, high : float
        The band, in budgets, the frames are kept in.
    """

    def __init__(self, budget, fraction=0.0, gain=0.5, step=0.02, miss_step=0.1, fall=0.005, low=0.7, high=0.85):
        self.budget = positive(budget, "time_budget")
        self.fraction = real(fraction, "min_fraction", low=0.0, high=1.0)
        self.floor = self.fraction
        self.gain, self.step, self.miss_step, self.fall = float(gain), float(step), float(miss_step), float(fall)
        self.low, self.high = float(low), float(high)
        self.frames = 0
        self.misses = 0
        self.wall = 0.0       # the latest steered frame's wall time (s)
        self.full_cost = 0.0  # the latest full solve's time (s), set by the reducer

    def observe(self, wall, steered=True):
        """Take one frame's wall time (s); returns whether it missed the budget.

        ``steered=False``: the forced fraction did not set this frame's time (a frame solved in
        full space, or a shadow frame); it counts, but does not move the fraction.
        """
        self.frames += 1
        ratio = float(wall) / self.budget
        miss = ratio > 1.0
        self.misses += int(miss)
        if not steered:
            return miss
        self.wall = float(wall)
        if ratio > self.high:
            least = self.miss_step if miss else self.step
            self.fraction = min(1.0, self.fraction + max(least, self.gain * (ratio - self.high)))
        elif ratio < self.low:
            self.fraction = max(self.floor, self.fraction - self.fall)
        return miss

    def fits(self, extra):
        """Whether a frame ``extra`` seconds longer than the latest steered one stays in budget."""
        return self.wall + float(extra) <= self.budget


class PaysOff:
    """Whether reduction pays, from measured costs of reduced frames and full solves.

    Parameters
    ----------
    probe_every : int
        Full-space frames before the first probe of reduction; doubles after each failed probe,
        up to ``probe_max``.
    keep_dofs : float
        Reduced frames that keep at least this fraction of the DOFs, ``patience`` in a row, do
        not pay whatever their time.
    patience : int
        Reduced frames measured before reduction may be judged (thresholds chosen by an error
        budget start small and grow over the first frames).
    margin : float
        Return to reduction only when a probe costs at most ``1 - margin`` of a full solve.
    smoothing : float
        Weight of the newest measurement in the running costs.
    window : int, optional
        When given, a running cost is the least of the latest ``window`` measurements instead: load
        from elsewhere only adds time, so the least of a few frames is their cost without it.
    confirm : bool
        Reduced frames judged too costly do not send the run to full space at once: the next frame
        is solved in full space (:meth:`plan` says ``"confirm"``), its cost replaces the running
        full cost, and only when the reduced frames still cost more does the run fall back.
        Reduced frames are measured every frame and full ones only now and then, so without it a
        burst of load during reduced frames is compared with full frames measured while the
        machine was quiet.
    trial_frames : int
        Reduced frames after a probe that judge it (:meth:`await_trial`), their least cost with
        ``window``: the first frame after a fall-back pays one-off costs (analyses of new patterns).
    """

    def __init__(self, probe_every=20, probe_max=160, keep_dofs=0.95, patience=5, margin=0.05, smoothing=0.3,
                 window=None, confirm=False, trial_frames=1):
        self.probe_every, self.probe_max, self.patience = int(probe_every), int(probe_max), int(patience)
        self.keep_dofs, self.margin, self.smoothing = float(keep_dofs), float(margin), float(smoothing)
        self.window = int(window or 0)  # 0: a moving average (plain numbers: checkpoints save them)
        self.confirm = bool(confirm)
        self.confirming = False  # the next frame is a full-space frame that confirms a fall-back (``confirm``)
        self.trial_frames = int(trial_frames)
        if self.trial_frames < 1:
            raise ValueError(f"trial_frames must be >= 1, got {trial_frames}")
        self.trial = 0  # reduced frames left that judge a probe (:meth:`await_trial`)
        self.full_recent, self.reduced_recent = [], []  # the latest measurements (with ``window``)
        self.full_cost = 0.0   # s per frame solved in full space (or per full solve: what the reducer measures)
        self.reduced_cost = 0.0  # s per reduced frame
        self.shadow_cost = 0.0   # s a shadow frame adds to a reduced frame (0: full_cost)
        self.full_samples = 0
        self.full_seen = 0     # full solves timed; the first (with the solver's symbolic analysis) is not a sample
        self.reduced_samples = 0
        self.dof_ratio = 0.0
        self.kept_all = 0      # reduced frames in a row that kept at least keep_dofs of the DOFs
        self.in_full = False
        self.wait = 0          # full-space frames left before the next probe
        self.period = self.probe_every

    def _mix(self, old, new, n):
        return new if n == 0 else (1 - self.smoothing) * old + self.smoothing * new

    def _running(self, recent, old, new, n, fresh=False):
        """The running cost after measurement ``new``: the least over the window, else a moving average."""
        if not self.window:
            return new if fresh else self._mix(old, new, n)
        if fresh:
            recent.clear()
        recent.append(float(new))
        del recent[:-self.window]
        return float(min(recent))

    def full_solved(self, seconds, fresh=False):
        """Record a full solve's (or full frame's) cost; ``fresh`` replaces the running cost (a probe)."""
        self.full_seen += 1
        if self.full_seen == 1:
            return
        self.full_cost = self._running(self.full_recent, self.full_cost, seconds, self.full_samples, fresh)
        self.full_samples += 1

    def shadow_added(self, seconds):
        """What a shadow frame's full solve added to its reduced frame (s), for the shadows' share."""
        self.shadow_cost = float(seconds) if not self.shadow_cost else self._mix(self.shadow_cost, seconds, 1)

    def reduced_solved(self, seconds, dof_ratio, fresh=False):
        """Record a reduced frame's cost. ``fresh`` (a probe after full-space frames) replaces the
        running cost instead of mixing into it: the frames before the fall-back ran with other
        thresholds (an error budget's start small and grow), and judging a probe by them would
        keep the run in full space."""
        self.reduced_cost = self._running(self.reduced_recent, self.reduced_cost, seconds, self.reduced_samples, fresh)
        self.reduced_samples += 1
        self.dof_ratio = float(dof_ratio)
        kept = self.dof_ratio >= self.keep_dofs
        self.kept_all = int(kept) if fresh else (self.kept_all + 1 if kept else 0)

    def overhead(self, shadow_every):
        """Per reduced frame, the shadow frames' share of what a shadow adds (a full solve)."""
        return (self.shadow_cost or self.full_cost) / max(shadow_every, 1)

    def pays(self, shadow_every=None, margin=0.0):
        """Whether the measured reduced frames (with their shadows) beat a full solve by ``margin``."""
        if self.kept_all >= self.patience or (self.kept_all and self.in_full):
            return False
        if not (self.full_samples and self.reduced_samples):
            return True
        extra = self.overhead(shadow_every) if shadow_every else 0.0
        return self.reduced_cost + extra <= (1.0 - margin) * self.full_cost

    def await_trial(self):
        """The probe just solved cannot be judged on its own wall time: the next ``trial_frames``
        frames, reduced (:meth:`plan` says ``"trial"``), are, by :meth:`decide` with ``probed=True``
        after the last (the reducer counts them down in :attr:`trial`).

        A probe is a shadow frame: its contact, if any, is solved through the full-space operator,
        so it costs what a full frame's contact costs, which on a resting pile is most of a full
        frame. Judged on it, a reduced frame whose contact costs a few of its bodies' DOFs looks
        as dear as a full one, and the run stays in full space."""
        self.trial = self.trial_frames

    def plan(self):
        """"full" (solve this frame in full space), "confirm" (a full-space frame that decides a
        fall-back, with ``confirm``), "probe" (a reduced frame with a shadow), "trial" (a reduced
        frame that judges the probe before it, :meth:`await_trial`) or "reduced"."""
        if self.confirming:
            return "confirm"
        if self.trial:
            return "trial"
        if not self.in_full:
            return "reduced"
        if self.wait > 0:
            self.wait -= 1
            return "full"
        return "probe"

    def decide(self, shadow_every=None, probed=False, confirmed=False, settled=True):
        """After a reduced frame, a probe or a confirming full frame: stay reduced, or go to full
        space until the next probe. ``settled=False`` (with ``probed``): the probe's frame made
        more error than the reducer's error budget allows for long, so its thresholds shrink and the
        frames after it would reduce less and cost more than it did: the probe fails, and when no
        trial frame was spent on it, the next one comes after ``probe_every`` frames (the wait
        does not double)."""
        warm = self.reduced_samples >= self.patience and self.full_samples >= 1
        if confirmed:  # reduced frames seemed too costly: a full frame measured beside them decides
            self.confirming = False
            if not self.pays(shadow_every):
                self.in_full, self.wait, self.period = True, self.probe_every, self.probe_every
        elif probed:
            tried, self.trial = self.trial > 0, 0
            if settled and self.pays(shadow_every, self.margin):
                self.in_full, self.period = False, self.probe_every
            elif not (settled or tried):  # the probe found bodies still settling: probe as soon again
                self.in_full, self.wait = True, self.probe_every
            else:
                self.in_full = True
                self.period = min(2 * self.period, self.probe_max)
                self.wait = self.period
        elif (warm or self.kept_all >= self.patience) and not self.pays(shadow_every):
            if self.confirm and self.kept_all < self.patience:
                self.confirming = True
            else:
                self.in_full, self.wait, self.period = True, self.probe_every, self.probe_every
        return self.in_full
