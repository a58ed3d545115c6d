"""OMA with its defaults (issue 38, acceptance "simulated sweep" and "uncertainty calibrated"), reduced to one
cell of ``benchmarks/bench_oma_sweep.py`` and one seed of its roving tower (the full tables: docs/oma.md).

Both use the benchmark's own records (same building, seeds and noise), so the numbers are reproducible; the
tolerances are the acceptance bars, and docs/oma.md gives the measured values they are checked against."""

import importlib.util
import warnings
from pathlib import Path

import numpy as np
import pytest

spec = importlib.util.spec_from_file_location(
    "bench_oma_sweep", Path(__file__).resolve().parents[2] / "benchmarks" / "bench_oma_sweep.py")
bench = importlib.util.module_from_spec(spec)
spec.loader.exec_module(bench)


@pytest.mark.slow
def test_sweep_cell_every_mode_within_half_percent_and_calibrated():
    """100 Hz, 10 minutes, 4 channels, the first 10 of the benchmark's 20 seeds: each of the five modes (the two
    close pairs 1 % apart and the torsion) within 0.5 % in at least 9 of 10 seeds, no spurious mode, and each
    mode's median reported standard error within a factor 1.5 of the spread over the seeds (20 seeds,
    docs/oma.md: 19-20 of 20 within 0.5 %, ratios 0.82-1.06). Not every cell of the sweep meets both bars:
    docs/oma.md gives the ones that do not (20 Hz, 5 minutes, 2 channels above all)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        cell = bench.run_cell(100, 10, 4, 10)
    for mode in cell["modes"]:
        assert mode["within_half_percent"] >= 9, mode
        assert 1 / 1.5 < mode["ratio_median"] < 1.5, mode
    assert sum(cell["spurious_per_seed"]) == 0


@pytest.mark.slow
def test_roving_tower_merged_with_the_defaults():
    """The issue's situation (four roving setups of 6-8 channels, 328 s at 40 Hz, two reference channels,
    sensor noise 5 % of the top floor's RMS): every setup finds the six lowest modes with no option given, and
    the merged shapes over all 24 channels match the true ones (MAC > 0.95)."""
    from seqbayes.structural.oma.setups import ssi_cov_setups

    model = bench.tower_model()
    records, names = [], []
    for j, rover in enumerate(bench.ROVING):
        channels = bench.REFERENCES + rover
        records.append(bench.modal_record(model.select(channels), 328.0, 1 / 40, rng=np.random.default_rng([42, 0, j]),
                                          force_corner_hz=2.0, noise="floor"))
        names.append(channels)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        merged = ssi_cov_setups(records, 1 / 40, names, bench.REFERENCES)
    assert list(merged.channels) == list(model.channels)
    for i, f in enumerate(model.frequencies[:6]):
        j = int(np.argmin(np.abs(merged.frequencies - f)))
        assert abs(merged.frequencies[j] / f - 1) < 0.01
        assert merged.found[:, j].all()
        true, found = model.shapes[:, i], merged.shapes[:, j]
        assert (true @ found) ** 2 / ((true @ true) * (found @ found)) > 0.95
