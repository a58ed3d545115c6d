"""SMC^2's rejuvenation: particle-marginal Metropolis-Hastings of the static parameters, spread over updates.

A PMMH proposal re-runs its inner filter over every dataset so far, so one sweep at step ``s`` costs
``N M s`` evaluations against ``N M`` for an update without moves. Done at once, a late rejuvenation is
hundreds of times an ordinary update (issue 23: 148-186 s at s = 260 against 0.03 s). Here a rejuvenation
is a queue: resampling schedules sweeps, each a fresh random permutation of the particles, stopped by the stages'
rule, and every update spends at most ``SamplerConfig.move_budget x N M`` evaluations (:data:`MOVE_BUDGET` by
default) on the queue's next particles; the rest waits for the next update. The budget defers only what a long
stream can wait for (:class:`~seqbayes.predictive.smc2.NestedPredictive` decides, :func:`rejuvenate` enforces):

- a tempered update (more than one stage: the dataset is far from the predictive) completes its moves at every
  stage, because each stage's exponent is chosen from the particles' ESS, which copies would overstate;
- after a resampling, the moves first restore the copies' diversity (:func:`distinct_ess`) to the ESS the
  weights had before it, beyond the budget (up to :data:`RESTORE_LIMIT` times it); only the sweeps beyond that,
  which decorrelate further, are deferred.

On the README's drifting model, which the data contradict (every update resamples and tempers), a budget that
deferred everything left the cloud degenerate and the log-evidence 6.1 nats off the Kalman value at step 5;
with these two rules it is as accurate as without a budget (``tests/statistical/test_smc2_conflicting_drift.py``).

With ``SamplerConfig.surrogate`` ``"quadratic"`` (or ``"auto"``) every proposal first faces a quadratic fitted to the
particles' log targets (delayed acceptance, :mod:`seqbayes.moves.delayed`): only the survivors re-run their inner
filters, and the budget counts those re-runs alone. The screen is a function of the proposal alone, so the second
stage's ratio keeps the pseudo-marginal target exact.

SEMC's moves are ensemble moves: a proposal for a particle of the batch is built from particles outside it. By default
that is the stretch move with the step size adapted by Eq. (9), as in the paper's stages. With
``SamplerConfig.strict_budget`` it is the differential-evolution move instead (ter Braak 2006,
:class:`~seqbayes.moves.stretch.DifferentialMove`: ``x + 2.38 / sqrt(2 d) (x_j - x_k)``, still affine invariant): when
the expensive re-runs are the budget, what counts is how far the particles travel per re-run, and at the same
acceptance the stretch move's accepted jumps are much shorter (its proposals mix long stretches, mostly rejected, with
short ones). The outer moves of SMC^2 are a PMMH kernel, not the paper's SEMC stage move, so any kernel that keeps the
target serves; ``docs/benchmarks.md`` ("Coulomb at 50,000 calls") has the measured jumps per re-run.

Why it stays exact: each attempt is a PMMH kernel that leaves the current extended target invariant
(the step's ``p_0(phi) p^(D^{1:s} | phi)`` at the stage's exponent; Andrieu & Roberts 2009), applied to a
subset of particles chosen by a permutation drawn independently of their values and weights. A kernel
that leaves ``pi`` invariant, applied to a weighted sample of ``pi``, keeps it one (``E[w K f(x)] =
pi(K f) = pi(f)``), so the particles left waiting stay a weighted sample of each later target and the
moved ones join it. Choosing particles by their values or their past acceptances would not be exact
(a kernel applied only where ``x`` lies in some set is not ``pi``-invariant), hence the permutations.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..moves.base import SweepStats, metropolis_accept
from ..moves.delayed import QuadraticScreen
from ..priors import inside_support
from ..priors import BoxTransform

__all__ = ["MOVE_BUDGET", "RESTORE_BATCH", "RESTORE_LIMIT", "Rejuvenation", "Refilter", "Budget", "distinct_ess",
           "rejuvenate", "run_inner", "outer_logpdf", "rerun_cost"]


#: SMC^2's PMMH budget per update, in units of ``N M`` (``SamplerConfig.move_budget``): with the advance itself an
#: update without tempering costs at most ~6 ``N M`` (plus the guide's pilot) however long the stream.
MOVE_BUDGET = 5

#: While the cloud's diversity is being restored, the fraction of the particles attempted per batch: small, so that the
#: restoring stops soon after it is reached (each batch re-runs its particles' inner filters over the whole history).
RESTORE_BATCH = 0.1

#: What restoring the ESS may spend beyond the budget, in units of the budget: an update then costs at most
#: ``(1 + RESTORE_LIMIT x move_budget) N M`` unless it tempers. Uncapped, one 300-dataset run's largest update
#: was 21x its median (restoring at s = 178; docs/benchmarks.md), against the issue's 20x.
RESTORE_LIMIT = 4


def rerun_cost(inner, datasets) -> int:
    """Evaluations of one particle's re-run (its inner filter over ``datasets``), the budget's unit: ``M s``."""
    return max(1, int(getattr(inner, "n_inner", 1)) * len(datasets))


@dataclass(frozen=True, eq=False)
class Rejuvenation:
    """The pending rejuvenation: the particles still to move in the current sweep (``queue``, indices in
    order), the most sweeps still allowed, the proposals and acceptances since the last resampling, and
    which particles have moved since (``moved``, ``(N,)`` bool, or empty before any resampling).

    ``queue`` is empty and ``sweeps_left`` 0 when nothing is pending."""

    queue: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))
    sweeps_left: int = 0
    n_proposed: int = 0
    n_accepted: int = 0
    moved: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))

    @property
    def pending(self) -> bool:
        return bool(self.queue.size or self.sweeps_left)

    @property
    def acceptance(self) -> float:
        return self.n_accepted / self.n_proposed if self.n_proposed else float("nan")

    def restarted(self, n_sweeps: int, n: int) -> "Rejuvenation":
        """After a resampling of ``n`` particles: at most ``n_sweeps`` sweeps, the tally reset."""
        return Rejuvenation(np.zeros(0, dtype=int), int(n_sweeps), 0, 0, np.zeros(n, dtype=bool))


@dataclass(frozen=True, eq=False)
class Refilter:
    """What a proposal's re-run needs: the problem, its inner filter, the split of the columns
    (:func:`~seqbayes.predictive.inner.nested_split`), the datasets so far and each one's guide."""

    problem: object
    inner: object
    split: tuple
    datasets: object
    guides: object


@dataclass(frozen=True)
class Budget:
    """The evaluations a rejuvenation may spend: ``limit`` (in re-run evaluations), the ESS to restore first
    (``restore x N``, 0: none), what the update's earlier stages have ``spent`` and the restoring allowance
    ``restore_limit`` in budgets (:func:`rejuvenate`)."""

    limit: int
    restore: float = 0.0
    spent: int = 0
    restore_limit: float = RESTORE_LIMIT


def outer_logpdf(prior, columns, outer) -> np.ndarray:
    """``log p_0`` of outer particles ``outer (K, len(columns))`` under the independent marginals of ``prior``."""
    total = np.zeros(outer.shape[0])
    for column, j in enumerate(columns):
        total += prior.marginal_logpdf(j, outer[:, column])
    return total


def run_inner(problem, inner, split, static, datasets, guides, likelihood, rng):
    """Re-run inner filters from the first dataset (with each step's guide): ``log p^(D^{1:s-1})``,
    ``log p^(D^s | D^{1:s-1})`` and the final cloud, for the outer particles ``static``."""
    past = np.zeros(static.shape[0])
    cloud, last = None, None
    for k, dataset in enumerate(datasets):
        if last is not None:
            past = past + last
        last, cloud = inner.advance(problem, split, static, cloud, dataset, k == 0, likelihood, rng, guides[k])
    return past, last, cloud


def distinct_ess(static: np.ndarray) -> float:
    """The cloud's diversity after a resampling: ``N^2 / sum_g c_g^2`` over the groups of ``c_g`` identical rows of
    ``static (N, d)`` (the ESS of equal weights spread over the distinct values; ``N`` when all differ)."""
    _, counts = np.unique(static, axis=0, return_counts=True)
    return static.shape[0] ** 2 / float(np.sum(counts.astype(float) ** 2))


def _pmmh_screen(config, static, components, coefficients, transform):
    """Delayed acceptance's cheap log target for PMMH (``SamplerConfig.surrogate`` ``"quadratic"`` or ``"auto"``),
    or ``None``: a quadratic fitted to the particles' log targets in the moves' coordinates, the evaluations already
    made. Fixed for the call, so for every attempt it is a function of the proposal alone, which keeps the
    pseudo-marginal target exact (the inner filters' randomness enters stage 2 only)."""
    if config.moves.screen not in ("quadratic", "auto"):
        return None
    position = transform.forward(static) if transform is not None else static
    jacobian = transform.log_jacobian(position) if transform is not None else 0.0
    with np.errstate(invalid="ignore"):
        return QuadraticScreen.fit(position, components @ coefficients + jacobian)


def rejuvenate(refilter: Refilter, config, static, log_weights, cloud, components, beta, step_size,
               pending: Rejuvenation, budget: Budget, likelihood, rng):
    """PMMH attempts on the queue's next particles at tempering exponent ``beta``, within ``budget`` evaluations.

    ``components`` is ``(N, 3)``: ``log p^(D^s | ...)``, ``log p_0(phi)``, ``log p^(D^{1:s-1} | phi)``; the target
    is ``beta c_0 + c_1 + c_2``. A proposal re-runs its inner filter over ``datasets`` (fresh randomness), which is
    what makes the noisy likelihood estimate an exact PMMH target. Particles are attempted in batches (one
    vectorised re-run each): SMC's Gaussian random walk with the weighted particles' covariance, or SEMC's stretch
    move against the particles outside the batch with its step size adapted by Eq. (9) after each batch
    (the differential-evolution move, at its fixed scale, with ``config.strict_budget``). Sweeps
    stop as the stages' schedule says (:func:`~seqbayes.moves.schedule.stage_done`'s rule): after at least
    ``n_moves`` once ``moved_fraction`` of the particles have moved since the resampling, or at the last sweep
    allowed. Only that decision looks at the particles (as a whole); which particle moves never does.
    When one particle's re-run alone exceeds a positive budget (``s`` beyond ``MOVE_BUDGET N``), one particle is
    attempted all the same, so a rejuvenation always progresses.

    The budget (``budget.limit``) binds only once the copies a resampling left are diverse again: while
    :func:`distinct_ess` is below ``budget.restore x N`` (the ESS of the weights the cloud was resampled from),
    particles are attempted in batches of :data:`RESTORE_BATCH` x N beyond the budget, up to :data:`RESTORE_LIMIT`
    times it, so that a resampling does not leave the cloud less diverse than its weights were (late in a long
    stream, where one sweep costs more than that, the rest of the restoring waits with the other deferred sweeps).

    ``budget.spent`` is what the update's earlier stages have spent on moves and ``budget.restore_limit`` the
    restoring allowance in budgets (``SamplerConfig.strict_budget`` passes the former and 1: the update's stages
    share one budget, restoring included).

    Returns
    -------
    static, cloud, components, SweepStats, step_size, n_batches, Rejuvenation
    """
    n = static.shape[0]
    problem, inner, split, datasets, guides = (refilter.problem, refilter.inner, refilter.split, refilter.datasets,
                                               refilter.guides)
    restore, spent, restore_limit, budget = budget.restore, budget.spent, budget.restore_limit, budget.limit
    per_particle = rerun_cost(inner, datasets)
    columns = inner.outer_columns(split, problem.kernel.dim)
    support = problem.support[columns]
    moves, strict = config.moves, config.predictive.strict_budget
    transform = BoxTransform(support) if moves.transform and np.isfinite(support).any() else None
    coefficients = np.array([beta, 1.0, 1.0])
    stats, n_batches = SweepStats(), 0
    queue, sweeps_left = pending.queue, pending.sweeps_left
    n_proposed, n_accepted = pending.n_proposed, pending.n_accepted
    moved_since = pending.moved.copy() if pending.moved.size == n else np.zeros(n, dtype=bool)
    copied = False
    screen = _pmmh_screen(config, static, components, coefficients, transform)
    while queue.size or sweeps_left:
        if not queue.size:  # a new sweep: every particle once, in an order independent of the particles
            done = moves.max_sweeps - sweeps_left
            if done >= moves.min_sweeps and (moves.moved_fraction == 0 or moved_since.mean() >= moves.moved_fraction):
                sweeps_left = 0
                break
            queue, sweeps_left = rng.permutation(n), sweeps_left - 1
        k = min(queue.size, (budget - spent) // per_particle)
        if restore and spent < restore_limit * budget and distinct_ess(static) < restore * n:  # restore the ESS first
            k = min(queue.size, max(k, int(np.ceil(RESTORE_BATCH * n))))
        k = moves.pmmh_batch(k, n)  # the ensemble moves need a complement to draw partners from
        if k < 1:
            if spent or budget <= 0:
                break
            k = 1
        if not copied:
            static, components = static.copy(), components.copy()
            cloud = {key: value.copy() for key, value in cloud.items()}
            copied = True
        active, queue = queue[:k], queue[k:]
        position = transform.forward(static) if transform is not None else static
        # under a strict budget SEMC's PMMH proposes by differential evolution, not the stretch move (module doc)
        proposals, log_hastings, identical = moves.pmmh_proposals(position, active, log_weights, step_size, strict, rng)
        phi = transform.inverse(proposals) if transform is not None else proposals
        inside = ~identical & inside_support(phi, support)
        cheap_old = cheap_new = np.zeros(k)
        if screen is not None:  # delayed acceptance, stage 1: only proposals the cheap screen accepts are re-run
            cheap_old, cheap_new = screen(position[active]), np.full(k, -np.inf)
            cheap_new[inside] = screen(proposals[inside])
            passed = metropolis_accept(cheap_old, cheap_new, log_hastings, rng) & inside
            stats = stats + SweepStats(n_screen_evaluations=int(inside.sum()) + k,
                                       n_screened_out=int((inside & ~passed).sum()))
            # stage 2's ratio t(x') - t(x) - s(x') + s(x): the Hastings term has cancelled (Christen and Fox 2005)
            log_hastings, inside = cheap_old - np.where(passed, cheap_new, 0.0), passed
        new_components = np.full((k, 3), -np.inf)
        jac_new, jac_old = np.zeros(k), np.zeros(k)
        if transform is not None:
            jac_old = transform.log_jacobian(position[active])
        new_cloud = {key: value[active] for key, value in cloud.items()}
        if inside.any():
            rows = np.flatnonzero(inside)
            past, last, rerun = run_inner(problem, inner, split, phi[rows], datasets, guides, likelihood, rng)
            new_components[rows] = np.column_stack([last, outer_logpdf(problem.prior, columns, phi[rows]), past])
            for key in new_cloud:
                new_cloud[key][rows] = rerun[key]
            if transform is not None:
                jac_new[rows] = transform.log_jacobian(proposals[rows])
            spent += rows.size * per_particle
        with np.errstate(invalid="ignore"):
            current = components[active] @ coefficients + jac_old
            proposed = new_components @ coefficients + jac_new
        proposed = np.where(np.isnan(proposed), -np.inf, proposed)
        accept = metropolis_accept(np.where(np.isnan(current), -np.inf, current), proposed, log_hastings, rng) & inside
        moved = active[accept]
        moved_since[moved] = True
        static[moved] = phi[accept]
        components[moved] = new_components[accept]
        for key in cloud:
            cloud[key][moved] = new_cloud[key][accept]
        n_batches += 1
        n_proposed, n_accepted = n_proposed + k, n_accepted + int(accept.sum())
        stats = stats + SweepStats(k, int(accept.sum()), int(identical.sum()), int(inside.sum()))
        step_size = moves.pmmh_step_size(step_size, float(accept.mean()), strict)  # Eq. (9) for SEMC's
    return (static, cloud, components, stats, step_size, n_batches,
            Rejuvenation(queue, sweeps_left, n_proposed, n_accepted, moved_since))
