"""The misspecification matrix's simulator (studies/environment_cells.py): every cell's year is the eigenproblem of
the stiffness its truth sidecar describes, the lag and the knee are the stated functions, the noise and the missing
modes have the stated rates, and the cells share their random numbers."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from seqbayes.structural.structures import ShearBuilding
from seqbayes.studies.environment import read_truth
from seqbayes.studies.environment_cells import (CELLS, Damage, Misspecification, YearBase, cell_year, freezing_knee,
                                                read_cell_year, simulate_cell_year, structure_temperature,
                                                write_cell_year)

SMALL = YearBase(n_days=16, sets_per_day=4)
EVERYTHING = Misspecification(thermal_lag_hours=6.0, sensitivity_scatter=0.3, knee_location=(-2.0, 2.0),
                              knee_width=(0.5, 2.0), humidity_effect=-2e-4, humidity_in_csv=True,
                              frequency_noise=(0.0, 0.0))


def _rebuild(table, truth):
    """The frequencies (S, n) from the CSV's columns and the sidecar's settings alone, one eigenproblem per set."""
    s, base, cell = truth.settings["drawn"], truth.settings["base"], truth.settings["cell"]
    structure = structure_temperature(table["day"], table["temperature"], cell["thermal_lag_hours"])
    a, b = np.array(s["alpha_factors"]), np.array(s["beta_factors"])
    knee = freezing_knee(structure, s["knee_location"], s["knee_width"])
    ratios = 1 + base["alpha"] * a * (structure[:, None] - base["reference_temperature"]) + base["beta"] * b * knee[:, None]
    ratios *= (1 + cell["humidity_effect"] * (table["humidity"] - base["reference_humidity"]))[:, None]
    if truth.damage_day is not None:
        ratios[table["day"] >= truth.damage_day, truth.damage_storey - 1] *= 1 - truth.damage_size
    building = ShearBuilding(s["masses"], s["stiffnesses"])
    return np.vstack([building.modes(r)[0][0] for r in ratios])


def test_a_year_is_the_eigenproblem_its_truth_describes(tmp_path):
    table, truth = simulate_cell_year(np.random.default_rng(1), EVERYTHING, base=SMALL, damage=Damage(12.0, 3, 0.05))
    write_cell_year(tmp_path / "y.csv", table, truth)
    back, sidecar = read_cell_year(tmp_path / "y.csv"), read_truth(tmp_path / "y.csv")
    observed = np.column_stack([back[f"f{r}"] for r in range(1, 5)])
    np.testing.assert_allclose(observed, _rebuild(back, sidecar), rtol=1e-8)  # the CSV's 10 digits
    drawn = sidecar.settings["drawn"]
    assert all(0.7 <= v <= 1.3 for v in drawn["alpha_factors"] + drawn["beta_factors"])
    assert -2 <= drawn["knee_location"] <= 2 and 0.5 <= drawn["knee_width"] <= 2
    assert np.all(np.abs(np.array(drawn["masses"]) / SMALL.masses - 1) <= 0.05)
    assert np.all(np.abs(np.array(drawn["stiffnesses"]) / SMALL.stiffnesses - 1) <= 0.10)
    assert sidecar.settings["nominal"]["masses"] == list(SMALL.masses)
    assert (sidecar.damage_day, sidecar.damage_storey, sidecar.damage_size) == (12.0, 3, 0.05)


def test_the_first_order_lag_is_exact_for_a_step_and_damps_a_daily_cycle():
    times = np.arange(0, 3, 1 / 24)
    lagged = structure_temperature(times, np.where(times > 0, 10.0, 0.0), 6.0)
    np.testing.assert_allclose(lagged, 10 * (1 - np.exp(-times * 24 / 6)), atol=1e-12)
    # a daily sine at steady state: amplitude 1 / sqrt(1 + (w tau)^2), lag atan(w tau) / w (exact as the step -> 0)
    fine = np.arange(0, 12, 1 / 1440)
    out = structure_temperature(fine, np.sin(2 * np.pi * fine), 6.0)[-1440:]
    wtau = 2 * np.pi * 6 / 24
    assert np.ptp(out) / 2 == pytest.approx(1 / np.sqrt(1 + wtau**2), rel=2e-3)
    peak = fine[-1440:][np.argmax(out)] % 1
    assert peak - 0.25 == pytest.approx(np.arctan(wtau) / (2 * np.pi), abs=2 / 1440)
    np.testing.assert_array_equal(structure_temperature(times, times, 0.0), times)


def test_the_smooth_knee_tends_to_the_kink_and_misses_it_by_at_most_w_log_2():
    x = np.linspace(-10, 10, 2001)
    for width in (0.5, 2.0):
        gap = freezing_knee(x, 1.0, width) - np.minimum(x - 1.0, 0)
        assert gap.max() <= 1e-15 and gap.min() == pytest.approx(-width * np.log(2), abs=1e-12)
    np.testing.assert_allclose(freezing_knee(x, 1.0, 1e-4), np.minimum(x - 1.0, 0), atol=1e-4)


def test_noise_and_missing_modes_have_the_stated_rates():
    cell = CELLS["noise_missing"]
    base = YearBase(n_days=365, sets_per_day=24)
    noisy, _ = simulate_cell_year(np.random.default_rng(4), cell, base=base)
    exact, _ = simulate_cell_year(np.random.default_rng(4), replace(cell, frequency_noise=(0.0, 0.0), report_std=False,
                                                                    missing_fraction=0.0), base=base)
    f = np.column_stack([noisy[f"f{r}"] for r in range(1, 5)])
    sf = np.column_stack([noisy[f"sf{r}"] for r in range(1, 5)])
    f0 = np.column_stack([exact[f"f{r}"] for r in range(1, 5)])
    missing = np.isnan(f)
    share = missing.any(axis=1).mean()
    assert abs(share - 0.2) < 4 * np.sqrt(0.2 * 0.8 / f.shape[0])  # binomial: 4 standard errors
    assert not missing.all(axis=1).any() and np.array_equal(np.isnan(sf), missing)
    relative = sf[~missing] / f[~missing]
    assert relative.min() >= 0.003 and relative.max() <= 0.005
    z = (f[~missing] - f0[~missing]) / (relative * f0[~missing])  # the error in its own sd: N(0, 1) up to O(sd)
    assert abs(z.mean()) < 4 / np.sqrt(z.size) and abs(z.std() - 1) < 4 / np.sqrt(2 * z.size) + 0.006


def test_cells_share_their_years_random_numbers_and_a_seed_reproduces_a_year():
    base = YearBase(n_days=10)
    a, ta = cell_year("lag0", "loss2", 3, base=base, damage_window=(2, 8))
    b, tb = cell_year("lag6", "loss2", 3, base=base, damage_window=(2, 8))
    c, _ = cell_year("lag0", "loss2", 3, base=base, damage_window=(2, 8))
    np.testing.assert_array_equal(a["temperature"], b["temperature"])
    assert ta.settings["drawn"]["masses"] == tb.settings["drawn"]["masses"] and ta.damage_day == tb.damage_day
    assert not np.array_equal(a["f1"], b["f1"])
    for key in a:
        np.testing.assert_array_equal(a[key], c[key])
    other, _ = cell_year("lag0", "loss2", 4, base=base, damage_window=(2, 8))
    assert not np.array_equal(a["temperature"], other["temperature"])
    calibration, _ = cell_year("lag0", "loss2", 3, base=base, damage_window=(2, 8), purpose=1)
    assert not np.array_equal(a["temperature"], calibration["temperature"])
    healthy, th = cell_year("humidity", "healthy", 0, base=base, damage_window=(2, 8))
    assert th.damage_day is None and th.damage_size == 0.0 and "humidity" not in healthy  # not given to the model


def test_the_csv_has_the_interface_columns_and_empty_cells(tmp_path):
    table, truth = cell_year("noise_missing", "healthy", 0, base=YearBase(n_days=3), damage_window=(1, 2))
    write_cell_year(tmp_path / "y.csv", table, truth)
    lines = (tmp_path / "y.csv").read_text().splitlines()
    assert lines[0] == "day,temperature,f1,f2,f3,f4,sf1,sf2,sf3,sf4"
    assert any(",," in line for line in lines[1:])
    back = read_cell_year(tmp_path / "y.csv")
    for key in table:
        np.testing.assert_allclose(back[key], table[key], rtol=1e-9, equal_nan=True)
    assert not list(tmp_path.glob("*.part"))
    (tmp_path / "bad.csv").write_text("time,f1\n0,1\n")
    with pytest.raises(ValueError, match="day,temperature"):
        read_cell_year(tmp_path / "bad.csv")


@pytest.mark.parametrize("make, name", [
    (lambda: Misspecification(thermal_lag_hours=-1.0), "thermal_lag_hours"),
    (lambda: Misspecification(knee_width=(1.0, 0.5)), "knee_width"),
    (lambda: Misspecification(frequency_noise=(0.1, 0.6)), "frequency_noise"),
    (lambda: Misspecification(missing_fraction=1.0), "missing_fraction"),
    (lambda: Misspecification(sensitivity_scatter=1.0), "sensitivity_scatter"),
    (lambda: Damage(10.0, 2, 0.0), "size"),
    (lambda: Damage(10.0, 0, 0.05), "element"),
    (lambda: YearBase(n_days=0), "n_days"),
    (lambda: simulate_cell_year(np.random.default_rng(0), CELLS["lag0"], base=SMALL, damage=Damage(1.0, 5, 0.05)),
     "element 5"),
    (lambda: cell_year("lag99", "healthy", 0), "cell_name"),
    (lambda: cell_year("lag0", "loss7", 0), "kind"),
    (lambda: cell_year("lag0", "healthy", 0, base=SMALL, damage_window=(5, 30)), "damage_window"),
])
def test_bad_input_names_the_argument(make, name):
    with pytest.raises(ValueError, match=name):
        make()
    with pytest.raises(TypeError, match="rng"):
        simulate_cell_year(0, CELLS["lag0"])
