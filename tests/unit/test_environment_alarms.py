"""The alarm rule, its scoring and its calibration (studies/environment_alarms.py), and the matrix's per-cell
summary against the issue's bars (studies/environment_matrix.py): exact checks on constructed years and one
statistical check of the calibrated false-alarm rate."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.stats import chi2

from seqbayes.studies.environment_alarms import (AlarmRule, DailyVerdict, alarm_times, calibrate, episode_starts,
                                                 false_alarm_rate, held_for, rate_interval, score_year)
from seqbayes.studies.environment_matrix import summarise


def _verdict(score, first_day=0.0, element=None, size=None, onset=None):
    score = np.asarray(score, float)
    D = score.size
    nan = np.full((D, 3), np.nan)
    return DailyVerdict(np.arange(D), score, np.zeros(D, int) if element is None else element,
                        nan if size is None else size, nan if onset is None else onset, first_day)


def test_rule_runs_and_episodes():
    above = np.array([1, 1, 0, 1, 1, 1, 0, 1], bool)
    assert held_for(above, 2).tolist() == [0, 1, 0, 0, 1, 1, 0, 0]
    assert held_for(np.vstack([above, ~above]), 1).tolist() == [above.tolist(), (~above).tolist()]
    assert episode_starts(above).tolist() == [1, 0, 0, 1, 0, 0, 0, 1]
    v = _verdict([0.1, 0.99, 0.2, 0.97, 0.98, 0.99], first_day=0)
    assert alarm_times(v, AlarmRule(0.95, 2)).tolist() == [5.0, 6.0]  # the end of days 4 and 5
    assert alarm_times(_verdict([0.99, 0.99, 0.99], first_day=2), AlarmRule(0.95, 2)).tolist() == [3.0]
    assert alarm_times(_verdict([0.95, 0.95]), AlarmRule(0.95, 1)).tolist() == []  # strictly above
    with pytest.raises(ValueError, match="consecutive"):
        AlarmRule(0.5, 0)
    with pytest.raises(ValueError, match="size"):
        DailyVerdict(np.arange(3), np.zeros(3), np.zeros(3), np.zeros((3, 2)), np.zeros((3, 3)))


def test_a_year_is_scored_by_the_conventions():
    D = 40
    score = np.zeros(D)
    score[[5, 6, 7, 12, 13]] = 1.0  # two false episodes (days 5-7 and 12-13) before the loss on day 20
    score[20:] = 1.0
    element = np.full(D, 3)
    size = np.tile([0.05, 0.03, 0.07], (D, 1))
    onset = np.tile([20.0, 19.0, 21.0], (D, 1))
    v = _verdict(score, first_day=2, element=element, size=size, onset=onset)
    s = score_year(v, {"damage_day": 20.0, "damage_storey": 3, "damage_size": 0.05}, AlarmRule(0.5, 2))
    # held on days 6, 7, 13 before the loss (times 7, 8, 14); from day 21 after it (time 22, delay 2)
    assert (s.false_alarms, s.false_alarm_days, s.exposure_days) == (2, 3, 18)
    assert s.delay == 2.0 and s.element == 3 and not s.in_alarm_at_damage
    assert s.size_covered and s.onset_covered and s.size == (0.05, 0.03, 0.07)
    miss = score_year(v, {"damage_day": 20.0, "damage_storey": 3, "damage_size": 0.08}, AlarmRule(0.5, 2))
    assert miss.size_covered is False
    healthy = score_year(v, {"damage_day": None}, AlarmRule(0.5, 2))
    assert healthy.false_alarms == 3 and healthy.exposure_days == 38 and healthy.delay is None
    already = score_year(_verdict(np.ones(10)), {"damage_day": 5.0, "damage_storey": 1, "damage_size": 0.1},
                         AlarmRule(0.5, 1))
    assert already.in_alarm_at_damage and already.delay == 1.0 and already.size_covered is None


def test_poisson_bounds_are_the_chi_square_ones():
    assert rate_interval(0, 1.0)[2] == pytest.approx(-np.log(0.05), rel=1e-12)
    for count in (1, 4, 20):
        rate, se, upper = rate_interval(count, 12.5)
        assert rate == count / 12.5 and se == pytest.approx(np.sqrt(count) / 12.5)
        assert upper == pytest.approx(chi2.ppf(0.95, 2 * count + 2) / 25)
    with pytest.raises(ValueError, match="exposure"):
        rate_interval(1, 0.0)


def test_calibration_takes_the_lowest_threshold_that_keeps_the_bound():
    rng = np.random.default_rng(0)
    healthy = [_verdict(rng.uniform(0, 0.5, 365)) for _ in range(60)]
    top = sorted((v.score.max() for v in healthy), reverse=True)
    # 60 years: the bound allows 2 false alarms (upper 0.105 > 0.1 at 3... check), so the third year's maximum
    allowed = max(c for c in range(10) if rate_interval(c, 60.0)[2] <= 0.1)
    result = calibrate(healthy, 0.1, consecutive=(1,))
    assert result.rule.consecutive == 1 and result.demonstrated
    assert result.rule.threshold == top[allowed]
    assert result.false_alarms["false_alarms"] == allowed
    # too few years to show 0.1 a year: the rule with no false alarm, flagged
    small = calibrate(healthy[:10], 0.1, consecutive=(1,))
    assert small.rule.threshold == max(v.score.max() for v in healthy[:10]) and not small.demonstrated
    assert small.false_alarms["rate_upper"] == pytest.approx(3.0 / 10, rel=2e-3)


def test_calibration_chooses_the_days_in_a_row_that_detect_soonest():
    rng = np.random.default_rng(1)
    healthy = [_verdict(rng.uniform(0, 0.2, 365)) for _ in range(30)]
    for v in healthy[:3]:  # isolated one-day spikes: k = 1 must sit above them, k = 2 need not
        v.score[100] = 0.9
    damaged_score = np.full(365, 0.1)
    damaged_score[200:] = 0.5
    damaged = [_verdict(damaged_score)]
    truths = [{"damage_day": 200.0, "damage_storey": 1, "damage_size": 0.02}]
    result = calibrate(healthy, 0.1, damaged=damaged, damaged_truths=truths, consecutive=(1, 2, 3))
    by_k = {c["consecutive"]: c for c in result.candidates}
    assert by_k[1]["threshold"] == pytest.approx(0.9) and by_k[1]["detected"] == 0
    assert result.rule.consecutive == 2 and result.delays["delays"] == [2.0]
    assert json.loads(json.dumps(result.to_json()))["rule"]["consecutive"] == 2
    with pytest.raises(ValueError, match="target_rate"):
        calibrate(healthy, 0.0)


def test_the_calibrated_rule_keeps_its_false_alarm_rate_on_fresh_years():
    """AR(1) daily scores: a rule calibrated on 30 healthy years (0 false alarms allowed at 0.1 a year) alarms in a
    fresh year with probability 1/31 (exchangeability of the 31 yearly maxima); measured over 300 replicates of
    30 calibration and 30 fresh years, within 4 binomial standard errors, and the rate per year stays below 0.1."""
    rng = np.random.default_rng(40)
    rho, shares, rates = 0.7, [], []
    for _ in range(300):
        noise = rng.standard_normal((60, 365))
        series = np.empty_like(noise)
        series[:, 0] = noise[:, 0]
        for d in range(1, 365):
            series[:, d] = rho * series[:, d - 1] + np.sqrt(1 - rho**2) * noise[:, d]
        years = [_verdict(s) for s in series]
        rule = calibrate(years[:30], 0.1, consecutive=(1,)).rule
        fresh = false_alarm_rate(years[30:], [{"damage_day": None}] * 30, rule)
        shares.append(fresh["years_with_false_alarms"] / 30)
        rates.append(fresh["rate"])
    expected = 1 / 31
    assert abs(np.mean(shares) - expected) < 4 * np.sqrt(expected * (1 - expected) / 9000)
    assert np.mean(rates) < 0.1


def _record(kind, score, truth, cpu=1.0):
    v = _verdict(score, element=np.full(len(score), truth.get("damage_storey") or 0),
                 size=np.tile([0.05, 0.0, 0.1], (len(score), 1)), onset=np.tile([50.0, 45.0, 55.0], (len(score), 1)))
    return {"kind": kind, "truth": truth, "verdict": v.to_json(), "cpu_seconds": cpu}


def test_the_cell_summary_applies_the_bars():
    quiet = np.zeros(100)
    caught = np.where(np.arange(100) >= 50, 1.0, 0.0)
    late = np.where(np.arange(100) >= 90, 1.0, 0.0)  # found on day 92: 42 days, past the 30
    loss5 = {"damage_day": 50.0, "damage_storey": 2, "damage_size": 0.05}
    loss2 = {"damage_day": 50.0, "damage_storey": 2, "damage_size": 0.02}
    records = ([_record("healthy", quiet, {"damage_day": None})] * 10 + [_record("loss5", caught, loss5)] * 10
               + [_record("loss2", caught, loss2)] * 7 + [_record("loss2", late, loss2)] * 3)
    s = summarise(records, AlarmRule(0.5, 2))
    assert s["healthy_with_alarm"] == 0 and s["false_alarms"] == 0
    assert s["loss5"]["found"] == 10 and s["loss5"]["median_delay"] == 2.0
    assert s["loss2"]["found"] == 7 and s["loss2"]["both_covered"] == 10
    assert s["bars"] == {"healthy": True, "loss5": True, "loss2": False, "intervals": True}
    assert summarise(records, None)["bars"]["healthy"] is False  # no rule: nothing passes


def test_calibration_raises_a_threshold_below_the_floor_and_refuses_a_floor_at_the_top():
    healthy = [_verdict(np.full(365, 0.01)) for _ in range(40)]
    assert calibrate(healthy, 0.1, consecutive=(1,), score_bounds=(0.0, 1.0)).rule.threshold == 0.01
    raised = calibrate(healthy, 0.1, consecutive=(1,), score_bounds=(0.0, 1.0), floor=0.5)
    assert raised.rule.threshold == 0.5 and raised.false_alarms["false_alarms"] == 0
    with pytest.raises(ValueError, match="floor"):
        calibrate(healthy, 0.1, score_bounds=(0.0, 1.0), floor=1.0)


def test_the_monitor_s_days_become_a_daily_verdict():
    from seqbayes.studies.environment_matrix import monitor_verdict

    nan = [np.nan] * 3
    stacked = {"day": np.array([0, 3]), "p_damage": np.array([0.0, 0.99]), "alarm": np.array([False, True]),
               "element": np.array([0, 2]), "size": np.array([nan, [0.05, 0.04, 0.06]]),
               "onset": np.array([nan, [2.5, 2.0, 3.0]])}
    v = monitor_verdict(stacked)
    assert v.days.tolist() == [0, 3] and v.score.tolist() == [0.0, 0.99] and v.element.tolist() == [0, 2]
    assert np.isnan(v.size[0]).all() and v.size[1].tolist() == [0.05, 0.04, 0.06]
    assert v.onset[1].tolist() == [2.5, 2.0, 3.0] and v.first_day == 0.0
    s = score_year(v, {"damage_day": 2.0, "damage_storey": 2, "damage_size": 0.05}, AlarmRule(0.5, 1))
    assert s.delay == 2.0 and s.element == 2 and s.size_covered and s.onset_covered
