"""Measurement path (issue 12, item 4): multichannel CSV/HDF5 loaders with units and
sampling rate, baseline correction, band-pass filtering, decimation; modal results
(frequencies, damping, shapes, MAC) from posterior samples."""

import numpy as np
import pytest

from seqbayes.structural.structures import G, ShearBuilding
from seqbayes.structural.structures.modal import mac, modal_summary
from seqbayes.structural.structures.records import ResponseRecord, read_csv, read_hdf5


def _sines(fs=200.0, seconds=20.0, freqs=(1.0, 30.0)):
    t = np.arange(int(seconds * fs)) / fs
    return t, np.column_stack([np.sin(2 * np.pi * f * t) for f in freqs])


def test_csv_units_time_column_and_errors(tmp_path):
    t = np.arange(100) / 50.0
    a = np.column_stack([t, 0.1 * np.sin(t), 2.0 * np.cos(t)])
    path = tmp_path / "rec.csv"
    np.savetxt(path, a, delimiter=",", header="time,ground,floor1", comments="")
    rec = read_csv(path, units={"ground": "g", "floor1": "cm/s2"}, time_column="time")
    assert rec.channels == ("ground", "floor1") and rec.units == ("m/s^2", "m/s^2")
    assert rec.dt == pytest.approx(0.02, rel=1e-9)
    np.testing.assert_allclose(rec.channel("ground"), 0.1 * np.sin(t) * G, rtol=1e-12)
    np.testing.assert_allclose(rec.select(["floor1"])[:, 0], 0.02 * np.cos(t), rtol=1e-12)
    with pytest.raises(ValueError, match="sampling_rate"):
        read_csv(path, units="g")  # the time column not named: no rate
    with pytest.raises(ValueError, match="sampling_rate"):
        read_csv(path, units="g", time_column="time", sampling_rate=100.0)  # disagrees with the column
    with pytest.raises(ValueError, match="units"):
        read_csv(path, units={"ground": "g"}, time_column="time")
    with pytest.raises(ValueError, match="units"):
        read_csv(path, units="furlong", time_column="time")
    with pytest.raises(ValueError, match="channel"):
        rec.channel("roof")
    bad = tmp_path / "bad.csv"
    np.savetxt(bad, np.column_stack([t**2, t]), delimiter=",", header="time,x", comments="")
    with pytest.raises(ValueError, match="time_column"):
        read_csv(bad, time_column="time")


def test_hdf5_attributes(tmp_path):
    import h5py

    path = tmp_path / "rec.h5"
    _, x = _sines(fs=100.0, seconds=2.0)
    with h5py.File(path, "w") as f:
        g = f.create_group("test1")
        g.attrs["sampling_rate"] = 100.0
        g.create_dataset("floor1", data=x[:, 0]).attrs["units"] = "g"
        g.create_dataset("drift1", data=x[:, 1]).attrs["units"] = "mm"
    rec = read_hdf5(path, "test1", channels=["floor1", "drift1"])
    assert rec.dt == pytest.approx(0.01) and rec.units == ("m/s^2", "m")
    np.testing.assert_allclose(rec.data, x * [G, 1e-3], rtol=1e-12)
    with pytest.raises(ValueError, match="channels"):
        read_hdf5(path, "test1", channels=["roof"])
    with pytest.raises(ValueError, match="group"):
        read_hdf5(path, "test2")


def test_baseline_band_pass_and_decimation():
    fs = 200.0
    t, x = _sines(fs)
    drift = 0.3 + 0.05 * t  # offset and linear drift
    rec = ResponseRecord(x + drift[:, None], 1 / fs, ("a", "b"), ("m/s^2", "m/s^2"))
    # exact: a polynomial baseline of the stated degree is removed entirely, and the correction is linear
    only_drift = ResponseRecord(np.column_stack([drift, 2 * drift]), 1 / fs, ("a", "b"), ("m", "m"))
    np.testing.assert_allclose(only_drift.baseline_corrected(1).data, 0.0, atol=1e-12)
    assert np.abs(only_drift.baseline_corrected(0).data).max() > 0.4  # degree 0 keeps the drift
    sines = ResponseRecord(x, 1 / fs, ("a", "b"), ("m/s^2", "m/s^2"))
    np.testing.assert_allclose(rec.baseline_corrected(1).data, sines.baseline_corrected(1).data, atol=1e-12)
    clean = sines
    band = clean.band_passed(0.5, 10.0)
    from scipy import signal

    inner = slice(1000, -1000)  # t = 5-15 s, away from the ends (filter transients)
    sos = signal.butter(4, [0.5, 10.0], btype="bandpass", fs=fs, output="sos")
    gain = np.abs(signal.sosfreqz(sos, [1.0, 30.0], fs=fs)[1]) ** 2  # forward and backward: |H|^2
    # the steady sine response; measured max deviation 2.5e-3 (the slow transient of the 0.5 Hz edge)
    np.testing.assert_allclose(band.data[inner], x[inner] * gain, atol=5e-3)
    assert gain[0] > 0.95 and gain[1] < 1e-3
    low = clean.decimated(4)  # 200 -> 50 Hz; the 1 Hz sine survives, the 30 Hz one is above the new Nyquist
    assert low.dt == pytest.approx(0.02) and low.data.shape[0] == 1000
    np.testing.assert_allclose(low.data[50:-50, 0], x[::4, 0][50:-50], atol=0.01)
    assert np.abs(low.data[50:-50, 1]).max() < 0.02
    with pytest.raises(ValueError, match="low, high"):
        rec.band_passed(1.0, 150.0)
    with pytest.raises(ValueError, match="factor"):
        rec.decimated(0)
    with pytest.raises(ValueError, match="channels"):
        ResponseRecord(x, 0.01, ("a",), ("m",))


def test_mac_properties():
    rng = np.random.default_rng(0)
    q, _ = np.linalg.qr(rng.standard_normal((4, 4)))
    np.testing.assert_allclose(mac(q, q), np.eye(4), atol=1e-12)  # orthogonal shapes
    np.testing.assert_allclose(mac(-3.0 * q[:, :2], q), mac(q[:, :2], q), atol=1e-12)  # scale and sign
    with pytest.raises(ValueError, match="shapes_a"):
        mac(np.ones((3, 2)), np.ones((4, 2)))


def test_modal_summary_from_samples():
    b = ShearBuilding(np.array([24.0, 20.0, 20.0, 16.0]) * 1e3, np.array([36.0, 30.0, 24.0, 16.0]) * 1e6,
                      (0.02, 0.04))
    theta = np.array([0.91, 0.85, 0.78, 0.94])
    freqs, shapes = b.modes(theta)
    point = modal_summary(b, np.tile(theta, (50, 1)), identified_shapes=-2.0 * shapes[0])
    np.testing.assert_allclose(point.frequency_mean, freqs[0], rtol=1e-12)
    np.testing.assert_allclose(point.frequency_sd, 0.0, atol=1e-9)
    np.testing.assert_allclose(point.shape_mac, 1.0, rtol=1e-12)
    np.testing.assert_allclose(np.diag(point.mac_identified), 1.0, rtol=1e-12)
    # at theta = 1 the Rayleigh damping gives the specified ratios on modes 1 and 2
    np.testing.assert_allclose(modal_summary(b, np.ones((3, 4))).damping_mean[:2], [0.02, 0.04], rtol=1e-10)
    # a posterior spread: the frequency sd follows the samples, the first mode's frequency ~ sqrt(theta)
    rng = np.random.default_rng(1)
    samples = theta * (1 + 0.01 * rng.standard_normal((2000, 4)))
    spread = modal_summary(b, samples)
    direct = b.modes(samples)[0]
    np.testing.assert_allclose(spread.frequency_mean, direct.mean(axis=0), rtol=1e-12)
    np.testing.assert_allclose(spread.frequency_sd, direct.std(axis=0), rtol=1e-10)
    assert np.all(spread.shape_mac > 0.99) and np.all(spread.shape_mac < 1.0)
    assert "| 1 |" in spread.table()
    with pytest.raises(ValueError, match="theta_samples"):
        modal_summary(b, np.ones((3, 2)))
    with pytest.raises(ValueError, match="weights"):
        modal_summary(b, samples, weights=-np.ones(2000))
