"""The accept/reject step shared by every move, the records of what the moves did (:class:`SweepStats`, a step's
:class:`MoveTally`), and :class:`Moves`, the settings every move component shares: how many sweeps a stage makes and
when they stop."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..priors import inside_support

__all__ = ["metropolis_accept", "accepted", "evaluate_inside", "combine", "Moves", "SweepStats", "MoveTally",
           "NoScreen", "HIGH_DIMENSION"]

#: Above this many parameters the default moves are the scaled ones (:attr:`Moves.scaled`).
HIGH_DIMENSION = 10


def metropolis_accept(current_log_prob, proposal_log_prob, log_hastings, rng: np.random.Generator) -> np.ndarray:
    """Vectorised Metropolis-Hastings decision, ``(n,)`` bool.

    Accept when ``log U < proposal - current + log_hastings``. A proposal with
    ``-inf`` or NaN log-probability is always rejected; a current point at
    ``-inf`` is left for any finite proposal.
    """
    proposal = np.asarray(proposal_log_prob, dtype=float)
    return accepted(np.log(rng.random(proposal.shape)), current_log_prob, proposal, log_hastings)


def accepted(log_u, current_log_prob, proposal_log_prob, log_hastings) -> np.ndarray:
    """:func:`metropolis_accept`'s decision for the log-uniforms ``log_u`` drawn beforehand (a sampler that draws them
    before it evaluates the proposals, to keep its random stream)."""
    current = np.asarray(current_log_prob, dtype=float)
    proposal = np.asarray(proposal_log_prob, dtype=float)
    if np.isfinite(current).all():  # the usual case: no -inf - -inf to guard against
        return log_u < proposal - current + log_hastings  # NaN compares False
    finite = np.isfinite(proposal)
    with np.errstate(invalid="ignore"):
        log_ratio = np.where(finite, proposal - current + log_hastings, -np.inf)
    log_ratio[finite & np.isneginf(current)] = np.inf
    return log_u < log_ratio


def evaluate_inside(component_fn, points, support, n_components: int) -> tuple[np.ndarray, int]:
    """``component_fn`` at the points inside the ``(d, 2)`` support box; ``-inf`` outside.

    ``support=None`` means unbounded. Returns the ``(n, k)`` log-target components
    and the number of points evaluated. Points outside are rejected, never redrawn.
    """
    if support is None:
        return np.asarray(component_fn(points), dtype=float).reshape(points.shape[0], n_components), points.shape[0]
    out = np.full((points.shape[0], n_components), -np.inf)
    inside = inside_support(points, support)
    n_inside = int(np.count_nonzero(inside))
    if n_inside == points.shape[0]:
        out[:] = component_fn(points)
    elif n_inside:
        out[inside] = component_fn(points[inside])
    return out, n_inside


def combine(components, coefficients) -> np.ndarray:
    """Log target ``sum_k c_k l_k`` of ``(n, k)`` components; any ``-inf`` component gives ``-inf``.

    Components are never ``+inf`` (the samplers reject it), so a NaN can only come
    from ``0 x -inf`` and is mapped to ``-inf``.
    """
    if components.shape[1] == 1 and coefficients[0] == 1.0:  # a plain log-density (AIES)
        return components[:, 0].copy()
    with np.errstate(invalid="ignore"):  # 0 x -inf (a zero tempering exponent at a rejected row)
        total = components @ np.asarray(coefficients, dtype=float)
    total[np.isnan(total)] = -np.inf
    return total


@dataclass(frozen=True)
class Moves:
    """What every move component shares (:class:`~seqbayes.moves.stretch.Stretch`,
    :class:`~seqbayes.moves.gaussian.RandomWalk`): a stage's sweeps and when they stop, and the variants of the moves.

    Parameters
    ----------
    min_sweeps : int
        Sweeps per stage at least (3; the paper's SMC uses 1).
    max_sweeps : int
        Sweeps per stage at most (30; SEMC's virtual iterations, SMC's MH steps).
    moved_fraction : float
        The sweeps go on until this fraction of the particles has moved since the stage began (0.9; every particle
        should have had a fair chance to move, cf. PyMC's SMC).
    every_stage : bool or None
        Move at every tempering stage, also after a last stage that did not resample (``None``: the predictive's
        choice, True but for the exact history prior, which moves only after a resampling as IBIS does).
    transform : bool
        Move in unconstrained coordinates (log / logit of bounded parameters, :mod:`seqbayes.priors`);
        ``False`` moves in the parameters' own coordinates, as the paper does.
    scaled : bool or None
        Moves that keep working as the dimension grows (:mod:`seqbayes.moves.scaled`): each round an
        independence-MH sweep from a density fitted to the other half of the particles, then a local sweep, until
        the particles have travelled ``2 d`` squared whitened units (half that with ``economy``) and
        ``moved_fraction`` of them have moved. ``None``: on above :data:`HIGH_DIMENSION` parameters or with
        ``economy``.
    economy : bool
        Fewer likelihood calls for expensive models (docs/core.md, "Economy of likelihood calls"): the scaled
        moves stopped at half the travel and 70 % moved, one more move at a tempered step's last stage, no restart
        from the restricted prior while ``d + 1`` particles have a non-zero likelihood, and the importance evidence
        refitted once to the swept particles and swept until its standard error is small.
    screen : None, "quadratic", "auto" or callable
        Exact delayed acceptance (:mod:`seqbayes.moves.delayed`; Christen and Fox 2005): a cheap log target
        screens every proposal and only the survivors are evaluated. ``"quadratic"``: a quadratic fitted to the
        stage's log targets; ``"auto"``: that quadratic while it yields more accepted moves per evaluation than a
        plain sweep; a callable ``screen(theta (n, d), dataset) -> (n,)``: a cheap log-likelihood. Not applied to
        the scaled moves or the path-space remedy's sweeps.
    """

    min_sweeps: int = 3
    max_sweeps: int = 30
    moved_fraction: float = 0.9
    every_stage: bool | None = None
    transform: bool = True
    scaled: bool | None = None
    economy: bool = False
    screen: object = None

    def __post_init__(self):
        for name in ("min_sweeps", "max_sweeps"):
            value = getattr(self, name)
            if isinstance(value, bool) or int(value) != value or value < 1:
                raise ValueError(f"{name}: must be an integer >= 1, got {value!r}")
        if self.min_sweeps > self.max_sweeps:
            raise ValueError(f"min_sweeps: {self.min_sweeps} exceeds max_sweeps {self.max_sweeps}")
        if not 0.0 <= self.moved_fraction <= 1.0:
            raise ValueError(f"moved_fraction: must lie in [0, 1], got {self.moved_fraction}")
        for name in ("every_stage", "scaled"):
            if getattr(self, name) not in (None, True, False):
                raise ValueError(f"{name}: expected True, False or None, got {getattr(self, name)!r}")
        for name in ("transform", "economy"):
            if getattr(self, name) not in (True, False):
                raise ValueError(f"{name}: expected True or False, got {getattr(self, name)!r}")
        if not (self.screen is None or callable(self.screen) or self.screen in ("quadratic", "auto")):
            raise ValueError(f"screen: expected None, 'quadratic', 'auto' or a callable screen(theta, dataset), "
                             f"got {self.screen!r}")

    def uses_scaled(self, dim: int) -> bool:
        """Whether the scaled moves run for ``dim`` parameters (:attr:`scaled`)."""
        if self.scaled is not None:
            return bool(self.scaled)
        return self.economy or dim > HIGH_DIMENSION

    def resolved(self, n_samples: int, dim: int) -> "Moves":
        """These moves for ``n_samples`` particles of ``dim`` parameters, their defaults that depend on them filled
        in (:class:`ValueError` if they cannot run there)."""
        return self

    def done(self, n_sweeps: int, position, start, alpha: float = float("nan"), alpha_old: float = float("nan")) -> bool:
        """Whether a stage's sweeps stop: at ``max_sweeps``, else after ``min_sweeps`` once ``moved_fraction`` of the
        particles have moved since ``start`` (``position``, ``start``: ``(N, d)`` in the moves' coordinates); the
        rule of SMC, SEMC and SMC^2's PMMH alike (:class:`~seqbayes.moves.stretch.Stretch` adds Algorithm 2's
        virtual iterations)."""
        if n_sweeps >= self.max_sweeps:
            return True
        if n_sweeps < self.min_sweeps:
            return False
        return self.moved_fraction == 0 or np.mean(np.any(position != start, axis=1)) >= self.moved_fraction

    @property
    def initial_step_size(self) -> float:
        """The step size a run's state starts with (SEMC's ``u``; the others carry the stretch move's default,
        which they never adapt)."""
        return 2.0

    def step_size_after(self, adapted: float, step_size: float) -> float:
        """The step size a step carries on after moves that ``adapted`` it (SEMC's); ``step_size`` unchanged here."""
        return step_size


@dataclass(frozen=True)
class SweepStats:
    """Counts of one or more sweeps; the true acceptance rate is ``n_accepted / n_proposed``.

    With delayed acceptance (:mod:`seqbayes.moves.delayed`) ``n_evaluations`` counts the expensive
    evaluations only, ``n_screen_evaluations`` the cheap screen's and ``n_screened_out`` the proposals
    it rejected before any expensive call."""

    n_proposed: int = 0
    n_accepted: int = 0
    n_identical_partner: int = 0
    n_evaluations: int = 0
    n_screen_evaluations: int = 0
    n_screened_out: int = 0

    def __add__(self, other: "SweepStats") -> "SweepStats":
        return SweepStats(self.n_proposed + other.n_proposed, self.n_accepted + other.n_accepted,
                          self.n_identical_partner + other.n_identical_partner,
                          self.n_evaluations + other.n_evaluations,
                          self.n_screen_evaluations + other.n_screen_evaluations,
                          self.n_screened_out + other.n_screened_out)

    @property
    def acceptance_rate(self) -> float:
        return self.n_accepted / self.n_proposed if self.n_proposed else float("nan")


@dataclass(frozen=True)
class MoveTally:
    """What the moves of one step did: counts, SEMC's step size, virtual iterations."""

    stats: SweepStats = SweepStats()
    step_size: float = float("nan")
    n_virtual: int = 0

    def then(self, moved, moves) -> "MoveTally":
        """The tally after one stage's :class:`~seqbayes.moves.schedule.StageMoves` ``moved``; the ``moves``
        component says whether the adapted step size carries on (SEMC's)."""
        return MoveTally(self.stats + moved.stats, moves.step_size_after(moved.step_size, self.step_size),
                         self.n_virtual + moved.n_virtual)


class NoScreen:
    """A stage's delayed acceptance when the moves have no ``screen``: never active
    (:class:`~seqbayes.moves.delayed.Screening` is the one that screens)."""

    screen = None

    def active(self) -> bool:
        return False

    def record(self, stats: SweepStats) -> None:
        """Nothing to learn from a plain sweep."""
