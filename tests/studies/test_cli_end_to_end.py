"""The monitoring CLI end to end on a small user model (tests/_user_model.py) written to a folder:
init -> three updates -> status -> predict -> compare -> report, checking the outputs'
content, and bad input giving one clear message with the store unchanged."""

from __future__ import annotations

import base64
import hashlib
import html
import json
import re

import numpy as np
import pytest

from seqbayes import cli

from _user_model import decay_tables, write_config, write_model

# The user's model: free decay of a structure, amplitude A and decay rate b,
# y(t) = A exp(-b t) + noise, its likelihood taking the data as a dict of columns.
# The amplitude degrades by ~0.15 per campaign; the decay rate is constant.
DRIFT_RATE, DRIFT_NOISE = -0.15, 0.02
TRUTH_A = [1.8, 1.65, 1.5]
TRUTH_B = 0.4

BAD_SHAPE = """
def predict(theta, data):
    # the model's value of y at every row, for the report's data-versus-fit panel
    return theta[:, [0]] * np.exp(-theta[:, [1]] * data["t"][None, :])

def bad_shape(theta, data):
    return np.zeros((theta.shape[0], 2))
"""


@pytest.fixture(scope="module")
def work(tmp_path_factory):
    import xarray as xr

    root = tmp_path_factory.mktemp("e2e")
    write_model(root, "e2emodel", noise=0.05, by_name=True, extra=BAD_SHAPE)
    kernels = {"drift": f'A = {{ type = "drift", rate = {DRIFT_RATE}, noise_std = {DRIFT_NOISE} }}',
               "static": "# every parameter static"}
    common = dict(amplitude="A", data='format = "columns"', n_samples=120, seed=7)
    for name, kernel in kernels.items():
        config = write_config(root / f"{name}.toml", "e2emodel", name=name, kernel=kernel, **common)
        config.write_text(config.read_text().replace('likelihood = "e2emodel:loglike"\n',
                                                     'likelihood = "e2emodel:loglike"\npredict = "predict"\n'))
    write_config(root / "badshape.toml", "e2emodel", name="bad", func="bad_shape", **common)
    tables = decay_tables(TRUTH_A, np.linspace(0.0, 4.0, 25), 0.05, seed=12, rate=TRUTH_B)
    for s, table in enumerate(tables):
        if s == 1:   # the second campaign arrives as NetCDF
            t, y = table.T
            xr.Dataset({"t": ("row", t), "y": ("row", y)}).to_netcdf(root / "month2.nc", engine="h5netcdf")
        else:
            np.savetxt(root / f"month{s + 1}.csv", table, delimiter=",", header="t,y", comments="")
    return root


def run(capsys, *args):
    code = cli.main([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out, err


def sha(path):
    return hashlib.sha256(path.read_bytes()).hexdigest()


def test_full_monitoring_session(work, capsys):
    files = [work / "month1.csv", work / "month2.nc", work / "month3.csv"]
    for name in ("drift", "static"):
        code, out, _ = run(capsys, "init", work / f"{name}.toml", work / f"{name}.nc")
        assert code == 0
        assert f"model {name!r}: 2 parameters (A, b), SEMC with N = 120, seed 7" in out
        for s, path in enumerate(files, start=1):
            code, out, err = run(capsys, "update", work / f"{name}.nc", path)
            assert code == 0, err
            match = re.search(rf"step {s} from {path.name}: log-evidence increment (-?[\d.]+), cumulative (-?[\d.]+)",
                              out)
            assert match, out
            # the ESS says what it is, with the final set's distinct count beside it
            assert re.search(r"ESS [\d.]+ of N = 120 \(last tempering stage, before resampling\), \d+ distinct "
                             r"samples after the step", out), out
            assert err == ""   # no progress bar when stderr is not a terminal

    # ---- status: the table's content
    code, out, _ = run(capsys, "status", work / "drift.nc")
    assert code == 0
    lines = out.splitlines()
    assert "model 'drift'" in lines[0] and "steps: 3" in lines[0]
    for s, path in enumerate(files, start=1):
        # acceptance is "-" at a step that moved nothing (SMC^2 moves when the ESS falls)
        assert any(re.match(rf"\s+{s}\s+{re.escape(path.name)}\s+(0\.\d+|-)\s+[\d.]+", line) for line in lines), s
        assert any(re.match(rf"\s+{s}\s+A\s", line) for line in lines)
    code, out, _ = run(capsys, "status", work / "drift.nc", "--json", "--level", "0.9")
    status = json.loads(out)
    assert [r["step"] for r in status["steps"]] == [1, 2, 3]
    assert [r["dataset"] for r in status["steps"]] == [p.name for p in files]
    for r, a_true in zip(status["steps"], TRUTH_A):
        p = r["parameters"]
        # posterior consistent with the truth: within 4 posterior sd (the data are simulated from it)
        assert abs(p["A"]["mean"] - a_true) < 4 * p["A"]["sd"]
        assert abs(p["b"]["mean"] - TRUTH_B) < 4 * p["b"]["sd"]
        assert p["A"]["lower"] < p["A"]["mean"] < p["A"]["upper"]
        assert (r["acceptance_rate"] is None or 0.0 < r["acceptance_rate"] < 1.0) and 0.0 < r["ess"] <= 120.0  # null: no moves
    increments = [r["log_evidence_increment"] for r in status["steps"]]
    assert status["steps"][-1]["log_evidence"] == pytest.approx(sum(increments), rel=1e-12)
    # the 0.9 interval is narrower than the 0.95 one of the text table
    code, out95, _ = run(capsys, "status", work / "drift.nc", "--json")
    p90, p95 = status["steps"][0]["parameters"]["A"], json.loads(out95)["steps"][0]["parameters"]["A"]
    assert p95["lower"] < p90["lower"] and p90["upper"] < p95["upper"]

    # ---- predict: the drift kernel moves the mean by rate per step
    code, out, _ = run(capsys, "predict", work / "drift.nc", "--steps", "2", "--json",
                       "--output", work / "forecast.csv")
    assert code == 0
    forecast = json.loads(out)
    assert [(r["step"], r["ahead"], r["parameter"]) for r in forecast] == [
        (4, 1, "A"), (4, 1, "b"), (5, 2, "A"), (5, 2, "b")]
    last = status["steps"][-1]["parameters"]
    for r in forecast:
        k = r["ahead"]
        if r["parameter"] == "A":
            # mean of N = 120 equal-weight draws propagated k steps: E = mean + k rate, MC sd
            # sqrt(sd^2 + k q^2) / sqrt(N); 5 MC sd as tolerance
            tol = 5 * np.sqrt(last["A"]["sd"] ** 2 + k * DRIFT_NOISE ** 2) / np.sqrt(120)
            assert abs(r["mean"] - (last["A"]["mean"] + k * DRIFT_RATE)) < tol
            assert r["sd"] > last["A"]["sd"]          # the process noise widens the forecast
        else:
            assert abs(r["mean"] - last["b"]["mean"]) < 5 * last["b"]["sd"] / np.sqrt(120)
    draws = np.loadtxt(work / "forecast.csv", delimiter=",", skiprows=1)
    assert draws.shape == (2 * 120, 3) and set(draws[:, 0]) == {4.0, 5.0}
    steps_column = [line.split(",")[0] for line in (work / "forecast.csv").read_text().splitlines()[1:]]
    assert set(steps_column) == {"4", "5"}           # integer steps, not 4.000000000000000000e+00
    code, again, _ = run(capsys, "predict", work / "drift.nc", "--steps", "2", "--json")
    assert again == out                             # a forecast is reproducible and does not change the store
    code, text, _ = run(capsys, "predict", work / "drift.nc", "--steps", "1")
    assert "forecast from step 3" in text and re.search(r"\n\s+4\s+1\s+A\s", text)

    # ---- time to a threshold: A drifts down 0.15 per step from ~1.5; the run's own kernel and posterior
    threshold = round(last["A"]["mean"] - 0.6, 3)     # about four steps of drift below the last mean
    code, out, _ = run(capsys, "predict", work / "drift.nc", "--steps", "8", "--json", "--threshold", f"A<{threshold}")
    assert code == 0
    passage = json.loads(out)["thresholds"][0]
    assert (passage["parameter"], passage["direction"], passage["threshold"]) == ("A", "below", threshold)
    probability = np.array([r["probability"] for r in passage["steps"]])
    assert [r["step"] for r in passage["steps"]] == list(range(4, 12))
    assert abs(probability.sum() + passage["not_crossed"] - 1.0) < 1e-12
    # the mean path crosses after 0.6 / 0.15 = 4 steps; the spread (posterior sd ~0.02, kernel noise 0.02 per
    # step, so ~0.05 after 4 steps, a third of a step's drift) puts nearly all the mass at steps 3-5 ahead
    assert probability[2:5].sum() > 0.95 and passage["median_step"] in (6, 7, 8)
    assert run(capsys, "predict", work / "drift.nc", "--steps", "8", "--json", "--threshold", f"A<{threshold}")[1] == out
    code, text, _ = run(capsys, "predict", work / "drift.nc", "--steps", "3", "--threshold", "b > 0.9")
    assert code == 0 and "time to b > 0.9 from step 3" in text and "P(not crossed by step 6) = 1.0000" in text
    for bad, message in [("Q<1", r"threshold: 'Q' is not a parameter of this run; choose from A, b"),
                         ("A<<1", r"threshold: '<1' in 'A<<1' is not a number"), ("A=1", "NAME<VALUE")]:
        code, _, err = run(capsys, "predict", work / "drift.nc", "--steps", "3", "--threshold", bad)
        assert code == 2 and re.search(message, err), err

    # ---- compare: the drifting model explains the degrading amplitude
    code, out, _ = run(capsys, "compare", work / "drift.nc", work / "static.nc", "--json")
    assert code == 0
    comparison = json.loads(out)
    assert comparison["steps"] == 3 and comparison["best"] == "drift"
    rows = comparison["rows"]
    for s in (1, 2, 3):
        assert sum(r["probability"] for r in rows if r["step"] == s) == pytest.approx(1.0, abs=1e-12)
    drift3 = next(r for r in rows if r["step"] == 3 and r["model"] == "drift")
    assert drift3["log_evidence"] == status["steps"][-1]["log_evidence"]
    assert drift3["probability"] > 0.9
    code, out, _ = run(capsys, "compare", work / "drift.nc", work / "static.nc")
    assert "most probable: drift" in out and "log Bayes factor drift vs static" in out

    # ---- report: an HTML page with every figure embedded
    code, out, _ = run(capsys, "report", work / "drift.nc", "--compare", work / "static.nc",
                       "-o", work / "report.html", "--threshold", f"A<{threshold}", "--horizon", "8")
    assert code == 0 and "report written" in out
    page = (work / "report.html").read_text()
    images = re.findall(r"<img src='data:image/png;base64,([A-Za-z0-9+/=]+)' alt='([^']*)'>", page)
    assert len(images) == 6
    for data, _alt in images:
        png = base64.b64decode(data)
        assert png[:8] == b"\x89PNG\r\n\x1a\n"
        width, height = int.from_bytes(png[16:20], "big"), int.from_bytes(png[20:24], "big")
        assert width >= 400 and height >= 200
    for fig_id in ("fig-parameters", "fig-diagnostics", "fig-evidence", "fig-probabilities", "fig-threshold", "fig-fit"):
        assert f"id='{fig_id}'" in page
    # the model table in the usual notation, not raw JSON
    assert "<td class='l'>U(0.5, 2.5)</td>" in page and "<td class='l'>x - 0.15 + N(0, 0.02)</td>" in page
    assert '"loc"' not in page and "{&quot;" not in page
    # the time to a threshold: the same numbers as predict --threshold (same stored generator state)
    assert "<h2>Time to a threshold</h2>" in page
    first = passage["steps"][3]
    assert f"<td class=''>{first['step']}</td><td class=''>4</td><td class=''>{first['probability']:.4f}</td>" in page
    assert "last tempering stage, before resampling" in page
    assert "3-step forecast" in page and "Most probable model after step 3: <strong>drift</strong>" in page
    # data versus fit: the run keeps its datasets (SMC^2), so by default the last one, with the model's predict
    assert html.escape("Step 3 (month3.csv): the data of column 'y' and the model's prediction (predict)") in page
    code, _, err = run(capsys, "report", work / "drift.nc", "-o", work / "fit1.html", "--data", work / "month1.csv",
                       "--forecast", "0")
    assert code == 0, err
    assert html.escape("Step 1 (month1.csv): the data of column 'y'") in (work / "fit1.html").read_text()
    (work / "other.csv").write_text("t,y\n0,1\n1,0.5\n")
    code, _, err = run(capsys, "report", work / "drift.nc", "-o", work / "fit2.html", "--data", work / "other.csv")
    assert code == 2 and "--data: " in err and "other.csv was not assimilated by" in err, err
    nopredict = work / "nopredict.toml"
    nopredict.write_text((work / "drift.toml").read_text().replace('predict = "predict"', 'predict = "nosuch"'))
    code, _, err = run(capsys, "init", nopredict, work / "nopredict.nc")
    assert code == 2 and "model.predict: module 'e2emodel' has no attribute 'nosuch'" in err, err
    for path in files:
        assert f"<td class='l'>{path.name}</td>" in page
    mean_a3 = f"{status['steps'][-1]['parameters']['A']['mean']:.4g}"
    assert mean_a3 in page
    # figures as separate files
    code, _, _ = run(capsys, "report", work / "drift.nc", "-o", work / "files" / "r.html", "--no-embed",
                     "--forecast", "0")
    assert code == 0
    assert sorted(p.name for p in (work / "files" / "r_figures").iterdir()) == [
        "fig-diagnostics.png", "fig-evidence.png", "fig-fit.png", "fig-parameters.png", "fig-probabilities.png"]
    assert "src='r_figures/fig-parameters.png'" in (work / "files" / "r.html").read_text()

    assert run(capsys, "example", "no-such-study")[0] == 2   # the studies' dispatch is still there
    # `seqbayes example` alone lists the studies, one line each; --version; help without reST markup
    code, out, _ = run(capsys, "example")
    assert code == 0 and all(re.search(rf"^  {re.escape(name)} +\S", out, re.M) for name in cli.EXAMPLES)
    with pytest.raises(SystemExit) as exit_:
        cli.main(["--version"])
    assert exit_.value.code == 0
    from seqbayes import __version__

    assert capsys.readouterr().out.strip() == f"seqbayes {__version__}"
    for command in ([], ["init"], ["update"], ["status"], ["predict"], ["compare"], ["report"]):
        with pytest.raises(SystemExit):
            cli.main([*command, "--help"])
        help_text = capsys.readouterr().out
        assert "usage: seqbayes" in help_text and "``" not in help_text and ":mod:" not in help_text

    # (the console entry point in a fresh interpreter is exercised by tests/unit/test_kill_resume.py)


def test_bad_input_gives_one_clear_message_and_leaves_the_store_unchanged(work, capsys):
    import xarray as xr

    store = work / "guarded.nc"
    assert run(capsys, "init", work / "drift.toml", store)[0] == 0
    assert run(capsys, "update", store, work / "month1.csv")[0] == 0
    before = sha(store)
    t = np.linspace(0, 4, 25)
    (work / "nocol.csv").write_text("t,z\n" + "".join(f"{x},1.0\n" for x in t))
    (work / "nan.csv").write_text("t,y\n" + "".join(f"{x},{'nan' if i == 3 else 1.0}\n" for i, x in enumerate(t)))
    xr.Dataset({"t": ("row", t), "y": (("row", "ch"), np.ones((25, 2)))}).to_netcdf(work / "dim.nc",
                                                                                   engine="h5netcdf")
    cases = [
        (("update", store, work / "nocol.csv"), r"nocol.csv: missing column\(s\) 'y'"),
        (("update", store, work / "nan.csv"), r"nan.csv: column 'y' has 1 NaN/inf value\(s\), first at data row 4"),
        (("update", store, work / "dim.nc"), r"dim.nc: variable 'y' has shape \(25, 2\)"),
        (("update", store, work / "month1.csv"), r"already assimilated as step 1"),
        (("update", store, work / "absent.csv"), r"absent.csv: no such file"),
        (("update", work / "absent.nc", work / "month1.csv"), r"absent.nc: no such run store"),
        (("status", work / "month1.csv"), r"month1.csv: not a run store \(not a NetCDF-4/HDF5 file\)"),
    ]
    for args, message in cases:
        code, out, err = run(capsys, *args)
        assert code == 2, args
        assert len(err.strip().splitlines()) == 1, err        # one line, no traceback
        assert re.search(message, err), err
        assert err.startswith(f"seqbayes {args[0]}: error: ")
        assert sha(store) == before
    # a multi-file update checks every file before assimilating any
    code, _, err = run(capsys, "update", store, work / "month3.csv", work / "nan.csv")
    assert code == 2 and "nan.csv" in err and sha(store) == before
    # corrected data for the last campaign replace it on request
    code, out, _ = run(capsys, "update", store, work / "month3.csv", "--replace-last")
    assert code == 0 and "step 1 from month3.csv" in out
    code, out, _ = run(capsys, "status", store, "--json")
    assert [r["dataset"] for r in json.loads(out)["steps"]] == ["month3.csv"]

    # config errors at init: unknown distribution, likelihood that cannot be imported
    text = (work / "drift.toml").read_text()
    (work / "unknown_dist.toml").write_text(text.replace('dist = "uniform", loc = 0.0', 'dist = "unifrom", loc = 0.0'))
    (work / "no_module.toml").write_text(text.replace("e2emodel:loglike", "nosuchpackage.model:loglike"))
    for name, message in [("unknown_dist", r"unknown_dist.toml: priors.b.dist: unknown scipy.stats distribution "
                                           r"'unifrom'"),
                          ("no_module", r"no_module.toml: model.likelihood: cannot import module "
                                        r"'nosuchpackage.model'")]:
        code, _, err = run(capsys, "init", work / f"{name}.toml", work / f"{name}.nc")
        assert code == 2 and len(err.strip().splitlines()) == 1 and re.search(message, err), err
        assert not (work / f"{name}.nc").exists()

    # a likelihood returning the wrong shape
    assert run(capsys, "init", work / "badshape.toml", work / "badshape.nc")[0] == 0
    before = sha(work / "badshape.nc")
    code, _, err = run(capsys, "update", work / "badshape.nc", work / "month1.csv")
    assert code == 2 and len(err.strip().splitlines()) == 1
    assert re.search(r"month1.csv: likelihood e2emodel:bad_shape: loglike: returned shape \(\d+, 2\) for theta of "
                     r"shape \(\d+, 2\); expected \(\d+,\): .*theta has shape \(\d+, 2\) = \(N, d\).*; the run store is "
                     r"unchanged", err), err
    assert sha(work / "badshape.nc") == before


def test_progress_bars_in_a_terminal(work):
    """In a terminal (a pseudo-terminal here) update shows tqdm bars; elsewhere it is silent
    (checked above: stderr is empty when captured)."""
    import fcntl
    import os
    import pty
    import struct
    import sys
    import termios

    store = work / "tty.nc"
    assert cli.main(["init", str(work / "drift.toml"), str(store)]) == 0
    pid, fd = pty.fork()
    if pid == 0:  # pragma: no cover - the child, whose stdout/stderr are the terminal
        code = 70
        try:
            fcntl.ioctl(0, termios.TIOCSWINSZ, struct.pack("HHHH", 30, 120, 0, 0))
            sys.stdout = open(1, "w", closefd=False, buffering=1)   # past pytest's capture
            sys.stderr = open(2, "w", closefd=False, buffering=1)
            code = cli.main(["update", str(store), str(work / "month1.csv"), str(work / "month2.nc")])
        finally:
            os._exit(code)
    output = b""
    while True:
        try:
            chunk = os.read(fd, 4096)
        except OSError:
            break
        if not chunk:
            break
        output += chunk
    assert os.waitstatus_to_exitcode(os.waitpid(pid, 0)[1]) == 0
    text = output.decode(errors="replace")
    assert re.search(r"datasets: +\d+%\|", text)                # the bar over files
    assert re.search(r"step 1: likelihood: \d+eval", text)       # the likelihood-evaluation counter
    assert "step 2 from month2.nc" in text
