"""The prior-data conflict diagnostic (``StepInfo.prior_data_conflict``, issue 11)."""

import warnings

import numpy as np
import pytest

from seqbayes.engine.settings import from_flat
from seqbayes import SMC
from seqbayes.models.linear_gaussian import LinearGaussianStateSpace
from seqbayes.predictive.particle import prior_data_conflict
from seqbayes import PriorDataConflictWarning
from seqbayes.predictive.particle import step_conflict


def test_shift_in_prior_sds_exactly():
    prior = np.array([[0.0, 10.0], [2.0, 10.0], [4.0, 10.0], [6.0, 14.0]])  # means (3, 11), sds (sqrt 5, sqrt 3)
    posterior = np.array([[9.0, 11.0], [9.0, 11.0]])
    conflict = prior_data_conflict(prior, np.zeros(4), posterior, np.log([0.5, 0.5]))
    np.testing.assert_allclose(conflict, [6.0 / np.sqrt(5.0), 0.0], atol=1e-12)


def test_the_steps_prior_is_the_predictive_restricted_to_the_parameter_space():
    # half of the predictive draws of the second parameter lie below its bound 0: the step's prior (the model's,
    # and the exact grid references') is the inside half, so a posterior at the inside draws' mean is no conflict
    prior = np.array([[1.0, -3.0], [1.0, -1.0], [1.0, 1.0], [3.0, 3.0]])
    posterior = np.array([[2.0, 2.0]])
    support = np.array([[0.0, 10.0], [0.0, 10.0]])
    inside = step_conflict(prior, np.zeros(4), posterior, np.zeros(1), support)
    np.testing.assert_allclose(inside, [0.0, 0.0], atol=1e-12)                     # inside draws: means (2, 2)
    np.testing.assert_allclose(prior_data_conflict(prior, np.zeros(4), posterior, np.zeros(1)),
                               [0.5 / np.sqrt(0.75), 2.0 / np.sqrt(5.0)], atol=1e-12)  # unrestricted
    # no draw inside: the unrestricted moments (the restart's draws carry the step's prior then)
    outside = prior - [0.0, 10.0]
    np.testing.assert_allclose(step_conflict(outside, np.zeros(4), posterior, np.zeros(1), support),
                               prior_data_conflict(outside, np.zeros(4), posterior, np.zeros(1)), atol=1e-12)
    # one draw inside has no spread: the unrestricted moments too, not a shift over an sd of 0 (~1e150)
    one_inside = outside.copy()
    one_inside[3] = [3.0, 3.0]
    conflict = step_conflict(one_inside, np.zeros(4), posterior, np.zeros(1), support)
    np.testing.assert_allclose(conflict, prior_data_conflict(one_inside, np.zeros(4), posterior, np.zeros(1)),
                               atol=1e-12)
    assert np.all(conflict < 10.0)


def drifting_problem():
    return LinearGaussianStateSpace(np.column_stack([np.linspace(-1, 1, 10), np.ones(10)]), ("drift", "drift"),
                                    (0.0, 0.0), (0.05, 0.05), (0.0, 0.0), (1.0, 1.0), noise_std=0.2)


def test_an_abrupt_change_warns_and_names_the_parameter():
    problem = drifting_problem()
    data, path = problem.simulate(4, rng=3)
    jumped = data.copy()
    jumped[3] += 2.0  # the offset jumps by 2, ~14 predictive sds (process noise 0.05 on ~0.1 posterior sd)
    sampler = SMC(problem.prior, problem.kernel, problem.loglike, n_samples=500, rng=1)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        infos = [sampler.update(y) for y in jumped]
    conflicts = [w for w in caught if issubclass(w.category, PriorDataConflictWarning)]
    assert len(conflicts) == 1 and "step 4" in str(conflicts[0].message) and "theta_1" in str(conflicts[0].message)
    assert infos[3].prior_data_conflict > 4 and infos[3].conflict_parameter == 1
    # the exact remedy ran there (docs/prior_data_conflict.md) and the warning says so
    assert infos[3].path_steps == 4 and "assimilated on the path space" in str(conflicts[0].message)
    assert all(info.prior_data_conflict < 4 for info in infos[1:3])


def test_smooth_data_stay_silent():
    problem = drifting_problem()
    data, _ = problem.simulate(6, rng=4)
    sampler = SMC(problem.prior, problem.kernel, problem.loglike, n_samples=500, rng=2)
    with warnings.catch_warnings():
        warnings.simplefilter("error", PriorDataConflictWarning)
        infos = [sampler.update(y) for y in data]
    assert all(np.isfinite(info.prior_data_conflict) for info in infos)


def test_threshold_is_a_validated_setting():
    problem = drifting_problem()
    with pytest.raises(ValueError, match="conflict_threshold"):
        SMC(problem.prior, problem.kernel, problem.loglike, n_samples=50, rng=0, **from_flat("SMC", conflict_threshold=-1.0))


@pytest.mark.slow
def test_a_step_in_the_mixtures_tail_warns_through_the_ancestor_ess():
    # the other half of the diagnostic: with the shift's threshold out of reach, the jump still warns, because
    # only a few of the previous posterior's particles carry the step (ancestor ESS below remedy_ess * N, which
    # starts the remedy); without the remedy nothing is recorded there and only the shift could warn
    problem = drifting_problem()
    data, _ = problem.simulate(4, rng=3)
    data[3] += 2.0
    for remedy in (True, False):
        sampler = SMC(problem.prior, problem.kernel, problem.loglike, n_samples=500, rng=1, **from_flat("SMC", conflict_threshold=1e6, conflict_remedy=remedy))
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            infos = [sampler.update(y) for y in data]
        conflicts = [str(w.message) for w in caught if issubclass(w.category, PriorDataConflictWarning)]
        if remedy:
            assert infos[3].ancestor_ess < 0.05 * 500 and infos[3].path_steps == 4
            assert len(conflicts) == 1 and "step 4" in conflicts[0] and "StepInfo.ancestor_ess" in conflicts[0]
        else:
            assert conflicts == [] and infos[3].path_steps == 0
