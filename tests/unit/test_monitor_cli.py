"""``seqbayes environment`` as a replay through a monitor run store, and the store's commands on it."""

from __future__ import annotations

import json

import numpy as np

from seqbayes import cli
from seqbayes.store import open_run


def write_year(path, n_days=3, seed=2, nan_text=False):
    rng = np.random.default_rng(seed)
    rows = ["day,temperature,f1,f2"]
    for d in range(n_days):
        for t in d + np.sort(rng.uniform(0, 1, 5)):
            air = 5 + 8 * np.sin(2 * np.pi * t) + rng.normal()
            f = np.array([2.0, 5.5]) * np.exp(-0.0008 * (air - 10) + rng.normal(0, 0.003, 2))
            cells = [repr(float(x)) for x in f]
            if rng.random() < 0.2:
                cells[1] = "nan" if nan_text else ""
            rows.append(f"{float(t)!r},{float(air)!r},{cells[0]},{cells[1]}")
    path.write_text("\n".join(rows) + "\n")
    return path


def test_environment_replays_through_a_store_that_update_continues(tmp_path, capsys):
    year = write_year(tmp_path / "year.csv", seed=3)
    store = tmp_path / "kept.nc"
    argv = ["environment", str(year), "--frequencies", "2.0,5.5", "--particles", "16", "--store", str(store),
            "--json", str(tmp_path / "out.json")]
    assert cli.main(argv) == 0
    out = capsys.readouterr().out
    assert "alarm day: None" in out and "run store:" in out
    summary = json.loads((tmp_path / "out.json").read_text())
    kept = open_run(store)
    assert summary["p_damage"] == [i["p_damage"] for i in kept.infos] and kept.n_steps == 3
    nxt = tmp_path / "day3.csv"
    nxt.write_text("day,temperature,f1,f2\n3.2,6.0,2.001,5.49\n3.6,7.5,,5.495\n")
    assert cli.main(["update", str(store), str(nxt)]) == 0
    assert "step 4 from day3.csv: day 3 (2 sets)" in capsys.readouterr().out
    assert cli.main(["status", str(store), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["steps"][-1]["day"] == 3


def test_a_nan_cell_is_refused_where_an_empty_one_is_a_missing_mode(tmp_path, capsys):
    year = write_year(tmp_path / "year.csv", n_days=1, seed=5, nan_text=True)
    code = cli.main(["environment", str(year), "--frequencies", "2.0,5.5", "--particles", "16"])
    err = capsys.readouterr().err
    if "nan" in year.read_text():
        assert code == 2 and "a cell holds 'nan'" in err and len(err.splitlines()) == 1
