"""Bad records and the ``seqbayes oma`` command (issue 38, acceptance "bad records"; issue 42, the OMA items):
each bad record is refused (or warned about) in one line that names the problem, no raw LAPACK or numpy
message reaches the user, and the outputs never overwrite the record."""

import json
import os
import warnings

import numpy as np
import pytest

from seqbayes.cli import main
from seqbayes.structural.oma import OMAWarning, building_3d, modal_record, ssi_cov
from seqbayes.structural.oma.io import COLUMNS, read_record

MODEL = building_3d(3, (2.6, 2.626, 3.6), damping=0.01, max_frequency=8.0,
                    sensors=[(3, "A", "X"), (3, "A", "Y"), (2, "B", "X"), (2, "A", "Y")])


@pytest.fixture(scope="module")
def record():
    """Five minutes of the sweep's building at 20 Hz, 4 channels (6000 x 4)."""
    return modal_record(MODEL, 300.0, 0.05, rng=np.random.default_rng(7))


def _one_line(capsys, argv) -> tuple[int, str]:
    code = main(argv)
    err = capsys.readouterr().err.strip()
    return code, err


@pytest.mark.parametrize("bad, words", [
    (lambda y: np.full_like(y, 3.0), "every channel is constant"),
    (lambda y: np.column_stack([y[:, :3], np.full(len(y), 2.0)]), "channel 3 is constant"),
    (lambda y: np.where(np.arange(y.size).reshape(y.shape) == 100, np.nan, y), "NaN or infinite"),
    (lambda y: y[:, :1], "1 channel"),
    (lambda y: y.T, "looks transposed"),
])
def test_bad_records_are_refused_in_one_line_naming_the_problem(record, bad, words):
    with pytest.raises(ValueError, match=words) as err:
        ssi_cov(bad(record), 0.05)
    assert "\n" not in str(err.value) and str(err.value).startswith("y:")


def test_too_short_for_the_band(record):
    with pytest.raises(ValueError, match="too short for the band: it holds 30 cycles"):
        ssi_cov(record[:600], 0.05, band=(1.0, 8.0))     # 30 s of a band from 1 Hz
    with pytest.raises(ValueError, match="too short"):
        ssi_cov(record[:40], 0.05)                        # 2 s: nothing holds 50 cycles below 8 Hz


@pytest.mark.parametrize("dt", [1e-300, 1e300, 0.0, -1.0, float("nan")])
def test_a_sampling_step_out_of_range_is_refused(record, dt):
    with pytest.raises(ValueError, match="dt:"):
        ssi_cov(record, dt)


def test_an_aliased_record_warns(record):
    """A record decimated without a filter (energy up to the stated Nyquist frequency) warns; the same record
    sampled right does not."""
    fast = modal_record(MODEL, 300.0, 0.005, rng=np.random.default_rng(8))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        ssi_cov(fast[::10], 0.05)     # 200 Hz -> 20 Hz by dropping samples: modes up to 7.4 Hz fold, noise folds
    assert any("aliased" in str(w.message) for w in caught if w.category is OMAWarning)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        ssi_cov(record, 0.05)
    assert not any("aliased" in str(w.message) for w in caught)


def test_a_huge_amplitude_gives_the_same_modes_and_no_lapack_message(record, capfd):
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)   # no numpy overflow either
        small = ssi_cov(record, 0.05)
        huge = ssi_cov(record * 1e200, 0.05)
    out = capfd.readouterr()
    assert "DLASCL" not in out.out + out.err
    np.testing.assert_allclose(huge.frequencies, small.frequencies, rtol=1e-9)


def test_the_command_writes_the_modes_table_json_and_diagram(record, tmp_path, capsys):
    path = tmp_path / "rec.csv"
    t = np.arange(record.shape[0]) * 0.05
    np.savetxt(path, np.column_stack([t, record]), delimiter=",", header="time," + ",".join(MODEL.channels),
               comments="", fmt="%.8g")
    out, js, png = tmp_path / "modes.csv", tmp_path / "modes.json", tmp_path / "d.png"
    code = main(["oma", str(path), "--fs", "20", "--out", str(out), "--json", str(js), "--diagram", str(png),
                 "--day", "3.25"])
    printed = capsys.readouterr()
    assert code == 0, printed.err
    header = out.read_text().splitlines()[0].split(",")
    assert header[:10] == list(COLUMNS)
    assert header[10:] == [f"phi_{c}" for c in MODEL.channels] + [f"std_phi_{c}" for c in MODEL.channels]
    rows = np.genfromtxt(out, delimiter=",", skip_header=1)
    assert rows.shape[0] >= 3 and np.all(rows[:, 1] == 3.25) and rows[:, 2].tolist() == list(range(rows.shape[0]))
    assert np.all(np.isfinite(rows[:, 3:8]))                      # f, damping and their standard errors
    assert np.allclose(np.nanmax(rows[:, 10:14], axis=1), 1.0)    # shapes: largest component +1
    doc = json.loads(js.read_text())
    assert doc["status"] in ("complete", "partial") and len(doc["modes"]) == rows.shape[0]
    assert doc["settings"]["decimation"] == 1 and doc["settings"]["block_rows"] >= 2
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert not [p for p in os.listdir(tmp_path) if p.endswith(".tmp")]


def test_the_command_refuses_in_one_line(record, tmp_path, capsys):
    path = tmp_path / "rec.csv"
    t = np.arange(record.shape[0]) * 0.05
    np.savetxt(path, np.column_stack([t, record]), delimiter=",", header="time,a,b,c,d", comments="", fmt="%.8g")
    before = path.read_bytes()
    cases = [
        (["--fs", "40"], "time column steps by 0.05 s (20 Hz), not the 0.025 s (40 Hz) given: a wrong sampling rate"),
        (["--fs", "20", "--out", str(path)], "that is the record being read"),
        (["--fs", "20", "--json", str(tmp_path / "x"), "--out", str(tmp_path / "x")], "give each output its own file"),
        (["--dt", "1e-300"], "outside the 0.01 Hz"),
        (["--fs", "20", "--band", "1"], "--band: expected LO,HI"),
    ]
    for extra, words in cases:
        code, err = _one_line(capsys, ["oma", str(path), *extra])
        assert code == 2 and words in err and len(err.splitlines()) == 1, err
    assert path.read_bytes() == before
    transposed = tmp_path / "t.npy"
    np.save(transposed, record.T)
    code, err = _one_line(capsys, ["oma", str(transposed), "--fs", "20"])
    assert code == 2 and "looks transposed" in err and len(err.splitlines()) == 1
    ragged = tmp_path / "ragged.csv"
    ragged.write_text("a,b\n1,2\n3\n")
    code, err = _one_line(capsys, ["oma", str(ragged), "--fs", "20"])
    assert code == 2 and "line 3 has 1 fields, expected 2" in err


def test_a_fifo_or_device_is_not_read(tmp_path):
    fifo = tmp_path / "pipe.csv"
    os.mkfifo(fifo)
    with pytest.raises(ValueError, match="not a regular file"):
        read_record(fifo)          # returns at once: opened without waiting for a writer
    with pytest.raises(ValueError, match="not a regular file"):
        read_record("/dev/zero")


def test_an_empty_result_says_why_and_exits_one(tmp_path, capsys):
    noise = np.random.default_rng(3).standard_normal((6000, 3))
    path = tmp_path / "noise.npy"
    np.save(path, noise)
    code = main(["oma", str(path), "--fs", "20", "--band", "1,6"])
    printed = capsys.readouterr()
    assert code == 1
    lines = [line for line in printed.err.splitlines() if "no mode" in line]
    assert len(lines) == 1 and "try a longer record" in lines[0]
