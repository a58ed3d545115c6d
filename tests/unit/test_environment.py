"""The temperature simulator and the damage-against-environment monitor (issue 25): exact checks."""

from __future__ import annotations

import json

import numpy as np
import pytest

from seqbayes.structural.environment import (ChangeModelSampler, EnvironmentMonitor, EnvironmentPrior, alarm_days,
                                             split_days)
from seqbayes.structural.structures import ShearBuilding
from seqbayes.studies.environment import (MASSES, STIFFNESSES, ThermalLaw, read_truth, read_year_csv, simulate_year,
                                          stiffness_factor, write_year_csv)


def _year(**kwargs):
    options = dict(frequency_noise=0.0, n_days=6, sets_per_day=4)
    options.update(kwargs)
    return simulate_year(np.random.default_rng(3), **options)


def test_frequencies_are_the_eigenproblem_of_the_temperature_scaled_stiffness():
    table, _ = _year()
    building = ShearBuilding(MASSES, STIFFNESSES)
    factor = stiffness_factor(table["temperature"], -0.0015, -0.015, 10.0)
    # each row's K is c(T) K_ref: solve that eigenproblem directly, with no sqrt(c) shortcut
    scaled = ShearBuilding(MASSES, STIFFNESSES)
    expected = np.vstack([scaled.modes(np.full(4, c))[0][0] for c in factor])
    observed = np.column_stack([table[f"f{r}"] for r in range(1, 5)])
    np.testing.assert_allclose(observed, expected, rtol=1e-12)
    assert building.modes(np.ones(4))[0][0] == pytest.approx([2.0920, 5.5629, 8.2795, 10.3442], abs=1e-4)
    assert table["temperature"].min() >= -10 and table["temperature"].max() <= 30


def test_damage_applies_from_its_day_in_its_storey():
    healthy, _ = _year()
    damaged, truth = _year(damage_day=3.0, damage_storey=2, damage_size=0.05)
    assert truth.damage_day == 3.0 and truth.damage_storey == 2
    before = healthy["day"] < 3.0
    for r in range(1, 5):
        np.testing.assert_array_equal(damaged[f"f{r}"][before], healthy[f"f{r}"][before])
    ratio = np.column_stack([damaged[f"f{r}"][~before] / healthy[f"f{r}"][~before] for r in range(1, 5)])
    building = ShearBuilding(MASSES, STIFFNESSES)
    expected = building.modes([1, 0.95, 1, 1])[0][0] / building.modes(np.ones(4))[0][0]
    np.testing.assert_allclose(ratio, np.broadcast_to(expected, ratio.shape), rtol=1e-12)


def test_simulation_is_reproducible_and_noise_is_relative():
    a, _ = simulate_year(np.random.default_rng(5), n_days=3)
    b, _ = simulate_year(np.random.default_rng(5), n_days=3)
    for key in a:
        np.testing.assert_array_equal(a[key], b[key])
    quiet, _ = simulate_year(np.random.default_rng(5), n_days=40, frequency_noise=0.0)
    noisy, _ = simulate_year(np.random.default_rng(5), n_days=40, frequency_noise=0.004)
    relative = noisy["f1"] / quiet["f1"] - 1
    assert abs(relative.std() - 0.004) < 0.0003  # 960 draws: the sd's standard error is 0.0001


def test_csv_and_truth_round_trip(tmp_path):
    table, truth = _year(damage_day=2.0, damage_storey=4)
    sidecar = write_year_csv(tmp_path / "y.csv", table, truth)
    assert (tmp_path / "y.csv").read_text().splitlines()[0] == "day,temperature,f1,f2,f3,f4"
    back = read_year_csv(tmp_path / "y.csv")
    for key in table:
        np.testing.assert_allclose(back[key], table[key], rtol=1e-9)
    assert json.loads(sidecar.read_text())["damage_storey"] == 4
    assert read_truth(tmp_path / "y.csv") == truth
    assert read_truth(tmp_path / "missing.csv") is None
    (tmp_path / "bad.csv").write_text("time,temperature,f1\n0,1,2\n")
    with pytest.raises(ValueError, match="header"):
        read_year_csv(tmp_path / "bad.csv")


@pytest.mark.parametrize("kwargs, name", [
    (dict(damage_day=3.0, damage_storey=5), "damage_storey"),
    (dict(damage_day=3.0), "damage_day, damage_storey"),
    (dict(damage_size=1.5), "damage_size"),
    (dict(sets_per_day=0), "sets_per_day"),
    (dict(frequency_noise=-0.1), "frequency_noise"),
])
def test_simulator_bad_input_names_the_argument(kwargs, name):
    with pytest.raises(ValueError, match=name):
        simulate_year(np.random.default_rng(0), **kwargs)
    with pytest.raises(TypeError, match="rng"):
        simulate_year(0)


def test_alarm_rule():
    assert alarm_days([0.1, 0.99, 0.2, 0.97, 0.98, 0.99]).tolist() == [4, 5]
    assert alarm_days([0.1, 0.99, 0.2, 0.97], consecutive=1).tolist() == [1, 3]
    assert alarm_days([0.96, 0.99, 0.999], threshold=0.98, consecutive=2).tolist() == [2]
    assert alarm_days([0.99, 0.5, 0.99, 0.99, 0.99], consecutive=3).tolist() == [4]
    assert alarm_days([0.95, 0.95, 0.95]).tolist() == []  # strictly above the threshold
    with pytest.raises(ValueError, match="threshold"):
        alarm_days([0.5], threshold=1.0)
    with pytest.raises(ValueError, match="consecutive"):
        alarm_days([0.5], consecutive=0)


def test_split_days_groups_by_whole_day():
    day = np.array([1.5, 0.0, 0.5, 1.0, 3.2])
    groups = split_days(day, day * 10, np.column_stack([day + 1, day + 2]))
    assert [g[0] for g in groups] == [0, 1, 3]
    np.testing.assert_array_equal(groups[1][1], [10.0, 15.0])
    assert groups[2][2].shape == (1, 2)
    with pytest.raises(ValueError, match="frequencies"):
        split_days(day, day, np.ones((4, 2)))
    with pytest.raises(ValueError, match="frequencies"):
        split_days(day, day, -np.ones((5, 2)))


def _sampler(storey, n=2, seed=0):
    building = ShearBuilding(MASSES[:n], STIFFNESSES[:n])
    return ChangeModelSampler(building, storey, EnvironmentPrior(daily_hazard=0.2), 12, np.random.default_rng(seed))


def test_day_loglikes_equal_the_gaussian_density_of_every_set():
    sampler = _sampler(storey=2)
    rng = np.random.default_rng(1)
    days = [(rng.uniform(-8, 25, k), np.exp(rng.normal(0, 0.01, (k, 2))) * [3.0, 7.0]) for k in (3, 5, 2)]
    for temperature, freqs in days:
        sampler.history.append(temperature, np.log(freqs) - sampler.log_nominal)
    phi = sampler.sample_prior(7)
    l0, l1 = sampler.day_loglikes(phi, 0)
    p = sampler.prior
    for i in range(7):
        theta = np.exp(phi[i, :2])
        alpha, beta, sigma, delta = phi[i, 2], phi[i, 3], np.exp(phi[i, 4]), phi[i, 5]
        for k, (temperature, freqs) in enumerate(days):
            c = 1 + alpha * (temperature - p.reference_temperature) + beta * np.minimum(temperature, 0)
            for damaged, value in ((False, l0[i, k]), (True, l1[i, k])):
                ratios = theta * ([1, 1 - delta] if damaged else [1, 1])
                model = np.log(sampler.building.modes(ratios)[0][0])[None, :] + 0.5 * np.log(c)[:, None]
                resid = np.log(freqs) - model
                expected = np.sum(-0.5 * np.log(2 * np.pi * sigma ** 2) - 0.5 * resid ** 2 / sigma ** 2)
                assert value == pytest.approx(expected, rel=1e-9, abs=1e-9)


def test_damage_day_is_summed_out_exactly():
    sampler = _sampler(storey=1)
    rng = np.random.default_rng(2)
    l0, l1 = rng.normal(-3, 2, (4, 5)), rng.normal(-3, 2, (4, 5))
    total, log_p = sampler.log_marginal(l0, l1)
    p = sampler.prior.daily_hazard
    for i in range(4):
        terms = [p * (1 - p) ** (d - 1) * np.exp(l0[i, :d].sum() + l1[i, d:].sum()) for d in range(1, 5)]
        unchanged = (1 - p) ** 4 * np.exp(l0[i].sum())
        assert total[i] == pytest.approx(np.log(sum(terms) + unchanged), rel=1e-12)
        assert np.exp(log_p[i]) == pytest.approx(sum(terms) / (sum(terms) + unchanged), rel=1e-10)
    no_damage = _sampler(storey=None)
    total0, log_p0 = no_damage.log_marginal(l0, None)
    np.testing.assert_allclose(total0, l0.sum(axis=1))
    assert np.all(log_p0 == -np.inf)


def _days(seed, n_days=4, damage_day=None):
    table, _ = simulate_year(np.random.default_rng(seed), masses=MASSES[:2], stiffnesses=STIFFNESSES[:2],
                             n_days=n_days, sets_per_day=6, damage_day=damage_day,
                             damage_storey=None if damage_day is None else 2, damage_size=0.1)
    return split_days(table["day"], table["temperature"], np.column_stack([table["f1"], table["f2"]]))


def test_monitor_is_reproducible_and_shares_the_first_day():
    building = ShearBuilding(MASSES[:2], STIFFNESSES[:2])
    runs = []
    for _ in range(2):
        monitor = EnvironmentMonitor(building, n_particles=40, rng=np.random.default_rng(7))
        runs.append([monitor.update(t, f) for _, t, f in _days(1)])
    first = runs[0][0]
    assert len({m.log_evidence for m in first.models}) == 1  # day 0: no damage yet in any model
    np.testing.assert_allclose(first.model_probabilities, [0.5, 0.25, 0.25])
    assert [d.p_damage for d in runs[0]] == [d.p_damage for d in runs[1]]
    assert first.p_damage == 0.0


def test_monitor_sees_a_large_loss_in_its_storey():
    building = ShearBuilding(MASSES[:2], STIFFNESSES[:2])
    monitor = EnvironmentMonitor(building, n_particles=100, rng=np.random.default_rng(0))
    records = [monitor.update(t, f) for _, t, f in _days(4, n_days=8, damage_day=5.0)]
    assert max(r.p_damage for r in records[:5]) < 0.5
    assert records[-1].p_damage > 0.99 and records[-1].storey == 2
    assert abs(records[-1].damage_size - 0.1) < 0.02
    assert monitor.n_particle_evaluations > 0 and monitor.n_set_evaluations > monitor.n_particle_evaluations


def test_monitor_bad_input_names_the_argument():
    building = ShearBuilding(MASSES[:2], STIFFNESSES[:2])
    with pytest.raises(TypeError, match="rng"):
        EnvironmentMonitor(building, rng=0)
    with pytest.raises(TypeError, match="building"):
        EnvironmentMonitor("house", rng=np.random.default_rng(0))
    with pytest.raises(ValueError, match="threshold"):
        EnvironmentMonitor(building, threshold=2.0, rng=np.random.default_rng(0))
    monitor = EnvironmentMonitor(building, n_particles=20, rng=np.random.default_rng(0))
    with pytest.raises(ValueError, match="frequencies"):
        monitor.update(np.zeros(3), np.ones((3, 3)))
    with pytest.raises(ValueError, match="temperature"):
        monitor.update(np.zeros(2), np.ones((3, 2)))
    with pytest.raises(ValueError, match="damage_bounds"):
        EnvironmentPrior(damage_bounds=(0.3, 0.1))
    with pytest.raises(ValueError, match="storey"):
        ChangeModelSampler(building, 3, EnvironmentPrior(), 20, np.random.default_rng(0))


def test_mismatched_temperature_laws_are_the_eigenproblem_of_their_storeys():
    lagged, _ = _year(law=ThermalLaw(alpha_spread=0.3, thermal_lag_hours=6.0), damage_day=2.0, damage_storey=1)
    plain, _ = _year(damage_day=2.0, damage_storey=1)
    np.testing.assert_array_equal(lagged["temperature"], plain["temperature"])  # the same draws
    keep = np.exp(-6.0 / 6.0)  # 4 sets a day: 6 h apart, time constant 6 h
    structure = np.empty_like(plain["temperature"])
    structure[0] = plain["temperature"][0]
    for k in range(1, structure.size):
        structure[k] = keep * structure[k - 1] + (1 - keep) * plain["temperature"][k]
    alphas = -0.0015 * np.array([0.7, 0.9, 1.1, 1.3])
    ratios = 1 + alphas[None, :] * (structure - 10.0)[:, None] - 0.015 * np.minimum(structure, 0)[:, None]
    ratios[plain["day"] >= 2.0, 0] *= 0.95
    expected = ShearBuilding(MASSES, STIFFNESSES).modes(ratios)[0]
    observed = np.column_stack([lagged[f"f{r}"] for r in range(1, 5)])
    np.testing.assert_allclose(observed, expected, rtol=1e-12)
    with pytest.raises(ValueError, match="thermal_lag_hours"):
        _year(law=ThermalLaw(thermal_lag_hours=-1.0))
