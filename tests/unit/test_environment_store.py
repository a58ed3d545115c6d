"""Identified frequencies with their temperature covariate as run-store datasets (issue 25): the
no-damage model through ``seqbayes init / update / status`` and a TOML file."""

from __future__ import annotations

import json

import numpy as np
import pytest

from seqbayes import cli
from seqbayes.structural.environment import ChangeModelSampler, EnvironmentPrior, FrequencyLikelihood
from seqbayes.structural.structures import ShearBuilding
from seqbayes.studies.environment import MASSES, STIFFNESSES, simulate_year, write_year_csv

MODULE = f"""
from seqbayes.structural.environment import FrequencyLikelihood
loglike = FrequencyLikelihood({list(MASSES[:2])}, {list(STIFFNESSES[:2])})
"""

CONFIG = """\
[model]
name = "frequencies-under-temperature"
likelihood = "envstoremodel:loglike"
[data]
columns = ["temperature", "f1", "f2"]
format = "columns"
[priors]
theta_1 = { dist = "lognorm", args = [0.1] }
theta_2 = { dist = "lognorm", args = [0.1] }
alpha = { dist = "norm", scale = 0.005 }
beta = { dist = "norm", scale = 0.03 }
sigma = { dist = "loguniform", args = [0.0005, 0.05] }
[sampler]
type = "SMC"
n_samples = 300
seed = 3
"""


def test_frequency_likelihood_is_the_monitors_no_damage_density():
    like = FrequencyLikelihood(MASSES[:2], STIFFNESSES[:2])
    sampler = ChangeModelSampler(ShearBuilding(MASSES[:2], STIFFNESSES[:2]), None, EnvironmentPrior(), 10,
                                 np.random.default_rng(0))
    rng = np.random.default_rng(1)
    temperature = rng.uniform(-9, 25, 7)
    freqs = np.exp(rng.normal(0, 0.01, (7, 2))) * sampler.building.modes([1, 1])[0]
    sampler.history.append(temperature, np.log(freqs) - sampler.log_nominal)
    phi = sampler.sample_prior(5)
    expected, _ = sampler.day_loglikes(phi, 0)
    theta = np.column_stack([np.exp(phi[:, :2]), phi[:, 2:4], np.exp(phi[:, 4])])
    np.testing.assert_allclose(like(theta, {"temperature": temperature, "f1": freqs[:, 0], "f2": freqs[:, 1]}),
                               expected[:, 0], rtol=1e-10)
    np.testing.assert_allclose(like(theta, np.column_stack([temperature, freqs])), expected[:, 0], rtol=1e-10)
    with pytest.raises(ValueError, match="data"):
        like(theta, {"temperature": temperature})
    with pytest.raises(ValueError, match="theta"):
        like(theta[:, :3], np.column_stack([temperature, freqs]))


def test_a_few_days_through_the_command_line(tmp_path, capsys):
    (tmp_path / "envstoremodel.py").write_text(MODULE)
    (tmp_path / "run.toml").write_text(CONFIG)
    table, truth = simulate_year(np.random.default_rng(2), masses=MASSES[:2], stiffnesses=STIFFNESSES[:2],
                                 n_days=3, sets_per_day=24)
    files = []
    for day in range(3):
        rows = np.floor(table["day"]) == day
        path = tmp_path / f"day{day}.csv"  # the day column is extra: the run reads its columns by name
        write_year_csv(path, {k: v[rows] for k, v in table.items()}, truth)
        files.append(str(path))
    assert cli.main(["init", str(tmp_path / "run.toml"), str(tmp_path / "run.nc")]) == 0
    assert cli.main(["update", str(tmp_path / "run.nc"), *files, "-q"]) == 0
    capsys.readouterr()
    assert cli.main(["status", str(tmp_path / "run.nc"), "--json"]) == 0
    status = json.loads(capsys.readouterr().out)
    assert len(status["steps"]) == 3
    parameters = status["steps"][-1]["parameters"]
    truth = {"theta_1": 1.0, "theta_2": 1.0, "alpha": -0.0015, "beta": -0.015, "sigma": 0.004}
    for name, value in truth.items():
        assert parameters[name]["lower"] < value < parameters[name]["upper"], name
    assert parameters["sigma"]["sd"] < 0.0005


def test_environment_command_raises_the_alarm_on_a_short_year(tmp_path, capsys):
    table, truth = simulate_year(np.random.default_rng(5), masses=MASSES[:2], stiffnesses=STIFFNESSES[:2],
                                 n_days=8, sets_per_day=12, damage_day=5.0, damage_storey=1, damage_size=0.1)
    write_year_csv(tmp_path / "year.csv", table, truth)
    masses, stiffness = ",".join(map(str, MASSES[:2])), ",".join(map(str, STIFFNESSES[:2]))
    argv = ["environment", str(tmp_path / "year.csv"), "--masses", masses, "--stiffness", stiffness,
            "--particles", "60", "--every", "1", "--json", str(tmp_path / "out.json"),
            "--report", str(tmp_path / "year <b>.html")]
    assert cli.main(argv) == 0
    out = capsys.readouterr().out
    assert "ALARM" in out
    summary = json.loads((tmp_path / "out.json").read_text())
    assert len(summary["p_damage"]) == 8
    assert summary["alarm_day"] == 6 and summary["element"] == "1"  # damage from day 5: alarm after days 5 and 6
    assert max(summary["p_damage"][:5]) < 0.5
    # the report: the alarm, the learned law, one row a day with P(damage) as the JSON has it
    page = (tmp_path / "year <b>.html").read_text()
    assert "Alarm: raised" in page and "thermal_lag_h" in page
    assert page.count("<td class=''>ALARM</td>") == len(summary["alarm_days"]) > 0
    for p in summary["p_damage"]:
        assert f"<td class=''>{p:.3g}</td>" in page
    assert cli.main(["environment", str(tmp_path / "year.csv"), "--masses", "1,x", "--stiffness", stiffness]) == 2
    assert "--masses" in capsys.readouterr().err
