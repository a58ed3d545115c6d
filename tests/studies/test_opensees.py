"""The OpenSees frame example (seqbayes.models.opensees_frame) and its run through the command line.

Needs OpenSees (``pip install opensees``, the ``seqbayes[opensees]`` extra; the ``test`` extra, which
``make test`` installs, includes it); without it every test here but the first is skipped with that reason. The 20-campaign run, its wall time and its check
against the exact grid reference are in benchmarks/bench_opensees.py (docs/benchmarks.md).
"""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from seqbayes.models import opensees_frame as frame

ROOT = Path(__file__).resolve().parents[2]
NEEDS_OPENSEES = "OpenSees is not installed (pip install opensees, or pip install 'seqbayes[opensees]')"


def test_without_opensees_the_module_imports_and_a_solve_says_what_to_install(monkeypatch):
    monkeypatch.setitem(sys.modules, "opensees", None)   # import opensees -> ImportError
    monkeypatch.setattr(frame, "_SESSION", {"pid": None, "ops": None, "ground": None})
    assert frame.opensees_available() is False
    with pytest.raises(ImportError, match=r"pip install opensees"):
        frame.loglike(np.array([[1.0, 0.03, 0.3]]), np.zeros((5, 4)))


def _newmark_linear(kappa, zeta, ground):
    """The elastic frame by Newmark's average-acceleration rule in numpy: absolute floor accelerations ``(n-1, 2)``."""
    k1, k2, m = kappa * frame.STIFFNESS, frame.STIFFNESS, frame.MASS
    mass = m * np.eye(2)
    stiffness = np.array([[k1 + k2, -k2], [-k2, k2]])
    damping = 2.0 * zeta * frame.OMEGA_1 * mass
    dt, beta, gamma = frame.DT, 0.25, 0.5
    u, v, a = np.zeros(2), np.zeros(2), np.zeros(2)   # at rest, ground[0] = 0
    effective = stiffness + gamma / (beta * dt) * damping + mass / (beta * dt**2)
    out = []
    for g in ground[1:]:
        force = -mass @ np.ones(2) * g
        rhs = (force + mass @ (u / (beta * dt**2) + v / (beta * dt) + (0.5 / beta - 1.0) * a)
               + damping @ (gamma / (beta * dt) * u + (gamma / beta - 1.0) * v + dt * (0.5 * gamma / beta - 1.0) * a))
        u_new = np.linalg.solve(effective, rhs)
        a_new = (u_new - u) / (beta * dt**2) - v / (beta * dt) - (0.5 / beta - 1.0) * a
        v = v + dt * ((1.0 - gamma) * a + gamma * a_new)
        u, a = u_new, a_new
        out.append(a + g)
    return np.array(out)


def test_elastic_response_matches_newmark_by_hand():
    pytest.importorskip("opensees.openseespy", reason=NEEDS_OPENSEES)
    ground = frame.excitation(3) * 0.05               # far below yield: the frame stays elastic
    ground = ground - ground[0]                        # at rest at t_0
    theta = np.array([[0.9, 0.03], [1.1, 0.01]])
    got = frame.response(theta, ground)
    for row, (kappa, zeta) in enumerate(theta):
        expected = _newmark_linear(kappa, zeta, ground)
        assert np.allclose(got[row], expected, rtol=1e-8, atol=1e-10 * np.abs(expected).max())


def test_yielding_makes_the_response_nonlinear_and_loglike_is_the_gaussian_of_the_residuals():
    pytest.importorskip("opensees.openseespy", reason=NEEDS_OPENSEES)
    ground = frame.excitation(12)
    small = frame.response([[1.0, 0.03]], ground * 0.05)[0]
    full = frame.response([[1.0, 0.03]], ground)[0]
    # elastic: the response scales with the excitation; the full record yields the first storey
    assert np.max(np.abs(full - 20.0 * small)) > 0.05 * np.max(np.abs(full))
    datasets, kappa = frame.simulate(2, np.random.default_rng(5))
    assert datasets[0].shape == (frame.WINDOW_STEPS, 4) and kappa[0] == 0.98
    theta = np.array([[0.97, 0.03, 0.3], [0.9, 0.05, 0.5]])
    residual = datasets[1][1:, None, 2:] - frame.response(theta, datasets[1][:, 1]).transpose(1, 0, 2)
    n = residual.shape[0] * 2
    expected = [np.sum(-0.5 * (residual[:, i] / s) ** 2 - np.log(s) - 0.5 * np.log(2 * np.pi))
                for i, s in enumerate(theta[:, 2])]
    assert np.allclose(frame.loglike(theta, datasets[1]), expected, rtol=1e-12)
    assert residual.shape == (frame.WINDOW_STEPS - 1, 2, 2) and n == 150
    with pytest.raises(ValueError, match="theta"):
        frame.loglike(theta[:, :2], datasets[1])
    with pytest.raises(ValueError, match="data"):
        frame.loglike(theta, datasets[1][:, :3])


def _seqbayes(*args, cwd):
    done = subprocess.run([sys.executable, "-m", "seqbayes.cli", *args], cwd=cwd, capture_output=True, text=True)
    assert done.returncode == 0, done.stdout + done.stderr
    return done.stdout


@pytest.mark.slow
def test_the_example_runs_through_the_cli_with_process_workers_identical_to_serial(tmp_path):
    pytest.importorskip("opensees.openseespy", reason=NEEDS_OPENSEES)
    paths = frame.write_campaigns(tmp_path, 3, seed=2026)
    toml = (ROOT / "examples" / "opensees" / "frame.toml").read_text()
    toml = re.sub(r"n_samples = \d+", "n_samples = 16", toml)
    toml = re.sub(r"n_inner = \d+", "n_inner = 4", toml)
    (tmp_path / "frame.toml").write_text(toml)                                    # 2 worker processes
    (tmp_path / "serial.toml").write_text(toml.replace('executor = "processes"', 'executor = "serial"'))
    for config, run in (("frame.toml", "run.nc"), ("serial.toml", "serial.nc")):
        assert "SEMC with N = 16" in _seqbayes("init", config, run, cwd=tmp_path)
        out = _seqbayes("update", "-q", run, *[p.name for p in paths], cwd=tmp_path)
        assert len(re.findall(r"likelihood evaluations in", out)) == 3
    status = _seqbayes("status", "run.nc", cwd=tmp_path)
    assert "steps: 3" in status and "kappa" in status and "sigma" in status
    _seqbayes("report", "run.nc", "-o", "run.html", cwd=tmp_path)
    assert (tmp_path / "run.html").stat().st_size > 10_000
    from seqbayes.store import open_run

    parallel, serial = open_run(tmp_path / "run.nc").result, open_run(tmp_path / "serial.nc").result
    for a, b in zip(parallel.steps, serial.steps):
        assert a.posterior.tobytes() == b.posterior.tobytes()
    # the stiffness follows the simulated loss: within the posterior's 99.9 % interval at every campaign
    truth = np.loadtxt(tmp_path / "true_kappa.csv", delimiter=",", skiprows=1)[:, 1]
    for s, record in enumerate(parallel.steps):
        lo, hi = record.quantile([0.0005, 0.9995])[:, 0]
        assert lo - 0.01 < truth[s] < hi + 0.01, (s, lo, hi, truth[s])
