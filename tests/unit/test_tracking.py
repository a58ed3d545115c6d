"""Mode tracking (seqbayes.structural.tracking) and the modes table (seqbayes.structural.modes_table):
exact checks of the assignment, a statistical check on simulated poles with known modes, and the
bundled guyed-mast data."""

from importlib import resources

import numpy as np
import pytest

from seqbayes.structural.modal_references import simulate_poles
from seqbayes.structural.modes_table import PoleTable, read_covariates, read_modes_table, write_modes_table
from seqbayes.structural.tracking import (ReferenceModes, TrackerSettings, assign, reference_from_poles,
                                          track_poles, track_step)

MAST = resources.files("seqbayes") / "data" / "guyed_mast"


def _table(day, frequency, std=None, **extra):
    n = len(frequency)
    nan = np.full(n, np.nan)
    return PoleTable(day=np.broadcast_to(day, (n,)), frequency=frequency,
                     std_frequency=nan if std is None else std, damping_pct=nan, std_damping_pct=nan, mpc=nan,
                     mpd=nan, model_order=nan, slot=np.arange(n), **extra)


# ------------------------------------------------------------------------ the assignment
def test_assign_keeps_close_modes_apart_and_marks_spurious():
    mean = np.array([0.351, 0.355])
    var = np.full((4, 2), 0.0008 ** 2)
    # both close modes, in reverse order, plus one far pole and a pole between the gates
    assert assign([0.3553, 0.3508, 0.40, 0.3531], var, mean).tolist() == [1, 0, -1, -1]
    # one pole: the nearer track; the other mode is missing (no column shifts)
    assert assign([0.3548], var[:1], mean).tolist() == [1]
    # a duplicate of mode 1: the better one is kept, the other is spurious (not pushed onto mode 2)
    a = assign([0.3511, 0.3513, 0.3551], var[:3], mean)
    assert a.tolist() == [0, -1, 1]


def test_assign_is_the_optimal_assignment_inside_the_gate():
    rng = np.random.default_rng(3)
    from itertools import permutations

    for _ in range(50):
        k, m = int(rng.integers(1, 5)), int(rng.integers(1, 5))
        f = rng.uniform(0, 1, k)
        mean = rng.uniform(0, 1, m)
        var = rng.uniform(0.01, 0.05, (k, m)) ** 2
        gate = 3.0
        got = assign(f, var, mean, gate)
        # brute force over every partial injective assignment
        best, best_cost = None, np.inf
        options = list(range(m)) + [-1] * k
        for perm in set(permutations(options, k)):
            cost, ok = 0.0, True
            for i, j in enumerate(perm):
                if j < 0:
                    cost += gate ** 2 / 4
                else:
                    z2 = (f[i] - mean[j]) ** 2 / var[i, j]
                    ok &= z2 < gate ** 2
                    cost += 0.5 * z2
            cost += (m - sum(j >= 0 for j in perm)) * gate ** 2 / 4
            if ok and cost < best_cost - 1e-12:
                best, best_cost = perm, cost
        assert got.tolist() == list(best)


def test_assign_uses_the_mac():
    mean = np.array([1.0, 1.01])
    var = np.full((1, 2), 0.02 ** 2)
    mac = np.array([[0.1, 0.99]])            # nearer the first in frequency, but the second's shape
    assert assign([1.0], var, mean, mac=mac).tolist() == [1]
    assert assign([1.0], var, mean, mac=np.array([[0.1, 0.5]])).tolist() == [-1]   # both below the MAC gate


# ------------------------------------------------------------------------ tracking
def test_track_step_marks_a_missing_mode_and_updates_the_others():
    ref = ReferenceModes([0.351, 0.355, 0.62], initial_sd=0.001, drift=0.0002, scatter=0.0005, std_scale=0.0)
    state = ref.initial_state()
    state, a = track_step(state, ref, _table(0.0, [0.6205, 0.3512]))
    assert a.tolist() == [2, 0]
    assert abs(state.mean[0] - 0.3512) < abs(0.351 - 0.3512) and state.mean[1] == 0.355
    assert state.cov[1, 1] > state.cov[0, 0]              # the missing mode's uncertainty grows


def test_tracking_simulated_poles_recovers_the_modes():
    table, truth = simulate_poles(np.random.default_rng(11))
    tracked = track_poles(table)
    ref = tracked.reference
    assert ref.n_modes == 6
    assert np.allclose(ref.frequencies, [0.351, 0.355, 0.620, 0.626, 1.31, 2.04], rtol=0.003)
    a = tracked.assignment
    real = truth > 0
    # a pole of one mode is never given to another (a duplicate may stand in for its mode's pole)
    wrong = (a > 0) & (truth != 0) & (np.abs(truth) != a)
    # bench_tracking_mast.py --synthetic: over 10 seeds of 7 days at most 1.3 % and 2.8 %
    assert wrong.sum() <= 0.015 * real.sum()
    assert np.mean(a[truth == 0] > 0) < 0.04                 # clutter rarely accepted
    found = np.mean([(a[(np.abs(truth) == j)] == j).any() for j in range(1, 7)])
    assert found == 1.0
    # a record never holds one mode twice
    for rows in tracked.rows:
        ids = a[rows][a[rows] > 0]
        assert ids.size == np.unique(ids).size


def test_tracking_is_reproducible_and_given_modes_are_kept():
    table, _ = simulate_poles(np.random.default_rng(5), days=1.0)
    one, two = track_poles(table), track_poles(table)
    assert np.array_equal(one.assignment, two.assignment)
    given = reference_from_poles(table, TrackerSettings(initial_days=1.0), frequencies=[0.351, 0.355, 0.62, 0.626])
    assert np.array_equal(given.frequencies, [0.351, 0.355, 0.62, 0.626])
    assert np.all(given.scatter > 0) and np.all(given.drift > 0)


def test_too_few_records_says_what_to_change():
    few = _table(np.arange(3.0), [1.0, 1.0, 1.0])
    with pytest.raises(ValueError, match="at least 5.*initial_days"):
        reference_from_poles(few)
    given = reference_from_poles(few, frequencies=[1.0])        # given modes: the noise takes defaults
    assert np.allclose(given.scatter, 0.003) and track_poles(few, given).coverage.tolist() == [1.0]


# ------------------------------------------------------------------------ the mast
@pytest.fixture(scope="module")
def mast():
    poles = read_modes_table(MAST / "poles_60min.csv")
    return poles, track_poles(poles)


def test_mast_modes_are_found_and_close_pairs_never_cross(mast):
    poles, tracked = mast
    assert poles.n_rows == 2877 and len(tracked.rows) == 468
    f = tracked.reference.frequencies
    for target in (0.351, 0.355, 0.618, 0.626, 1.31, 2.04):      # PROVENANCE.md's modes
        assert np.min(np.abs(f / target - 1)) < 0.01
    for a, b in ((0, 1), (2, 3)):                               # the two close pairs
        both = np.isfinite(tracked.frequency[:, a]) & np.isfinite(tracked.frequency[:, b])
        assert both.sum() > 300
        assert np.all(tracked.frequency[both, a] < tracked.frequency[both, b])
        assert np.all(tracked.track_mean[:, a] < tracked.track_mean[:, b])
    cover = tracked.coverage
    assert np.all(cover[:4] > 0.75) and np.all(cover > 0.3)   # the bands' presence (37-88 %) bounds it
    assert 0.1 < tracked.spurious.sum() / poles.n_rows < 0.35


def test_mast_datasets_carry_modes_and_temperatures(mast, tmp_path):
    _, tracked = mast
    cov = read_covariates(MAST / "temperature_60min.csv")
    files = tracked.write_datasets(tmp_path, "hour", cov)
    assert len(files) == sum(1 for r in tracked.rows if np.any(tracked.assignment[r] > 0))
    first = read_modes_table(files[0])
    assert first.mode.tolist() == sorted(first.mode.tolist())
    assert np.allclose(first.covariates["Pt100_01_mean_degC"], 11.328)
    assert np.all(tracked.frequency[0][first.mode - 1] == first.frequency)


def test_modes_table_round_trip(tmp_path):
    table = _table([0.5, 0.5], [1.2, 3.4], [0.01, np.nan], shapes=np.array([[1.0, -0.5], [0.2, 1.0]]),
                   std_shapes=np.array([[0.01, 0.02], [np.nan, 0.03]]), channels=("a", "b"), mode=[1, 2],
                   covariates={"temperature": [10.0, 10.0]})
    back = read_modes_table(write_modes_table(tmp_path / "t.csv", table))
    assert np.array_equal(back.frequency, table.frequency) and back.mode.tolist() == [1, 2]
    assert np.array_equal(back.shapes, table.shapes) and np.isnan(back.std_shapes[1, 0])
    assert np.isnan(back.std_frequency[1]) and back.channels == ("a", "b")
    assert np.array_equal(back.covariates["temperature"], [10.0, 10.0])


@pytest.mark.parametrize("text, match", [
    ("day,freq\n0,1\n", "missing column.*frequency_hz"),
    ("day,frequency_hz\n0,abc\n", "line 2, column 'frequency_hz': not a number"),
    ("day,frequency_hz\n0,-1\n", "row 1.*positive"),
    ("day,frequency_hz\n0,1,2\n", "line 2 has 3 fields"),
    ("day,frequency_hz\n", "no rows"),
])
def test_modes_table_errors_name_the_line(tmp_path, text, match):
    path = tmp_path / "bad.csv"
    path.write_text(text)
    with pytest.raises(ValueError, match=match):
        read_modes_table(path)


def test_settings_are_checked():
    with pytest.raises(ValueError, match="gate"):
        TrackerSettings(gate=0)
    with pytest.raises(ValueError, match="min_presence"):
        TrackerSettings(min_presence=1.5)
