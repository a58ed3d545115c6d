"""The monitor run store (docs/environment.md, "The monitor run store"): resumption bit for bit, the work of a
resumed day, both dataset forms, and refusals that leave the store byte-identical."""

from __future__ import annotations

import json

import numpy as np
import pytest

from seqbayes.store import DataError, DuplicateDatasetError, StoreError, create_run, load_config, open_run
from seqbayes.structural.monitor.table import monitor_table

TOML = """
[model]
name = "two-modes"
[monitor]
model = "modes"
frequencies = [2.0, 5.5]
n_particles = 32
seed = 7
"""


def year_table(n_days=4, seed=4):
    rng = np.random.default_rng(seed)
    day = np.concatenate([d + np.sort(rng.uniform(0, 1, 6)) for d in range(n_days)])
    air = 4 + 6 * np.sin(2 * np.pi * day) + rng.normal(0, 1, day.size)
    f = np.array([2.0, 5.5]) * np.exp(-0.0008 * (air[:, None] - 10) + rng.normal(0, 0.003, (day.size, 2)))
    f[day >= 2, 1] *= 0.98
    f[rng.random(f.shape) < 0.2] = np.nan
    return {"day": day, "temperature": air, "f1": f[:, 0], "f2": f[:, 1]}


def cell(v):
    return "" if not np.isfinite(v) else repr(float(v))


def write_days(folder, table):
    """One year-CSV file per calendar day; returns the paths."""
    paths = []
    rows = np.floor(table["day"]).astype(int)
    for d in np.unique(rows):
        path = folder / f"day{d}.csv"
        lines = ["day,temperature,f1,f2"] + [",".join(cell(table[k][i]) for k in ("day", "temperature", "f1", "f2"))
                                             for i in np.flatnonzero(rows == d)]
        path.write_text("\n".join(lines) + "\n")
        paths.append(path)
    return paths


@pytest.fixture
def run(tmp_path):
    (tmp_path / "monitor.toml").write_text(TOML)
    config = load_config(tmp_path / "monitor.toml")
    create_run(tmp_path / "store.nc", config)
    return tmp_path, config


def _numbers(info):
    return {k: v for k, v in info.items() if k != "cpu_seconds"}


@pytest.mark.slow
def test_store_day_by_day_across_processes_equals_the_whole_table(run):
    folder, config = run
    table = year_table()
    paths = write_days(folder, table)
    for path in paths:                                    # a fresh open for every day, as a new process would
        store = open_run(folder / "store.nc")
        store.update(path)
    store = open_run(folder / "store.nc")
    whole = monitor_table(table, config.build_model(), np.random.default_rng(config.seed), config.build_settings())
    assert [_numbers(i) for i in store.infos] == [_numbers({"step": k + 1, **d.to_dict()})
                                                  for k, d in enumerate(whole)]
    assert store.infos[-1]["p_damage"] > 0.9            # the 2 % drop of mode 2 from day 2 is found
    p_mode = store.infos[-1]["damage"]["class_probabilities"]
    assert p_mode[1] > 0.9 and p_mode[1] > p_mode[0]


@pytest.mark.slow
def test_a_resumed_day_costs_the_day_not_the_history(run):
    folder, config = run
    paths = write_days(folder, year_table(n_days=6))
    store = open_run(folder / "store.nc")
    for path in paths:
        store.update(path)
    n = config.n_particles
    for k, info in enumerate(store.infos):
        chunks = k + 1                                  # one chunk per day so far
        # the day's own chunk for every particle, plus one pass over the history per proposal of each sweep
        assert n <= info["filter_updates"] <= n + info["n_sweeps"] * n * chunks
        if info["n_sweeps"] == 0:
            assert info["filter_updates"] == n
    assert any(i["n_sweeps"] == 0 for i in store.infos[1:])
    # a reopened store redoes none of the earlier days: the work of the last day is the uninterrupted run's
    again = open_run(folder / "store.nc")
    fresh = create_run(folder / "other.nc", config)
    for path in paths[:-1]:
        fresh.update(path, write=False)
    fresh.write()
    resumed = open_run(folder / "other.nc")
    info = resumed.update(paths[-1])
    assert info["filter_updates"] == again.infos[-1]["filter_updates"]
    assert _numbers(info) == _numbers(again.infos[-1])


def test_a_tracked_modes_table_equals_the_year_rows(run):
    """Both dataset forms give the same table, hence the same bits (in memory: the writes are tested above)."""
    folder, config = run
    table = year_table(n_days=2)
    paths = write_days(folder, table)
    rows = np.floor(table["day"]).astype(int)
    modes = []
    for d in (0, 1):
        lines = ["day,mode,frequency_hz,std_frequency_hz,temperature"]
        for i in np.flatnonzero(rows == d):
            for m in (1, 2):
                if np.isfinite(table[f"f{m}"][i]):
                    lines.append(f"{cell(table['day'][i])},{m},{cell(table[f'f{m}'][i])},,{cell(table['temperature'][i])}")
        path = folder / f"modes{d}.csv"
        path.write_text("\n".join(lines) + "\n")
        modes.append(path)
    a = open_run(folder / "store.nc")
    b = open_run(folder / "store.nc")
    for path, other in zip(paths, modes):
        np.testing.assert_array_equal(a.read_datafile(path), b.read_datafile(other))
        a.update(path, write=False)
        b.update(other, write=False)
    assert [_numbers(i) for i in a.infos] == [_numbers(i) for i in b.infos]


@pytest.fixture(scope="module")
def one_day(tmp_path_factory):
    """The bytes of a store after its first day (made once for the module)."""
    folder = tmp_path_factory.mktemp("one_day")
    (folder / "monitor.toml").write_text(TOML)
    store = create_run(folder / "store.nc", load_config(folder / "monitor.toml"))
    store.update(write_days(folder, year_table(n_days=1))[0])
    return (folder / "store.nc").read_bytes()


@pytest.mark.parametrize("text, expected", [
    ("day,temperature,f1,f2,f3\n1.1,5,2.0,5.5,9.0\n", "f3"),                     # an extra mode column
    ("day,temperature,f1,f2\n1.1,5,2.0,5.5\n1.0,5,2.0,5.5\n", "does not come after"),   # late set
    ("day,temperature,f1,f2\n1.1,5,2.0,5.5\n2.1,5,2.0,5.5\n", "2 calendar days"),
    ("day,temperature,f1,f2\n1.1,5,2.0 # x,5.5\n", "'#'"),
    ("day,temperature,f1,f2\n1.1,1e6,2.0,5.5\n", "temperature"),
    ("day,temperature,f1,f2\n1.1,5,2e-6,5.5\n", "f1"),
    ("day,temperature,f1,f2\n1.1,5,25.0,60.0\n", "times its reference"),
    ("day,temperature,f1,f2\n1e20,5,2.0,5.5\n", "day"),
    ("day,mode,frequency_hz,temperature\n1.1,3,2.0,5\n", "mode"),
    ("day,mode,frequency_hz,temperature\n1.1,1,2.0,5\n1.1,1,2.1,5\n", "twice"),
    ("day,frequency_hz\n1.1,2.0\n", "untracked"),
    ("a;b\n1;2\n", "neither"),
])
def test_bad_datasets_give_one_line_and_leave_the_store_unchanged(one_day, tmp_path, text, expected):
    folder = tmp_path
    (folder / "store.nc").write_bytes(one_day)
    before = (folder / "store.nc").read_bytes()
    bad = folder / "bad.csv"
    bad.write_text(text)
    with pytest.raises(DataError) as err:
        open_run(folder / "store.nc").update(bad)
    assert expected in str(err.value) and "\n" not in str(err.value)
    assert (folder / "store.nc").read_bytes() == before


def test_duplicate_and_earlier_days_refused(run):
    folder, _ = run
    paths = write_days(folder, year_table(n_days=2))
    store = open_run(folder / "store.nc")
    store.update(paths[0], write=False)
    store.update(paths[1])
    before = (folder / "store.nc").read_bytes()
    with pytest.raises(DuplicateDatasetError):
        open_run(folder / "store.nc").update(paths[1])
    copy = folder / "copy.csv"
    lines = paths[0].read_text().splitlines()
    copy.write_text("\n".join([lines[0], lines[1].replace(lines[1].split(",")[1], "7.5", 1)]) + "\n")
    with pytest.raises(DataError, match="not after the last set"):
        open_run(folder / "store.nc").update(copy)
    assert (folder / "store.nc").read_bytes() == before
    with pytest.raises(StoreError, match="replace-last"):
        open_run(folder / "store.nc").update(paths[1], replace_last=True)


def test_a_damaged_store_is_refused(run):
    folder, _ = run
    store = open_run(folder / "store.nc")
    first, second = write_days(folder, year_table(n_days=2))
    store.update(first, write=False)
    store.update(second)
    data = bytearray((folder / "store.nc").read_bytes())
    (folder / "cut.nc").write_bytes(bytes(data[: len(data) // 2]))
    with pytest.raises(StoreError):
        open_run(folder / "cut.nc")
    status = open_run(folder / "store.nc").status_json()
    assert status["kind"] == "monitor" and len(status["steps"]) == 2
    json.dumps(status)
