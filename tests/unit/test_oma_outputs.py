"""Issue 42 items 1-3 for ``seqbayes oma`` and ``seqbayes track``: outputs through the store's target checks
(never an input, never a foreign file without ``--force``, written atomically), and the record and poles tables
through the store's strict reader."""

import os

import numpy as np
import pytest

from seqbayes.cli import main
from seqbayes.store import targets
from seqbayes.structural.oma import building_3d, modal_record

MODEL = building_3d(3, (2.6, 2.626, 3.6), damping=0.01, max_frequency=8.0,
                    sensors=[(3, "A", "X"), (3, "A", "Y"), (2, "B", "X"), (2, "A", "Y")])


@pytest.fixture(scope="module")
def record_file(tmp_path_factory):
    """Five minutes of the sweep's building at 20 Hz, 4 channels, as .npy."""
    path = tmp_path_factory.mktemp("oma") / "rec.npy"
    np.save(path, modal_record(MODEL, 300.0, 0.05, rng=np.random.default_rng(7)))
    return path


def _poles(path, n_days=3, per_day=6, seed=0):
    rng = np.random.default_rng(seed)
    day = np.arange(n_days * per_day) / per_day
    rows = [f"{d:.6f},{4.0 * np.exp(rng.normal(0, 0.003)):.6f},0.01" for d in day]
    path.write_text("day,frequency_hz,std_frequency_hz\n" + "\n".join(rows) + "\n")
    return path


def _run(capsys, argv):
    code = main([str(a) for a in argv])
    return code, capsys.readouterr().err.strip()


def test_oma_refuses_a_foreign_existing_output_unless_forced(record_file, tmp_path, capsys):
    mine = {"--out": tmp_path / "notes.csv", "--json": tmp_path / "notes.json", "--diagram": tmp_path / "photo.png"}
    for option, path in mine.items():
        path.write_text("the user's own file\n")
        code, err = _run(capsys, ["oma", record_file, "--fs", "20", option, path])
        assert code == 2 and "exists and is not a file this command wrote" in err and "--force" in err, err
        assert len(err.splitlines()) == 1 and path.read_text() == "the user's own file\n"
    options = [a for option, path in mine.items() for a in (option, path)]
    code, err = _run(capsys, ["oma", record_file, "--fs", "20", *options, "--force"])
    assert code == 0 and all(path.read_bytes() != b"the user's own file\n" for path in mine.values())
    code, err = _run(capsys, ["oma", record_file, "--fs", "20", *options[:4]])   # its own outputs: no --force
    assert code == 0, err
    assert not [p for p in os.listdir(tmp_path) if ".tmp" in p]


def test_oma_never_writes_over_its_record_even_forced(record_file, tmp_path, capsys):
    link = tmp_path / "hard.npy"
    os.link(record_file, link)
    before = record_file.read_bytes()
    code, err = _run(capsys, ["oma", record_file, "--fs", "20", "--json", link, "--force"])
    assert code == 2 and "is the input" in err and record_file.read_bytes() == before


def test_oma_output_that_cannot_be_written_is_one_line_and_keeps_the_old_file(record_file, tmp_path, capsys,
                                                                                monkeypatch):
    out = tmp_path / "modes.csv"
    assert _run(capsys, ["oma", record_file, "--fs", "20", "--out", out])[0] == 0
    before = out.read_bytes()

    def full(*args):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(targets.os, "replace", full)
    code, err = _run(capsys, ["oma", record_file, "--fs", "20", "--out", out])
    assert code == 2 and "No space left on device" in err and "the old file is kept" in err
    assert out.read_bytes() == before and not [p for p in os.listdir(tmp_path) if ".tmp" in p]


@pytest.mark.parametrize("text, words", [
    ("0.1,0.2,0.3\n0.2,0.1,0.4\n", "line 1 holds numbers, not channel names"),
    ("t;a;b\n0;1;2\n", "separated by ';'"),
    ("t,a,a\n0,1,2\n", "name each column once"),
    ("t,a,b\n0,1,2 # ok\n0.05,1,2\n", "holds a '#'"),
    ("t,a,b\n0,1,2\n0.05,1_0,2\n", "not a number"),
])
def test_a_record_csv_goes_through_the_strict_reader(tmp_path, capsys, text, words):
    path = tmp_path / "rec.csv"
    path.write_text(text)
    code, err = _run(capsys, ["oma", path, "--fs", "20"])
    assert code == 2 and words in err and len(err.splitlines()) == 1, err


def test_track_writes_through_the_guard_and_refuses_foreign_files(tmp_path, capsys):
    poles = _poles(tmp_path / "poles.csv")
    out = tmp_path / "tracked"
    out.mkdir()
    (out / "record_001.csv").write_text("my notes\n")
    code, err = _run(capsys, ["track", poles, "--out", out])
    assert code == 2 and "record_001.csv: exists and is not a file this command wrote" in err, err
    assert sorted(os.listdir(out)) == ["record_001.csv"]          # nothing written before the refusal
    assert _run(capsys, ["track", poles, "--out", out, "--force"])[0] == 0
    written = sorted(os.listdir(out))
    assert "tracking.csv" in written and "run.toml" in written and not [p for p in written if ".tmp" in p]
    assert _run(capsys, ["track", poles, "--out", out])[0] == 0    # its own files: replaced without --force
    # the poles table inside the folder under an output's name is an input: never written, even forced
    inside = _poles(out / "tracking.csv")
    before = inside.read_bytes()
    code, err = _run(capsys, ["track", inside, "--out", out, "--force"])
    assert code == 2 and "is the input" in err and inside.read_bytes() == before
    code, err = _run(capsys, ["track", poles, "--out", poles])
    assert code == 2 and "is a file, not a folder" in err
    code, err = _run(capsys, ["track", poles, "--out", out, "--prefix", "../escape"])
    assert code == 2 and "--prefix" in err and not (tmp_path / "escape_001.csv").exists()


@pytest.mark.parametrize("body, words", [
    ("day,frequency_hz\n0,4.0\n0.5,4.01 # check\n", "holds a '#'"),
    ("day,frequency_hz\n0,4.0\n1e20,4.01\n", "outside -36525 to 36525"),
    ("day,frequency_hz\n1,4.0\n0.5,4.01\n", "does not come after"),
    ("day,frequency_hz\n0,4.0\n0.5,1e6\n", "outside 0.001 to 10000"),
    ("day;frequency_hz\n0;4.0\n", "separate its columns by ';'"),
    ("day,frequency_hz,std_frequency_hz\n0,4.0,\uff11\n", "not a number"),
])
def test_track_reads_the_poles_table_through_the_strict_reader(tmp_path, capsys, body, words):
    path = tmp_path / "poles.csv"
    path.write_text(body)
    code, err = _run(capsys, ["track", path, "--out", tmp_path / "out"])
    assert code == 2 and words in err and len(err.splitlines()) == 1, err
    assert not (tmp_path / "out").exists()


def test_track_refuses_a_fifo_without_waiting(tmp_path, capsys):
    fifo = tmp_path / "poles.csv"
    os.mkfifo(fifo)
    code, err = _run(capsys, ["track", fifo, "--out", tmp_path / "out"])
    assert code == 2 and "FIFO" in err


def test_track_removes_its_own_stale_datasets_and_refuses_a_foreign_one(tmp_path, capsys):
    """A second run with fewer records: the first run's datasets beyond the new ones would be read by
    ``seqbayes update DIR/record_*.csv``; they are removed (they are this command's), a foreign file of that
    name is refused."""
    out = tmp_path / "tracked"
    assert _run(capsys, ["track", _poles(tmp_path / "long.csv", n_days=4), "--out", out])[0] == 0
    before = sorted(p.name for p in out.glob("record_*.csv"))
    assert _run(capsys, ["track", _poles(tmp_path / "short.csv", n_days=3), "--out", out])[0] == 0
    after = sorted(p.name for p in out.glob("record_*.csv"))
    assert len(after) < len(before) and after == before[:len(after)]
    (out / "record_999.csv").write_text("my notes\n")
    code, err = _run(capsys, ["track", tmp_path / "short.csv", "--out", out])
    assert code == 2 and "record_999.csv: matches the datasets' names" in err
    assert (out / "record_999.csv").read_text() == "my notes\n"
