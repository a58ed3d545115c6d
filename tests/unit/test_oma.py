"""Operational modal analysis (issue 25, item 2; issue 38): SSI-cov against exact covariances, the automated
identification of a simulated ambient record, and the data-file row it produces."""

import numpy as np
import pytest
from scipy.linalg import expm, solve_discrete_lyapunov

from seqbayes.structural.oma import (
    ambient_record,
    output_covariances,
    record_row,
    ssi_cov,
    ssi_poles,
    stabilisation_diagram,
)
from seqbayes.structural.structures import ShearBuilding, mac


def _exact_covariances(building, dt, lags):
    """``R_i = C A^i Sigma C^T`` of the discretised building driven by white state noise (no data)."""
    n = building.n_storeys
    A_c, _ = building.continuous_state_space(np.ones(n))
    A = expm(A_c[0] * dt)
    C = building.observation_matrix(np.ones(n))[0]
    sigma = solve_discrete_lyapunov(A, np.eye(2 * n))
    return np.stack([C @ np.linalg.matrix_power(A, i) @ sigma @ C.T for i in range(lags)])


def test_two_dof_modes_from_exact_covariances():
    building = ShearBuilding([1e3, 1.2e3], [1e6, 8e5], damping_ratios=(0.02, 0.03))
    covariances = _exact_covariances(building, 0.01, 20)
    poles = ssi_poles(covariances, 0.01, order=4, block_rows=8)
    frequencies, shapes = building.modes(np.ones(2))
    np.testing.assert_allclose(poles.frequencies, frequencies[0], rtol=1e-6)
    np.testing.assert_allclose(poles.damping_ratios, building.modal_damping_ratios(np.ones(2))[0], rtol=1e-6)
    # accelerations of a proportionally damped mode are proportional to its (real) shape: MAC 1
    unit = shapes[0] / np.linalg.norm(shapes[0], axis=0)
    np.testing.assert_allclose(np.abs(np.sum(poles.shapes.conj() * unit, axis=0)) ** 2, 1.0, atol=1e-6)


def test_covariances_exact_on_small_series():
    y = np.array([[1.0, 2.0], [3.0, 0.0], [2.0, 1.0]])
    R = output_covariances(y, 1)
    centred = y - y.mean(axis=0)
    np.testing.assert_allclose(R[0], centred.T @ centred / 3)
    np.testing.assert_allclose(R[1], centred[1:].T @ centred[:-1] / 2)


def test_bad_input_is_named():
    good = np.random.default_rng(0).standard_normal((500, 2))
    with pytest.raises(ValueError, match="y:"):
        output_covariances(np.full((10, 2), np.nan), 2)
    with pytest.raises(ValueError, match="max_lag"):
        output_covariances(good, 500)
    with pytest.raises(ValueError, match="dt"):
        stabilisation_diagram(good, dt=0.0)
    with pytest.raises(ValueError, match="max_order"):
        stabilisation_diagram(good, 0.01, max_order=5)
    with pytest.raises(ValueError, match="block_rows"):
        ssi_poles(output_covariances(good, 5), 0.01, order=2, block_rows=4)
    with pytest.raises(ValueError, match="order"):
        ssi_poles(output_covariances(good, 9), 0.01, order=20, block_rows=5)
    with pytest.raises(ValueError, match="covariances"):
        ssi_poles(np.zeros((10, 2, 3)), 0.01, order=2, block_rows=5)
    with pytest.raises(ValueError, match="n_modes"):
        ssi_cov(good, 0.01, n_modes=50)  # white noise has no stable modes to speak of
    with pytest.raises(ValueError, match="temperature"):
        record_row(good, 0.01, day=1.0, temperature=np.nan, n_modes=1)


@pytest.mark.slow
def test_ambient_record_four_storeys_within_half_percent():
    """The simulated years' building (f = 2.09 .. 10.34 Hz, 2 % damping) with a 5 % loss in storey
    2, twenty minutes at 100 Hz with 5 % measurement noise: every frequency within 0.5 % (the issue's
    acceptance bullet) and every shape with MAC > 0.99, the four modes found by the stabilisation
    diagram alone; damping ratios within 25 % (5 rms errors). Over 20 seeds of the undamaged building
    (``benchmarks/bench_oma.py --seeds 20``) the largest error was 0.29 % (mode 4; rms 0.10-0.13 %,
    docs/oma.md): 0.5 % is about four rms errors."""
    building = ShearBuilding([2.0e5, 2.0e5, 2.0e5, 1.6e5], [3.0e8, 2.6e8, 2.2e8, 1.8e8], damping_ratios=(0.02, 0.02))
    theta = np.array([1.0, 0.95, 1.0, 1.0])
    y = ambient_record(building, theta, duration=1200.0, dt=0.01, rng=3)
    modes = ssi_cov(y, 0.01)  # no n_modes: the modes stable over at least half the orders
    frequencies, shapes = building.modes(theta)
    assert modes.frequencies.size == 4
    assert np.max(np.abs(modes.frequencies / frequencies[0] - 1)) < 0.005
    assert np.all(np.diag(mac(modes.shapes, shapes[0])) > 0.99)
    np.testing.assert_allclose(modes.damping_ratios, building.modal_damping_ratios(theta)[0], rtol=0.25)
    row = record_row(y, 0.01, day=3.5, temperature=-2.0, n_modes=4)
    np.testing.assert_array_equal(row, np.concatenate([[3.5, -2.0], modes.frequencies]))


def test_bench_oma_writes_a_data_file_with_its_truth_sidecar(tmp_path):
    """``benchmarks/bench_oma.py --out``: the header the workflow reads, the two rows of 2-minute records
    within 1.5 % of the truth, and the truth sidecar. (2-minute records are short for the automated
    defaults: ``bench_oma.py --seeds 20 --duration 120`` gives rms errors of 0.50 and 0.43 % for modes 1 and
    2, and for modes 3 and 4 ``n_modes=4`` takes a spurious cluster in some of the 20 seeds (largest errors
    24-25 %); docs/oma.md. The accuracy of 20-minute records is the slow test above.)"""
    import importlib.util
    import json
    from pathlib import Path

    spec = importlib.util.spec_from_file_location(
        "bench_oma", Path(__file__).resolve().parents[2] / "benchmarks" / "bench_oma.py")
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    out = tmp_path / "year.csv"
    report = bench.main(["--out", str(out), "--days", "1", "--per-day", "2", "--duration", "120",
                         "--damage-day", "0.5", "--damage-storey", "3"])
    assert out.read_text().splitlines()[0] == "day,temperature,f1,f2,f3,f4"
    rows = np.loadtxt(out, delimiter=",", skiprows=1)
    assert rows.shape == (2, 6) and rows[:, 0].tolist() == [0.0, 0.5]
    truth = np.array(report["data_file"]["true_frequencies"])
    assert np.max(np.abs(rows[:, 2:] / truth - 1)) < 0.015
    sidecar = json.loads(out.with_suffix(".json").read_text())
    assert (sidecar["damage_day"], sidecar["damage_storey"], sidecar["damage_size"]) == (0.5, 3, 0.05)
    with pytest.raises(SystemExit):
        bench.main(["--out", str(out), "--json", str(out.with_suffix(".json"))])  # would overwrite the sidecar
