"""The shake-table study end to end on a tiny variant (one case, 4 s)."""

import json

import numpy as np

from seqbayes.studies import shake_table


def test_cli_writes_tables_summary_and_figures(tmp_path):
    argv = ["--cases", "wc1", "--duration", "4", "--members", "60", "--level", "3", "--ref-walkers", "8",
            "--ref-steps", "10", "--output", str(tmp_path)]
    assert shake_table.main(argv) == 0
    summary = json.loads((tmp_path / "summary.json").read_text())
    case = summary["cases"][0]
    assert case["case"] == "wc1" and len(case["sgenmcmc"]["mean"]) == 3
    assert np.all(np.isfinite(case["ekf"]["mean"])) and np.all(np.isfinite(case["reference"]["sd"]))
    assert "theta_1" in (tmp_path / "table2.md").read_text()
    for name in ("fig4_drifts_wc1.png", "fig6_convergence.png", "fig7_posteriors_wc1.png"):
        assert (tmp_path / name).stat().st_size > 1000


def test_masses_reproduce_the_stated_period():
    b = shake_table.building_of(shake_table.CASES["wc1"])
    assert abs(1 / b.modes(np.ones(3))[0][0, 0] - 0.47) < 0.02
