"""Issue 42, items 1 and 3: every finding of the issue on reading tables and on tracebacks, one test each.

``seqbayes environment`` reads its CSV through the run store's reader (:mod:`seqbayes.store.datasets`) with the
rules of :func:`seqbayes.studies.environment.year_spec`; numeric options are bounded at parse time; numpy's
warnings and any exception end in one line of our own words.
"""

from __future__ import annotations

import os
import re
import threading
import warnings

import numpy as np
import pytest

from seqbayes import cli
from seqbayes.store.datasets import MAX_FILE_BYTES, DataError, TableSpec, check_table, read_datafile
from seqbayes.studies.environment import MASSES, STIFFNESSES, read_year_csv, simulate_year, write_year_csv

BUILDING = ["--masses", ",".join(map(str, MASSES[:2])), "--stiffness", ",".join(map(str, STIFFNESSES[:2]))]


def year(tmp_path, name="year.csv", n_days=2, sets_per_day=3, seed=5):
    """A short simulated year of the 2-storey building, as the CSV ``seqbayes environment`` reads."""
    table, truth = simulate_year(np.random.default_rng(seed), masses=MASSES[:2], stiffnesses=STIFFNESSES[:2],
                                 n_days=n_days, sets_per_day=sets_per_day)
    write_year_csv(tmp_path / name, table, truth)
    return tmp_path / name


def edited(tmp_path, source, edit, name="bad.csv"):
    """``source`` with ``edit(lines) -> lines`` applied (line 0 is the header)."""
    lines = source.read_text().splitlines()
    (tmp_path / name).write_text("\n".join(edit(lines)) + "\n")
    return tmp_path / name


def environment(capsys, path, *options):
    """``seqbayes environment PATH`` on the 2-storey building with 10 particles: (exit code, stdout, stderr)."""
    code = cli.main(["environment", str(path), *BUILDING, "--particles", "10", "--every", "1",
                     *[str(o) for o in options]])
    out, err = capsys.readouterr()
    return code, out, err


def refused(capsys, path, message, *options):
    """The command refuses in one line matching ``message``, without a raw warning, and ``path`` is unchanged."""
    before = path.read_bytes() if path.is_file() and path.stat().st_size < 1 << 24 else None   # not the sparse GiB
    code, out, err = environment(capsys, path, *options)
    assert code == 2 and len(err.splitlines()) == 1 and err.startswith("seqbayes environment: error: "), err
    assert re.search(message, err), err
    assert "Warning" not in err and "Traceback" not in err and out == ""
    if before is not None:
        assert path.read_bytes() == before
    return err


# ------------------------------------------------------------------ Medium: days are not checked
def test_unsorted_days_are_refused_naming_the_rows(tmp_path, capsys):
    good = year(tmp_path)
    bad = edited(tmp_path, good, lambda lines: [lines[0], lines[1], lines[3], lines[2], *lines[4:]])
    refused(capsys, bad, r"bad.csv: column 'day', data row 3 \(line 4\): 0.3333333333 does not come after "
                         r"0.6666666667 \(data row 2 \(line 3\)\): the rows must be in increasing time order, one "
                         r"row per time \(a late or repeated row is refused\)")


def test_negative_days_are_refused(tmp_path, capsys):
    bad = edited(tmp_path, year(tmp_path), lambda lines: [lines[0], "-2" + lines[1][1:], *lines[2:]])
    refused(capsys, bad, r"column 'day' has 1 value\(s\) outside 0 to 36525, first -2 at data row 1 \(line 2\) "
                         r"\(days since the first monitored day; --max-day sets the upper bound\)")


def test_duplicated_days_are_refused(tmp_path, capsys):
    bad = edited(tmp_path, year(tmp_path), lambda lines: [*lines[:3], lines[2], *lines[3:]])
    refused(capsys, bad, r"data row 3 \(line 4\): 0.3333333333 does not come after 0.3333333333 .*a late or "
                         r"repeated row is refused")


def test_a_gap_of_a_billion_days_is_refused_even_with_the_largest_max_day(tmp_path, capsys):
    def gap(lines):
        return [lines[0], *lines[1:4], *[f"{float(line.split(',')[0]) + 1e9:.10g},{line.split(',', 1)[1]}"
                                        for line in lines[4:]]]
    bad = edited(tmp_path, year(tmp_path), gap)
    refused(capsys, bad, r"column 'day' has 3 value\(s\) outside 0 to 36525, first 1e\+09 at data row 4")
    refused(capsys, bad, r"outside 0 to 1e\+08", "--max-day", "1e8")


def test_a_day_of_1e20_is_refused_without_a_raw_warning(tmp_path, capsys):
    bad = edited(tmp_path, year(tmp_path), lambda lines: [*lines[:-1], "1e20," + lines[-1].split(",", 1)[1]])
    with warnings.catch_warnings():
        warnings.simplefilter("error")          # a RuntimeWarning anywhere on the path fails the test
        err = refused(capsys, bad, r"first 1e\+20 at data row 6 \(line 7\)")
    assert "-9223372036854775808" not in err


def test_the_rule_for_late_and_repeated_sets_is_the_readers_and_stated():
    """The one validation behind every table: "increasing" refuses a repeated time, "grouped" allows the rows
    of one time together (the modes of one record) and refuses a late one."""
    increasing = TableSpec(("day", "f"), time="day")
    grouped = TableSpec(("day", "f"), time="day", time_order="grouped")
    repeated = np.array([[0.0, 1.0], [1.0, 1.0], [1.0, 2.0], [2.0, 1.0]])
    with pytest.raises(DataError, match=r"data row 3: 1 does not come after 1 \(data row 2\)"):
        check_table(repeated, increasing)
    np.testing.assert_array_equal(check_table(repeated, grouped), repeated)
    with pytest.raises(DataError, match=r"data row 4: 0.5 does not come after 1 \(data row 3\): the rows must be in "
                                        r"time order, the rows of one time together \(a late row is refused\)"):
        check_table(np.array([[0.0, 1.0], [1.0, 1.0], [1.0, 2.0], [0.5, 1.0]]), grouped)
    np.testing.assert_array_equal(check_table(repeated[::-1], TableSpec(("day", "f"), time="day", time_order=None)),
                                  repeated[::-1])


# ------------------------------------------------------------------ Medium: extra columns, '#', extremes
def test_extra_columns_are_refused_naming_them_unless_the_columns_are_named(tmp_path, capsys):
    good = year(tmp_path)
    wide = edited(tmp_path, good, lambda lines: [lines[0] + ",f3"] + [line + ",12.5" for line in lines[1:]],
                  name="wide.csv")
    refused(capsys, wide, r"wide.csv: 1 extra column\(s\) 'f3'; expected only the header day,temperature,f1,f2; "
                          r"name the columns to read with --columns DAY,TEMPERATURE,F1,...,Fn")
    code, out, _ = environment(capsys, good)
    assert code == 0
    code, named, _ = environment(capsys, wide, "--columns", "day,temperature,f1,f2")
    assert code == 0 and named == out                     # the same run on the columns it was told to read
    refused(capsys, wide, r"--columns: expected 4 names \(time, temperature and 2 frequencies for a 2-storey "
                          r"building\), got 3", "--columns", "day,temperature,f1")


@pytest.mark.parametrize("edit, message", [
    (lambda lines: [lines[0], lines[1] + " # recalibrated", *lines[2:]],
     r"column 'f2', line 2: '[0-9.]+ # recalib\.\.\.' holds a '#'; a data file holds no comments \(a reader that "
     r"took them would drop the rest of the row\): remove it"),
    (lambda lines: [lines[0], "# sensor replaced", *lines[1:]], r"line 2 is a comment \('#'\)"),
    (lambda lines: ["# " + lines[0], *lines[1:]], r"the header starts with '#'"),
])
def test_a_hash_inside_a_row_is_refused(tmp_path, capsys, edit, message):
    refused(capsys, edited(tmp_path, year(tmp_path), edit), message)


@pytest.mark.parametrize("value", ["1e-06", "1e+06"])
def test_extreme_frequencies_are_refused_before_the_monitor_runs(tmp_path, capsys, value):
    bad = edited(tmp_path, year(tmp_path), lambda lines: [lines[0]] + [    # f1 = value, f2 = 2.5 value
        ",".join(line.split(",")[:2] + [value, f"{2.5 * float(value):g}"]) for line in lines[1:]])
    refused(capsys, bad, rf"column 'f1' has 6 value\(s\) outside 0.01 to 1000, first {value.replace('+', '.')} at "
                         rf"data row 1 \(line 2\) \(Hz; --frequency-range LOW,HIGH sets the bounds\)")
    # allowed by the bounds, they are still refused: no building of these masses and stiffnesses has them
    refused(capsys, bad, r"the median of column 'f1' is 1e[-+]06 Hz, [0-9.e+-]+ times the building's natural "
                         r"frequency 1 of 3.73 Hz \(from --masses and --stiffness\); the monitor needs them within a "
                         r"factor of 10: check the building, the units \(Hz\) and the column order",
            "--frequency-range", "1e-9,1e9")


def test_a_day_table_that_is_not_probabilities_is_never_printed(tmp_path, capsys, monkeypatch):
    """The issue's frequencies of 1e-6 Hz printed P(M) = 1, 1, 1 after raw RuntimeWarnings. With the bounds and
    the building check out of the way, the monitor's numbers still break down there (frequencies 1e-4 times the
    building's): one line, no table, no output file, no raw warning. Where they only warn (1e-2 times, 4 days),
    the table is printed and the warnings are one line of our own."""
    import seqbayes.studies.environment as study

    monkeypatch.setattr(study, "MAX_FREQUENCY_RATIO", 1e9)

    def scaled(factor, name, **kwargs):
        return edited(tmp_path, year(tmp_path, name=f"{name}-year.csv", **kwargs), lambda lines: [lines[0]] + [
            ",".join(line.split(",")[:2] + [f"{float(v) * factor:.6g}" for v in line.split(",")[2:]])
            for line in lines[1:]], name=f"{name}.csv")
    refused(capsys, scaled(1e-4, "broken"), r"the monitor's numbers broke down on day 1 \(model probabilities 1, 1, "
                                            r"1\); the computation met an invalid value \(NaN: inf - inf, 0 / 0, "
                                            r"...\) \d+ times?: the data lie outside what this building's model can "
                                            r"produce.*; nothing was written",
            "--frequency-range", "1e-9,1e9", "--json", tmp_path / "out.json")
    assert not (tmp_path / "out.json").exists()
    code, out, err = environment(capsys, scaled(1e-2, "warned", n_days=4, sets_per_day=6),
                                 "--frequency-range", "1e-9,1e9")
    assert code == 0 and out.count("\n") == 6 and "alarm day:" in out
    assert re.fullmatch(r"seqbayes environment: warning: the computation met an invalid value \(NaN: inf - inf, 0 / 0, "
                        r"\.\.\.\) \d+ times? \(numpy floating-point warnings\); check the data's units and the "
                        r"options\n", err), err


@pytest.mark.parametrize("value", ["1e6", "1e300"])
def test_extreme_temperatures_are_refused(tmp_path, capsys, value):
    bad = edited(tmp_path, year(tmp_path), lambda lines: [lines[0], "0," + value + "," + lines[1].split(",", 2)[2],
                                                          *lines[2:]])
    refused(capsys, bad, r"column 'temperature' has 1 value\(s\) outside -80 to 80, first 1e\+(06|300) at data row 1 "
                         r"\(line 2\) \(degC; --temperature-range LOW,HIGH sets the bounds\)")


def test_frequencies_out_of_mode_order_are_refused(tmp_path, capsys):
    swapped = edited(tmp_path, year(tmp_path), lambda lines: [lines[0]] + [
        ",".join(line.split(",")[:2] + line.split(",")[2:][::-1]) for line in lines[1:]])
    refused(capsys, swapped, r"data row 1 \(line 2\): f1 = 10.1\d* is not below f2 = [0-9.]+; the columns 'f1', 'f2' "
                             r"must increase along each row \(mode 1 is the lowest; check the column order\)")


# ------------------------------------------------------------------ Medium: hangs and tracebacks
def _no_hang(target, seconds=30.0):
    """Run ``target()`` in a thread; fail if it is still running after ``seconds`` (a FIFO read would block)."""
    result = []

    def run():
        try:
            result.append((True, target()))
        except Exception as err:       # re-raised in the test's thread
            result.append((False, err))
    worker = threading.Thread(target=run, daemon=True)
    worker.start()
    worker.join(seconds)
    assert not worker.is_alive(), "the command hangs"
    done, value = result[0]
    if not done:
        raise value
    return value


def test_a_fifo_is_refused_without_waiting_on_it(tmp_path, capsys):
    from seqbayes.store.modules import read_toml
    from seqbayes.store.sg_report import read_mode_shapes

    os.mkfifo(tmp_path / "year.csv")
    refused(capsys, tmp_path / "year.csv", r"year.csv: is a FIFO \(named pipe\), not a regular file; a data file is "
                                           r"read only from a regular file")
    with pytest.raises(DataError, match="is a FIFO"):
        _no_hang(lambda: read_datafile(tmp_path / "year.csv", TableSpec(("day",))))
    with pytest.raises(ValueError, match=r"is a FIFO \(named pipe\), not a regular file; a TOML run configuration"):
        _no_hang(lambda: read_toml(tmp_path / "year.csv"))             # `seqbayes init FIFO RUN` hung too
    with pytest.raises(ValueError, match=r"--modes: .*year.csv: is a FIFO \(named pipe\)"):
        _no_hang(lambda: read_mode_shapes(tmp_path / "year.csv", 4))   # `seqbayes report --modes FIFO`
    os.mkfifo(tmp_path / "year.nc")
    with pytest.raises(DataError, match=r"year.nc: is a FIFO"):
        _no_hang(lambda: read_datafile(tmp_path / "year.nc", TableSpec(("day",))))
    (tmp_path / "text.nc").write_text("day\n1\n")
    with pytest.raises(DataError, match=r"text.nc: cannot read as NetCDF: the file starts with neither the NetCDF-3 "
                                        r"nor the NetCDF-4/HDF5 signature"):
        read_datafile(tmp_path / "text.nc", TableSpec(("day",)))


def test_dev_zero_and_a_file_over_the_bound_are_refused_before_they_are_read(tmp_path, capsys, monkeypatch):
    os.symlink("/dev/zero", tmp_path / "zero.csv")
    refused(capsys, tmp_path / "zero.csv", r"zero.csv: is a character device, not a regular file")
    with open(tmp_path / "big.csv", "wb") as fh:       # sparse: 1 GiB of nothing
        fh.truncate(MAX_FILE_BYTES + 1)
    reads = []
    real_read = os.read
    monkeypatch.setattr(os, "read", lambda fd, n: reads.append(n) or real_read(fd, n))
    refused(capsys, tmp_path / "big.csv", rf"big.csv: {MAX_FILE_BYTES + 1:,} bytes, more than the "
                                          rf"{MAX_FILE_BYTES:,} bytes a data file may have")
    assert reads == []


@pytest.mark.parametrize("option, value, message", [
    ("--every", "0", r"argument --every: expected an integer >= 1 and <= 1e\+09, got 0"),
    ("--particles", "1000000000", r"argument --particles: expected an integer >= 10 and <= 1e\+07, got 1000000000"),
    ("--particles", "1e3", r"argument --particles: expected an integer, got '1e3'"),
    ("--threshold", "1", r"argument --threshold: expected a number > 0 and < 1, got 1"),
    ("--threshold", "nan", r"argument --threshold: expected a number > 0 and < 1, got nan"),
    ("--consecutive", "0", r"argument --consecutive: expected an integer >= 1"),
    ("--seed", "-1", r"argument --seed: expected an integer >= 0"),
    ("--max-day", "0", r"argument --max-day: expected a number > 0 and <= 1e\+08, got 0"),
    ("--temperature-range", "30,-10", r"argument --temperature-range: expected LOW,HIGH with -10000 <= LOW < HIGH"),
    ("--frequency-range", "0,10", r"argument --frequency-range: expected LOW,HIGH with 1e-09 <= LOW"),
    ("--frequency-range", "1", r"argument --frequency-range: expected LOW,HIGH \(two numbers\), got '1'"),
])
def test_numeric_options_are_bounded_at_parse_time(tmp_path, capsys, option, value, message):
    with pytest.raises(SystemExit) as exit_:
        cli.main(["environment", str(tmp_path / "year.csv"), *BUILDING, option, value])
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and len(err.splitlines()) == 1 and "usage:" not in err
    assert re.search(rf"^seqbayes environment: error: {message}.* \(see seqbayes environment --help\)$", err), err


@pytest.mark.parametrize("argv, message", [
    (["status", "RUN", "--level", "1"], r"argument --level: expected a number > 0 and < 1, got 1"),
    (["predict", "RUN", "--steps", "0"], r"argument --steps: expected an integer >= 1, got 0"),
    (["report", "RUN", "--forecast", "-1"], r"argument --forecast: expected an integer >= 0, got -1"),
    (["report", "RUN", "--horizon", "0"], r"argument --horizon: expected an integer >= 1, got 0"),
    (["update", "RUN", "D", "--lock-timeout", "nan"], r"argument --lock-timeout: expected a number >= 0, got nan"),
    (["init", "C", "RUN", "--lock-timeout", "-1"], r"argument --lock-timeout: expected a number >= 0, got -1"),
])
def test_the_other_commands_numeric_options_are_bounded_too(capsys, argv, message):
    with pytest.raises(SystemExit) as exit_:
        cli.main(argv)
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and len(err.splitlines()) == 1 and re.search(message, err), err


def test_particles_beyond_the_memory_are_refused_after_reading_the_days(tmp_path, capsys, monkeypatch):
    real = os.sysconf
    monkeypatch.setattr(os, "sysconf", lambda name: 1024 if name == "SC_PHYS_PAGES" else real(name))  # 4 MiB
    refused(capsys, year(tmp_path), r"--particles 100000: 3 models over 2 days need about [0-9.]+ GiB of memory; this "
                                    r"machine has 0.00391 GiB", "--particles", "100000")


# ------------------------------------------------------------------ Low
def test_a_bom_header_is_read_as_without_it(tmp_path, capsys):
    good = year(tmp_path)
    (tmp_path / "bom.csv").write_bytes(b"\xef\xbb\xbf" + good.read_bytes())
    plain, with_bom = environment(capsys, good), environment(capsys, tmp_path / "bom.csv")
    assert plain[0] == with_bom[0] == 0 and plain[1] == with_bom[1]


def test_wrong_case_and_semicolons_say_what_was_expected_and_found(tmp_path, capsys):
    good = year(tmp_path)
    upper = edited(tmp_path, good, lambda lines: [lines[0].upper(), *lines[1:]], name="upper.csv")
    refused(capsys, upper, r"upper.csv: missing column\(s\) 'day', 'temperature', 'f1', 'f2'; the header has 'DAY', "
                           r"'TEMPERATURE', 'F1', 'F2' \(expected the header day,temperature,f1,f2\); column names are "
                           r"case-sensitive: the file has 'DAY', 'TEMPERATURE', 'F1' where 'day', 'temperature', 'f1' is "
                           r"expected; or name the file's columns with --columns")
    code, out, _ = environment(capsys, upper, "--columns", "DAY,TEMPERATURE,F1,F2")
    assert code == 0 and out == environment(capsys, good)[1]
    semi = edited(tmp_path, good, lambda lines: [line.replace(",", ";") for line in lines], name="semi.csv")
    refused(capsys, semi, r"semi.csv: missing column\(s\) .*; the header has 'day;temperature;f1;f2' \(expected the "
                          r"header day,temperature,f1,f2\); the file seems to separate its columns by ';': they must be "
                          r"separated by ','")
    rows = edited(tmp_path, good, lambda lines: [lines[0], lines[1].replace(",", ";"), *lines[2:]], name="rows.csv")
    refused(capsys, rows, r"rows.csv: line 2 has 1 fields, the header has 4 \(the line seems to separate its cells "
                          r"by ';'; they must be separated by ','\)")


def test_messages_do_not_leak_numpy_and_a_header_only_file_prints_no_warning(tmp_path, capsys):
    good = year(tmp_path)
    header = edited(tmp_path, good, lambda lines: lines[:1], name="header.csv")
    err = refused(capsys, header, r"^seqbayes environment: error: .*header.csv: no data rows\n$")
    ragged = edited(tmp_path, good, lambda lines: [lines[0], lines[1] + ",3", *lines[2:]], name="ragged.csv")
    err += refused(capsys, ragged, r"ragged.csv: line 2 has 5 fields, the header has 4")
    for leak in ("usecols", "loadtxt", "UserWarning", "numpy"):
        assert leak not in err


def test_read_year_csv_is_the_strict_reader(tmp_path):
    """The studies and benchmarks read years with the same rules as the command (the header's f1..fn)."""
    good = year(tmp_path)
    table = read_year_csv(good)
    assert list(table) == ["day", "temperature", "f1", "f2"] and table["day"].size == 6
    bad = edited(tmp_path, good, lambda lines: [*lines[:3], lines[2], *lines[3:]])
    with pytest.raises(DataError, match=r"bad.csv: column 'day', data row 3 \(line 4\)"):
        read_year_csv(bad)


def test_non_utf8_and_nul_bytes_are_refused_as_not_text(tmp_path, capsys):
    good = year(tmp_path)
    (tmp_path / "nul.csv").write_bytes(good.read_bytes() + b"\0\0")
    refused(capsys, tmp_path / "nul.csv", r"nul.csv: not a text CSV file \(it holds NUL bytes, the first at byte \d+\)")
    (tmp_path / "latin.csv").write_bytes(good.read_bytes().replace(b"day", b"d\xe4y"))
    refused(capsys, tmp_path / "latin.csv", r"latin.csv: not a text CSV file \(byte 1 is not UTF-8 text\)")


# ------------------------------------------------------------------ item 3: no raw warning or traceback
def test_numpy_warnings_become_one_line_of_our_own(tmp_path, capsys, monkeypatch):
    def noisy(args):
        np.log(np.array([-1.0, 0.0]))           # invalid value, divide by zero
        for _ in range(3):                      # each time counted, not only the first at a line
            np.log(np.array([-2.0]))
        print("result")
        return 0

    monkeypatch.setattr(cli.runs, "cmd_status", noisy)
    assert cli.main(["status", "RUN"]) == 0
    out, err = capsys.readouterr()
    assert out == "result\n"
    assert err == ("seqbayes status: warning: the computation met a division by zero 1 time, an invalid value (NaN: "
                   "inf - inf, 0 / 0, ...) 4 times (numpy floating-point warnings); check the data's units and the "
                   "options\n")


def test_any_exception_is_one_line_and_traceback_shows_it(capsys, monkeypatch):
    def bug(args):
        return 1 // 0

    monkeypatch.setattr(cli.runs, "cmd_status", bug)
    assert cli.main(["status", "RUN"]) == 2
    err = capsys.readouterr().err
    assert err == ("seqbayes status: error: ZeroDivisionError in seqbayes: integer division or modulo by zero (a bug: "
                   "please report it with the output of --traceback)\n")
    with pytest.raises(ZeroDivisionError):
        cli.main(["--traceback", "status", "RUN"])

    def memory(args):
        raise MemoryError()

    monkeypatch.setattr(cli.runs, "cmd_status", memory)
    assert cli.main(["status", "RUN"]) == 2
    assert capsys.readouterr().err.startswith("seqbayes status: error: not enough memory for this run")


def test_an_example_with_bad_options_ends_in_one_line(capsys):
    assert cli.main(["example", "quickstart", "--samples", "1"]) == 2
    err = capsys.readouterr().err
    assert err == "seqbayes example quickstart: error: n_samples: must be an integer >= 2, got 1\n"
