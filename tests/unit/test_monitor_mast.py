"""The real guyed mast through a monitor store day by day (a reduced form of benchmarks/bench_monitor_mast.py:
three days, the default 128 particles; with 48 the third day's P(damage) reached 0.9993: too few particles
for the 12 static parameters of seven modes): no alarm, and the first mode's frequency falls with temperature (PROVENANCE.md: about
1 % from cool to hot days), with a finite 95 % interval for every mode's coefficient."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))


@pytest.mark.slow
def test_three_days_of_the_mast_raise_no_alarm_and_learn_the_temperature_law(tmp_path):
    from bench_monitor_mast import run

    result = run(n_days=3, particles=128, seed=0, folder=tmp_path)
    status = result["status"]
    assert result["days"] == 3 and len(status["steps"]) == 3
    assert not status["alarm"] and max(s["p_damage"] for s in status["steps"]) < 0.5
    coefficients = status["environment"]["coefficients"]
    for i in range(len(result["reference"])):
        c = coefficients[f"temperature_{i + 1}"]
        assert all(math.isfinite(c[k]) for k in ("mean", "lower", "upper")) and c["lower"] < c["mean"] < c["upper"]
    assert coefficients["temperature_1"]["mean"] < 0
