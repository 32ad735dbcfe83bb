"""Options of the gradient loop (:class:`~plush_opt.control.gradient.Controller`).

:class:`ControlOptions` holds the loop's tuning, each field with its
reason, and hands the shared policy (:mod:`.policy`) its rules: the stop
rules, the look-further rule and the damping schedule.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from ..solve.equilibrium import EquilibriumOptions
from .kink import KinkRule
from .policy import LEVENBERG_MARQUARDT, Damping, ProbeRule, StopRules

DIRECTIONS = ("gauss-newton", "gradient")
BOUNDS = ("reparam", "clip")
TRIALS_IN_BLEND = ("auto", "mapped", "predicted")


@dataclass(frozen=True)
class ControlOptions:
    """Options of the gradient loop.

    Attributes
    ----------
    bounds : 'reparam' (c = f(xi), the default) or 'clip' (step on c, then
        clip to the bounds: the simple baseline).
    direction : 'gauss-newton' (Levenberg-Marquardt on the target
        residuals, uses dx/dc) or 'gradient' (steepest descent, one adjoint
        solve per iterate, Barzilai-Borwein step length).
    max_iterations : accepted iterates at most.
    max_time : seconds at most (None: no limit).
    ftol : stop when the relative decrease of O stays below ftol for
        ``patience`` consecutive iterates.
    gtol : stop when the projected gradient |P dO/dc| times the mean bound
        range is below gtol * max(O, floor), floor as below.
    objective_floor : O below this times the mean target weight (length^2)
        counts as targets reached: relative to the weights, so that tiny
        weights do not make a far target look reached.
    patience : see ftol.
    blend : width of the reparametrisation's blend zone, as a fraction
        of each winch's range.
    slope_floor : smallest f' used in the search direction (so a winch on
        a bound can come back).
    max_step : largest change of one winch's xi per iterate, as a fraction
        of its range (keeps the loop in the basin it starts in and every
        streamed iterate a modest move for the robot).
    max_backtracks : line-search trials per iterate.
    initial_damping : Levenberg-Marquardt damping at the start and after
        every restart, relative to the largest curvature of J^T J (small:
        the first step is nearly Gauss-Newton).
    min_damping : the damping never falls below this (keeps J^T J + damping
        well conditioned when a column vanishes).
    damping_decrease, damping_increase : the damping is divided by the first
        after an accepted step and multiplied by the second after a rejected
        trial (the usual asymmetric Levenberg-Marquardt schedule;
        :class:`~plush_opt.control.policy.Damping`, shared with the reduced
        bilevel search).
    initial_gradient_step : first steepest-descent step, as a fraction of the
        mean bound range per unit of gradient norm (later steps are
        Barzilai-Borwein).
    stuck_fraction : a loop whose O is still above this fraction of its O
        at the start of the current targets is "stuck near its start", which
        enables the bound probes of a restart (a loop that has made most of
        its progress is at a real optimum; probing would only cost time).
    probe_fractions : how far a restart probes inwards from a bound, as
        fractions of the range.
    probe_gain : a probe is taken only if it lowers O by this relative amount
        (a real improvement, not round-off).
    trial_newton : Newton iterations a line-search trial's equilibrium
        may take, its sub-steps along the branch included (the starting
        pose and restarts: ``equilibrium``'s own limit). A trial stays on
        the current iterate's stable branch (plush_opt/solve/branch.py): past a
        limit point it fails in a few iterations, and the step is cut
        instead of followed across a snap-through (docs/control.md).
    start_continuation : where the starting equilibrium fails from its
        start pose, it is sought by continuation in the contraction in this
        many steps (``EquilibriumOptions.continuation``) before the loop
        gives up; 0: not. A history-free plant only: with history (friction)
        the path is the physics and is followed anyway.
    trial_in_blend : where a step moves a winch inside the
        reparametrisation's blend zone: 'mapped' (the trial is f(xi + dxi),
        the plain map) or 'predicted' (the trial is the contraction the
        step's linear model predicts, f(xi) + f'(xi) dxi with f' floored at
        ``slope_floor``, kept within the bounds; xi is f's inverse there);
        'auto' (default): 'predicted' on a path-dependent plant, 'mapped'
        elsewhere. Near a bound the floor scales a winch's column down, so
        f(xi + dxi) moves it up to 1 / ``slope_floor`` times what the model
        predicted; on a smooth plant the line search shortens such a trial,
        but with friction it crosses stick/slip changes the sensitivities do
        not see, and the damping the rejections raise bends every winch's
        step (docs/control.md, "With friction at via points").
    kink_steps : on a path-dependent plant, where the loop would stop
        (stationary, stalled or a failed line search), every free winch
        alone is moved by each of these fractions of its range, largest
        first, in both directions, as certified trials: a move that lowers
        O is taken, and where none does the stop is a nonsmooth stationary
        point (:mod:`.kink`); empty: no test. From a thousandth of the
        range (the sensitivities' own scale of validity at a kink) down to
        a millionth (a slope measured by a move above the solver's
        residual tolerance).
    kink_doublings : a move the kink test found is doubled while O keeps
        falling, at most this many times (within ``max_step``).
    equilibrium : options of every equilibrium solve.
    """

    bounds: str = "reparam"
    direction: str = "gauss-newton"
    max_iterations: int = 100
    max_time: float | None = None
    ftol: float = 1e-9
    gtol: float = 1e-7
    objective_floor: float = 1e-14
    patience: int = 2
    blend: float = 0.02
    slope_floor: float = 0.1
    max_step: float = 0.2
    max_backtracks: int = 12
    initial_damping: float = LEVENBERG_MARQUARDT.initial
    min_damping: float = LEVENBERG_MARQUARDT.minimum
    damping_decrease: float = LEVENBERG_MARQUARDT.decrease
    damping_increase: float = LEVENBERG_MARQUARDT.increase
    initial_gradient_step: float = 0.1
    stuck_fraction: float = 0.5
    probe_fractions: tuple[float, ...] = (0.05, 0.15, 0.4)
    probe_gain: float = 1e-3
    trial_newton: int = 100
    start_continuation: int = 4
    trial_in_blend: str = "auto"
    kink_steps: tuple[float, ...] = (1e-3, 1e-4, 1e-5, 1e-6)
    kink_doublings: int = 8
    equilibrium: EquilibriumOptions = field(
        default_factory=lambda: EquilibriumOptions(eigenvalue=False))

    def __post_init__(self):
        if self.bounds not in BOUNDS:
            raise ValueError(f"bounds: expected one of {BOUNDS}, got {self.bounds!r}")
        if self.direction not in DIRECTIONS:
            raise ValueError(f"direction: expected one of {DIRECTIONS}, got {self.direction!r}")
        if self.max_iterations < 0:
            raise ValueError(f"max_iterations: expected >= 0, got {self.max_iterations!r}")
        if not 0 < self.min_damping <= self.initial_damping:
            raise ValueError("damping: expected 0 < min_damping <= initial_damping, got "
                             f"{self.min_damping!r}, {self.initial_damping!r}")
        if not (self.damping_decrease > 1 and self.damping_increase > 1):
            raise ValueError("damping_decrease, damping_increase: expected > 1, got "
                             f"{self.damping_decrease!r}, {self.damping_increase!r}")
        if not all(0 < f < 1 for f in self.probe_fractions):
            raise ValueError(f"probe_fractions: expected fractions in (0, 1), got {self.probe_fractions!r}")
        if not (isinstance(self.trial_newton, int) and self.trial_newton >= 1):
            raise ValueError(f"trial_newton: expected an integer >= 1, got {self.trial_newton!r}")
        if not (isinstance(self.start_continuation, int) and self.start_continuation >= 0):
            raise ValueError(f"start_continuation: expected an integer >= 0, got {self.start_continuation!r}")
        if self.trial_in_blend not in TRIALS_IN_BLEND:
            raise ValueError(f"trial_in_blend: expected one of {TRIALS_IN_BLEND}, got {self.trial_in_blend!r}")
        if not all(0 < h < 1 for h in self.kink_steps):
            raise ValueError(f"kink_steps: expected fractions in (0, 1), got {self.kink_steps!r}")
        if not (isinstance(self.kink_doublings, int) and self.kink_doublings >= 0):
            raise ValueError(f"kink_doublings: expected an integer >= 0, got {self.kink_doublings!r}")
        if not 0 < self.slope_floor <= 1:
            raise ValueError(f"slope_floor: expected 0 < slope_floor <= 1, got {self.slope_floor!r}")

    @property
    def damping(self) -> Damping:
        """The Levenberg-Marquardt schedule of these options."""
        return Damping(self.initial_damping, self.min_damping, self.damping_decrease,
                       self.damping_increase)

    @property
    def probe(self) -> ProbeRule:
        """The look-further rule of these options (each winch once per set of targets)."""
        return ProbeRule(self.stuck_fraction, tuple(self.probe_fractions), self.probe_gain, retry=False)

    @property
    def kink(self) -> KinkRule:
        """The test at a kink of these options (:mod:`.kink`)."""
        return KinkRule(tuple(sorted(self.kink_steps, reverse=True)), self.ftol, self.kink_doublings,
                        self.max_step)

    def predicted_trials(self, path_dependent: bool) -> bool:
        """Whether trials are the step's linear prediction (``trial_in_blend``)
        on a plant that is (or is not) ``path_dependent``."""
        return self.trial_in_blend == "predicted" or (self.trial_in_blend == "auto" and path_dependent)

    def stop_rules(self, floor: float) -> StopRules:
        """The stop rules of these options with the objective floor ``floor`` (length^2)."""
        return StopRules(self.gtol, self.ftol, self.patience, floor, self.max_iterations, self.max_time)
