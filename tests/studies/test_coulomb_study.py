"""The Coulomb-friction study of Sec. 6.4 against the acceptance bullets of issue 3.

The study of docs/coulomb_friction.md (``seqbayes example coulomb``: 10 runs, seed 2023, N = 1000,
4 steps, SEMC and SMC, T1 and T2) is run once for the module (~26 s on an idle 2-core
machine), so the page's tables are checked against the current code too
(``test_docs_tables_are_this_run``; ``make docs-regen`` rewrites them).
Tolerances on means over runs: the run-to-run stds measured in that study are <= 0.005 N for
F_mu and <= 0.01 rad/s for omega_n, so the acceptance tolerances (0.06 N, 2 rad/s, 0.25
posterior std) hold with a wide margin; the bounds below were derived for 3 runs and are kept.
"""

import math
import sys
from pathlib import Path

import numpy as np
import pytest

import seqbayes
from seqbayes.models import coulomb as cf
from seqbayes.studies import coulomb as study_mod

N_RUNS = 10
ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def study(tmp_path_factory):
    out = tmp_path_factory.mktemp("coulomb")
    # one process: the seeds do not depend on the workers, and the suite's own workers already use the cores
    return study_mod.run_study(n_runs=N_RUNS, out_dir=out, progress=False, workers=1)


def test_docs_tables_are_this_run(study):
    """docs/coulomb_friction.md shows the tables of this study (the command's defaults), to the
    precision of its 10 runs (the tolerance above the tables)."""
    sys.path.insert(0, str(ROOT / "tools"))
    try:
        import docgen
    finally:
        sys.path.remove(str(ROOT / "tools"))
    differences = docgen.compare_section(ROOT / "docs" / "coulomb_friction.md", "coulomb-tables",
                                         study_mod.tables_markdown(study))
    assert not differences, "run `make docs-regen`:\n" + "\n".join(differences)


@pytest.mark.parametrize("sampler", ["SEMC", "SMC"])
def test_s1_posterior_means_match_exact_reference(study, sampler):
    # 10-run study: mean errors <= 0.06 posterior std (SEMC) and 0.02 (SMC); the largest
    # run-to-run std of a run's error is 0.14 std (SEMC, sigma_phi), so a 3-run mean has a
    # standard error of 0.08 std and the 0.25 is > 2.3 standard errors away.
    ref = study.reference
    for kernel in ("T1", "T2"):
        means = np.array([r.steps[0].mean() for r in study.results[(sampler, kernel)]])
        err = (means.mean(axis=0) - ref.mean) / ref.std
        assert np.all(np.abs(err) < 0.25), (sampler, kernel, err)


def test_semc_t1_tracks_the_measured_friction_and_natural_frequency(study):
    f_mean = study.tables[("F_mu", "SEMC", "T1")][0]
    assert np.all(np.abs(f_mean - np.array(cf.MEASURED_FORCES)) < 0.06), f_mean
    w_mean = study.tables[("omega_n", "SEMC", "T1")][0]
    assert np.all(np.abs(w_mean - cf.OMEGA_N) < 2.0), w_mean


def test_semc_acceptance_rates_within_bounds(study):
    """Every step that moved its particles (SMC^2 moves only when the ESS falls; the first step always)."""
    for kernel in ("T1", "T2"):
        acc = study.acceptance[("SEMC", kernel)]
        assert acc.shape == (N_RUNS, 4)
        assert np.all(np.isfinite(acc[:, 0]))
        moved = acc[np.isfinite(acc)]
        assert np.all((moved >= 0.15) & (moved <= 0.50)), acc


def test_t1_is_the_most_probable_kernel_with_semc(study):
    lnb = study.log_bayes_factor("SEMC", "T1", "T2")
    assert lnb.mean() > 0, lnb
    # every T1 run beats its paired T2 run by more than the run-to-run std
    assert np.all(lnb > 0), lnb


@pytest.mark.parametrize("sampler", ["SEMC", "SMC"])
def test_s1_log_evidence_within_0p3_nats(study, sampler):
    # 10-run study: SEMC -14.594 +- 0.050, SMC -14.559 +- 0.017 (exact -14.556): the 3-run
    # mean's error is ~0.04 +- 0.03 nats, far inside the 0.3.
    z = np.array([r.log_evidence[0] for r in study.results[(sampler, "T1")]])
    assert abs(z.mean() - study.reference.log_evidence) < 0.3, z


def test_s4_log_evidence_spread_is_below_half_a_nat(study):
    # Issue 3: run-to-run std of the cumulative log-evidence at s = 4 below 0.5 nats.
    # Measured in the 10-run study (docs/coulomb_friction.md): 0.21 / 0.24 (SEMC T1 / T2),
    # 0.19 / 0.16 (SMC) nats. With 3 runs a single sample std has only 2 degrees of freedom,
    # so the bullet is asserted on the std pooled over the four (sampler, kernel) cells
    # (8 degrees of freedom): if every true std is <= 0.24, P(pooled > 0.5) =
    # P(chi2_8 > 8 (0.5/0.24)^2 = 34.7) ~ 3e-5. Each cell alone must stay below 0.75
    # (P(chi2_2 > 2 (0.75/0.24)^2) = exp(-9.8) ~ 6e-5 per cell); the paper's are 5-31 nats.
    variances = []
    for sampler in ("SEMC", "SMC"):
        for kernel in ("T1", "T2"):
            z4 = np.array([r.log_evidence[-1] for r in study.results[(sampler, kernel)]])
            assert z4.std(ddof=1) < 0.75, (sampler, kernel, z4)
            variances.append(z4.var(ddof=1))
    assert math.sqrt(np.mean(variances)) < 0.5, variances


def test_single_blas_thread_limits_blas():
    threadpoolctl = pytest.importorskip("threadpoolctl")
    with study_mod.single_blas_thread():
        blas = [p for p in threadpoolctl.threadpool_info() if p["user_api"] == "blas"]
        assert blas and all(p["num_threads"] == 1 for p in blas)


def test_outputs_written(study):
    out = study.out_dir
    text = (out / "tables.md").read_text()
    for label in ("Tables 4-5", "Tables 6-7", "Tables 8-9", "Tables 10-11", "Tables 12-13"):
        assert label in text
    rows = (out / "tables.csv").read_text().splitlines()
    assert rows[0].startswith("quantity,sampler,kernel,step,mean,std")
    assert len(rows) == 1 + 5 * 4 * 4
    for name in ("fig08_log_evidence.png", "fig09_acceptance.png", "fig10_friction.png",
                 "fig11_predictions.png", "fig12_static_T1.png", "fig13_static_T2.png"):
        assert (out / name).stat().st_size > 1000
    runs = sorted((out / "runs").glob("*.nc"))
    assert len(runs) == 4 * N_RUNS
    back = seqbayes.Result.from_netcdf(out / "runs" / "SEMC_T1_run00.nc")
    np.testing.assert_allclose(back.log_evidence, study.results[("SEMC", "T1")][0].log_evidence)
    text = study_mod.summary(study)
    assert "most probable: T1" in text and "Posterior of F_mu per step" in text


def test_same_seed_same_numbers(tmp_path):
    kwargs = dict(n_runs=1, n_samples=64, samplers=("SEMC",), kernels=("T1",), seed=5, progress=False,
                  workers=1, settings={"SEMC": {"n_moves": 1, "tempering_ess": 0.5}})
    a = study_mod.run_study(**kwargs)
    b = study_mod.run_study(**kwargs)
    ra, rb = a.results[("SEMC", "T1")][0], b.results[("SEMC", "T1")][0]
    np.testing.assert_array_equal(ra.log_evidence, rb.log_evidence)
    np.testing.assert_array_equal(ra.steps[-1].posterior, rb.steps[-1].posterior)


def test_bad_arguments():
    with pytest.raises(ValueError, match="n_runs"):
        study_mod.run_study(n_runs=0)
    with pytest.raises(ValueError, match="samplers"):
        study_mod.run_study(n_runs=1, samplers=("MCMC",))
    with pytest.raises(ValueError, match="kernels"):
        study_mod.run_study(n_runs=1, kernels=("T9",))


def test_cli_quick_variant_parses(monkeypatch, tmp_path, capsys):
    calls = {}

    def fake_run_study(**kwargs):
        calls.update(kwargs)
        raise SystemExit(0)

    monkeypatch.setattr(study_mod, "run_study", fake_run_study)
    with pytest.raises(SystemExit):
        study_mod.main(["--quick", "--out", str(tmp_path)])
    assert calls["n_runs"] == 2 and calls["n_samples"] == 1000
    assert math.isclose(0.21 / 4 + 0.23, 0.2825)


@pytest.mark.parametrize("sampler", ["SEMC", "SMC"])
@pytest.mark.parametrize("kernel", ["T1", "T2"])
def test_every_step_matches_the_exact_grid_reference(study, sampler, kernel):
    """All four steps against the exact grid filter (``cf.load_exact_reference``; issue 10).

    ``benchmarks/bench_coulomb_exact.py`` (10 runs, the study's settings) measures per-run errors of at
    most 0.163 posterior sd (means), 13 % (sds) and 0.30 nats (evidence; 0.46 in an earlier 10-run
    measurement), and a run-to-run spread of the mean errors of at most 0.07 sd. The sds have a tail: over 50
    SEMC runs (seeds 2023, 7, 11, 13, 17) the first step's sd error was at most 0.186 (before the importance
    sweeps were fitted to the other half) and 0.157 after, but for one run at 0.284, which one particle of
    1000 at 24 exact sds in sigma_r makes. A run is held to 0.3 sd, 35 % and 0.75 nats; the 10-run mean
    errors, whose standard error is at most 0.04 sd (means) and 0.03 (sds), to 0.2 sd, 10 % and 0.3 nats."""
    exact = cf.load_exact_reference(kernel)
    runs = study.results[(sampler, kernel)]
    mean_err = np.array([[(rec.mean() - exact.mean[s]) / exact.std[s] for s, rec in enumerate(r.steps)] for r in runs])
    sd_err = np.array([[rec.std() / exact.std[s] - 1 for s, rec in enumerate(r.steps)] for r in runs])
    z_err = np.array([[rec.info.log_evidence - exact.log_evidence[s] for s, rec in enumerate(r.steps)] for r in runs])
    assert np.all(np.abs(mean_err) < 0.3), mean_err
    assert np.all(np.abs(sd_err) < 0.35), sd_err
    assert np.all(np.abs(z_err) < 0.75), z_err
    assert np.all(np.abs(mean_err.mean(axis=0)) < 0.2), mean_err.mean(axis=0)
    assert np.all(np.abs(sd_err.mean(axis=0)) < 0.1), sd_err.mean(axis=0)
    assert np.all(np.abs(z_err.mean(axis=0)) < 0.3), z_err.mean(axis=0)


@pytest.mark.parametrize("sampler", ["SEMC", "SMC"])
def test_smc2_updates_stay_within_50000_expensive_calls(study, sampler):
    """Issue 23's bar for the study's settings (``coulomb.BOUNDED_COST``, both samplers): each SMC^2 update (steps 2-4)
    costs the advance (N M = 8,000), the guide's pilot (at most 4 x 500) and PMMH re-runs held to
    ``move_budget x N M`` = 40,000 in the budget's units (M s per re-run, of which a re-run evaluates 1 + M (s - 1));
    measured at most 40,750 over 20 runs per sampler (docs/benchmarks.md, "Coulomb at 50,000 calls")."""
    for kernel in ("T1", "T2"):
        for run in study.results[(sampler, kernel)]:
            calls = [rec.info.n_loglike_evals for rec in run.steps[1:]]
            assert max(calls) <= 50_000, calls
