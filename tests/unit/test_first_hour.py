"""Issue 24's input-validation, message, report and first-hour items: one test (or a few) per item.

Each test builds a small run (a line y = a + b t, both parameters drifting, SEMC with N = 40), edits
its files as a careless user or an attacker would, and checks the one-line answer.
"""

from __future__ import annotations

import dataclasses
import json
import warnings
from pathlib import Path

import numpy as np
import pytest
import xarray as xr
from scipy import stats

from seqbayes.engine.settings import from_flat
import seqbayes
from seqbayes import cli
from seqbayes.core.errors import PriorDataConflictWarning, documented
from seqbayes.core.likelihood import ValidatedLikelihood
from seqbayes.store import ConfigError, DataError, StoreError, create_run, load_config, open_run
from seqbayes.store.base import rehash
from seqbayes.store.config import RunConfig, parse_config
from seqbayes.store.datasets import printable, read_datafile
from seqbayes.store.report import render_report

MODEL = '''
import numpy as np

def loglike(theta, data):
    t, y = data[:, 0], data[:, 1]
    return -0.5 * np.sum((y - theta[:, [0]] - theta[:, [1]] * t) ** 2, axis=1) / 0.1**2

def failed_solve(theta, data):
    return np.full(theta.shape[0], np.nan)

def one_sample(theta, data):
    a, b = theta
    return -0.5 * np.sum((data[:, 1] - a - b * data[:, 0]) ** 2)
'''

TOML = '''
[model]
name = "line"
likelihood = "line:{func}"
[data]
columns = ["t", "y"]
[priors]
a = {{ dist = "uniform", loc = -2, scale = 4 }}
b = {{ dist = "norm", loc = 0, scale = 1 }}
[kernel]
a = {{ type = "drift", rate = 0.0, noise_std = 0.05 }}
b = {{ type = "drift", rate = 0.0, noise_std = 0.05 }}
[sampler]
type = "SEMC"
n_samples = 40
seed = 1
{extra}
'''


def table(k):
    t = np.linspace(0, 1, 15)
    y = 0.5 + 0.1 * k + 0.3 * t + 0.1 * np.random.default_rng(k).standard_normal(15)
    return np.column_stack([t, y])


def write(tmp_path, func="loglike", extra="", name="run.toml"):
    (tmp_path / "line.py").write_text(MODEL)
    (tmp_path / name).write_text(TOML.format(func=func, extra=extra))
    return tmp_path / name


@pytest.fixture(scope="module")
def two_steps(tmp_path_factory):
    """A run of two steps, made once for the module."""
    folder = tmp_path_factory.mktemp("two_steps")
    store = create_run(folder / "run.nc", load_config(write(folder)))
    store.assimilate(table(0), "d0.csv")
    store.assimilate(table(1), "d1.csv")
    return folder / "run.nc"


@pytest.fixture
def run(two_steps, tmp_path):
    """A copy of the two-step run in this test's folder (with its likelihood module): its path."""
    import shutil

    write(tmp_path)
    shutil.copyfile(two_steps, tmp_path / "run.nc")
    return tmp_path / "run.nc"


_READ: dict[str, xr.Dataset] = {}


def craft(path, out, edit):
    """``edit(dataset)`` applied to the store at ``path``, hashes redone as a writer would: only the
    checks of content, not the checksums, can catch it. (A store already read, byte for byte, is
    copied from memory: opening one with h5netcdf costs most of a crafted store's time.)"""
    import hashlib

    key = hashlib.sha256(Path(path).read_bytes()).hexdigest()
    if key not in _READ:
        with xr.open_dataset(path, engine="h5netcdf") as stored:
            _READ[key] = stored.load()
    ds = _READ[key].copy(deep=True)
    ds = edit(ds) or ds
    rehash(ds)
    ds.to_netcdf(out, engine="h5netcdf")
    return out


def edit_config(**changes):
    """An edit of the stored configuration (and its fingerprint, so that only validation catches it)."""
    def edit(ds):
        config = json.loads(ds.attrs["config"])
        for key, value in changes.items():
            where = config
            *parents, last = key.split(".")
            for parent in parents:
                where = where[parent]
            where[last] = value
        ds.attrs["config"] = json.dumps(config)
        ds.attrs["model_fingerprint"] = RunConfig(**{**config, "columns": tuple(config["columns"])}).fingerprint()
    return edit


def cli_run(capsys, *argv):
    code = cli.main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


# ----------------------------------------------------------------- the report escapes every stored field
@pytest.mark.slow
def test_the_report_escapes_the_stored_sampler_and_a_store_cannot_name_an_unknown_one(run, tmp_path):
    store = open_run(run)
    store.config = dataclasses.replace(store.config, sampler="<script>alert(1)</script>",
                                       name="<b>bold</b>", likelihood="line:<i>x</i>")
    page = render_report(store, forecast_steps=0)
    assert "<script>" not in page and "<b>bold" not in page and "<i>x" not in page
    assert "&lt;script&gt;alert(1)&lt;/script&gt;" in page
    crafted = craft(run, tmp_path / "c.nc", edit_config(sampler="<script>alert(1)</script>"))
    with pytest.raises(StoreError, match=r"sampler.type: expected \"SEMC\" or \"SMC\""):
        open_run(crafted)


def test_the_sg_report_escapes_its_stored_settings():
    from seqbayes.store import sg_report

    assert sg_report.text("<script>") == "&lt;script&gt;"
    source = Path(sg_report.__file__).read_text()
    # every configuration field interpolated into the page goes through text() (or a number format)
    assert "{cfg.settings['noise_parameters']}" not in source and "N = {cfg.n_members}" not in source


# ----------------------------------------------------------------- control characters in file names
def test_status_escapes_control_characters_of_a_data_file_name(run, capsys):
    store = open_run(run)
    store.assimilate(table(2), "x\x1b[2J\nforged.csv\u202e")
    code, out, _ = cli_run(capsys, "status", run)
    assert code == 0 and "\x1b" not in out and "\u202e" not in out
    assert "x\\x1b[2J\\nforged.csv" in out
    assert len([line for line in out.splitlines() if line.startswith("   3")]) == 3    # one table row, two params
    assert printable("a\x00b\tc", limit=3) == "a\\x..."


def test_errors_escape_control_characters(run, tmp_path, capsys):
    bad = tmp_path / "bad\x1b[31m\n.csv"
    bad.write_text("t,x\n1,2\n")           # no column y
    code, _, err = cli_run(capsys, "update", run, bad, "--quiet")
    assert code == 2 and "\x1b" not in err and err.count("\n") == 1 and "bad\\x1b[31m\\n.csv" in err


# ----------------------------------------------------------------- errors quote short, escaped excerpts
def test_a_file_that_is_not_a_csv_is_not_echoed_and_a_bad_cell_is_cut(tmp_path):
    config = load_config(write(tmp_path), check_likelihood=False)
    secret = "root:$6$saltsalt$" + "h" * 80 + ":19000:0:99999:7:::"
    (tmp_path / "shadow").write_text(secret + "\nbin:*:19000:0:99999:7:::\n")
    with pytest.raises(DataError) as caught:
        read_datafile(tmp_path / "shadow", config)
    assert "saltsalt" not in str(caught.value) and "<" in str(caught.value)   # its length, not its text
    (tmp_path / "cell.csv").write_text("t,y\n1," + "x" * 500 + "\x1b[2J\n")
    with pytest.raises(DataError, match=r"column 'y', line 2: not a number: 'x{20}\.\.\.'") as caught:
        read_datafile(tmp_path / "cell.csv", config)
    assert len(str(caught.value).split(".csv: ")[1]) < 70 and "\x1b" not in str(caught.value)


# ----------------------------------------------------------------- the likelihood cannot reach the run's arrays
def test_setflags_cannot_make_the_likelihoods_inputs_writable_again():
    data = np.arange(6.0).reshape(3, 2)
    kept = data.copy()

    def rewrites_theta(theta, d):
        theta.setflags(write=True)
        theta[:] = -1.0
        return np.zeros(theta.shape[0])

    theta = np.ones((4, 2))
    likelihood = ValidatedLikelihood(rewrites_theta, data)
    likelihood.loglike(theta)
    assert np.all(theta == 1.0)                   # the likelihood changed its own copy only

    def rewrites_data(theta, d):
        root = d
        while isinstance(root.base, np.ndarray):  # the deepest array under the view
            root = root.base
        root.setflags(write=True)
        return np.zeros(theta.shape[0])

    with pytest.raises(ValueError, match="tried to make its data writable"):
        ValidatedLikelihood(rewrites_data, data).loglike(theta)
    columns = {"t": data[:, 0].copy(), "y": data[:, 1].copy()}

    def rewrites_column(theta, d):
        d["t"].setflags(write=True)
        return np.zeros(theta.shape[0])

    with pytest.raises(ValueError, match="tried to make its data writable"):
        ValidatedLikelihood(rewrites_column, columns).loglike(theta)
    assert np.array_equal(data, kept) and np.array_equal(columns["t"], kept[:, 0])


# ----------------------------------------------------------------- settings read from a store are checked
@pytest.mark.parametrize("changes, message", [
    ({"settings.tempering": "false"}, r"sampler.tempering: expected true or false, got 'false'"),
    ({"kernel.a.noise_std": -1.0}, r"kernel.a.noise_std: must be >= 0"),
    ({"n_samples": 0}, r"sampler.n_samples: must be positive"),
    ({"n_samples": 10_000_000_000}, r"sampler.n_samples: 10000000000 samples of 2 parameters need about"),
    ({"priors.b.kwds.scale": float("nan")}, r"priors.b.scale: expected a finite number"),
    ({"executor": "threads"}, r"parallel.executor: expected one of"),
])
def test_a_stored_configuration_is_type_checked_with_the_key_named(run, tmp_path, changes, message):
    crafted = craft(run, tmp_path / "c.nc", edit_config(**changes))
    with pytest.raises(StoreError, match=message):
        open_run(crafted)


@pytest.mark.slow
def test_a_nan_initial_step_size_and_a_crafted_bit_generator_are_refused(run, tmp_path):
    def step_size(ds):
        ds.attrs["initial_step_size"] = float("nan")

    with pytest.raises(StoreError, match="initial_step_size is nan"):
        open_run(craft(run, tmp_path / "a.nc", step_size))
    for name in ("os", "Generator"):
        def generator(ds, name=name):
            states = [str(v) for v in ds["rng_state"].values]
            last = json.loads(states[-1])
            last["bit_generator"] = name
            states[-1] = json.dumps(last)
            ds["rng_state"] = (ds["rng_state"].dims, np.array(states, dtype=object))

        with pytest.raises(StoreError, match=f"rng_state\\[2\\]: rng state: '{name}' is not a numpy bit generator"):
            open_run(craft(run, tmp_path / f"{name}.nc", generator))


@pytest.mark.slow
def test_a_crafted_conflict_window_and_a_renamed_state_variable_are_one_line(run, tmp_path, capsys):
    (tmp_path / "d2.csv").write_text("t,y\n" + "\n".join(f"{t},{y}" for t, y in table(2)))

    def window(ds):
        ds["state_window"] = ds["state_window"] * 0 + 1000

    code, _, err = cli_run(capsys, "update", craft(run, tmp_path / "w.nc", window), tmp_path / "d2.csv")
    assert code == 2 and err.count("\n") == 1 and "state_window: the conflict remedy's window at step 2 holds 1000" in err
    state = next(name for name in xr.open_dataset(run, engine="h5netcdf").variables if name.startswith("mixture_"))

    def rename(ds):
        return ds.rename({state: state + "X"})

    code, _, err = cli_run(capsys, "update", craft(run, tmp_path / "r.nc", rename), tmp_path / "d2.csv")
    assert code == 2 and err.count("\n") == 1 and "damaged run store: the sampler state after step 2" in err
    assert "KeyError" not in err


def test_stored_sg_settings_are_type_checked():
    from seqbayes.store.sg_config import parse_sg_config, SGRunConfig

    raw = {"model": {"name": "two"}, "building": {"masses": [1e3, 1e3], "stiffnesses": [1e6, 1e6],
                                                  "damping_ratios": [0.02, 0.02]},
           "sensors": {"accelerations": [1, 2]}, "data": {"dt": 0.02, "input": "ag", "responses": ["a1", "a2"]},
           "priors": {"lower": 0.5, "upper": 1.5}, "noise": {"measurement_std": 0.05},
           "sampler": {"n_members": 20, "seed": 1, "leverage_correction": True}}
    stored = parse_sg_config(raw).to_dict()
    assert SGRunConfig.from_dict(json.loads(json.dumps(stored))) == parse_sg_config(raw)
    for key, value, message in [("measurement_std", [-0.05, 0.05], "noise.measurement_std: must be positive"),
                                ("process_std", -1.0, "noise.process_std: must be >= 0"),
                                ("dt", float("nan"), "data.dt: expected finite numbers"),
                                ("settings", {"leverage_correction": "false"}, "expected true or false"),
                                ("settings", {"proposal_scale": -1.0}, "sampler.proposal_scale: must be >= 0"),
                                ("n_members", 0, "sampler.n_members")]:
        with pytest.raises(ConfigError, match=message):
            SGRunConfig.from_dict({**stored, key: value})


# ----------------------------------------------------------------- one line instead of a traceback
def test_dask_without_its_extra_is_refused_at_init_naming_it(tmp_path, monkeypatch):
    import importlib.util

    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "distributed" else real(name, *a))
    with pytest.raises(ConfigError, match=r'parallel.executor: "dask" needs .* pip install "seqbayes\[dask\]"'):
        load_config(write(tmp_path, extra='[parallel]\nexecutor = "dask"'))
    pyproject = (Path(__file__).parents[2] / "pyproject.toml").read_text()
    assert 'dask = ["distributed' in pyproject                      # the extra the message names


def test_a_sample_size_beyond_memory_is_refused_before_allocating(tmp_path):
    with pytest.raises(ConfigError, match=r"sampler.n_samples: 10000000000 samples of 2 parameters need about "
                                          r"[0-9.e+]+ GiB of memory; this machine has"):
        parse_config({**_raw(tmp_path), "sampler": {"type": "SEMC", "n_samples": 10_000_000_000}},
                     check_likelihood=False)


def _raw(tmp_path):
    import tomllib

    return tomllib.loads(write(tmp_path).read_text())


@pytest.mark.parametrize("argv, option", [
    (["predict", "{run}", "--steps", "1000000000"], "--steps 1000000000"),
    (["report", "{run}", "--forecast", "100000000", "-o", "{tmp}/r.html"], "--forecast 100000000"),
    (["report", "{run}", "--horizon", "1000000000", "--threshold", "a<0", "-o", "{tmp}/r.html"],
     "--horizon 1000000000"),
])
def test_huge_horizons_are_refused_in_one_line(run, tmp_path, capsys, argv, option):
    code, _, err = cli_run(capsys, *[a.format(run=run, tmp=tmp_path) for a in argv])
    assert code == 2 and err.count("\n") == 1 and f"error: {option}: the command line simulates at most" in err
    assert not (tmp_path / "r.html").exists()
    limit = min(cli.MAX_SIMULATED // 40, cli.MAX_FORECAST_STEPS if option[2] != "h" else cli.MAX_SIMULATED)
    assert f"at most {limit} steps ahead for N = 40" in err


# ----------------------------------------------------------------- lenient CSV
@pytest.mark.parametrize("text, message", [
    ("t,y\n0,1_0\n1,2\n", r"column 'y', line 2: not a number: '1_0'"),
    ("t,y\n0,\uff11\n1,2\n", r"column 'y', line 2: not a number: '\uff11'"),
    ("t,y,y\n0,1,2\n", r"column\(s\) 'y' appear more than once in the header"),
    ("t,y\n0,1\n,\n1,2\n", r"line 3 has only empty cells"),
    ("t,y\n0,1\n , \n1,2\n", r"line 3 has only empty cells"),
])
def test_lenient_csv_is_refused(tmp_path, text, message):
    config = load_config(write(tmp_path), check_likelihood=False)
    (tmp_path / "d.csv").write_text(text, encoding="utf-8")
    with pytest.raises(DataError, match=message):
        read_datafile(tmp_path / "d.csv", config)


def test_a_bom_header_is_read_and_blank_lines_still_skipped(tmp_path):
    config = load_config(write(tmp_path), check_likelihood=False)
    (tmp_path / "bom.csv").write_bytes("\ufefft,y\n0,1.5\n\n1,2e0\n".encode())
    assert read_datafile(tmp_path / "bom.csv", config).tolist() == [[0.0, 1.5], [1.0, 2.0]]
    (tmp_path / "quoted.csv").write_text('t,y\n"0","-.5"\n"1","+3E-1"\n')
    assert read_datafile(tmp_path / "quoted.csv", config).tolist() == [[0.0, -0.5], [1.0, 0.3]]


# ----------------------------------------------------------------- the first hour
def test_an_all_nan_likelihood_blames_the_model_not_the_prior(tmp_path, capsys):
    create_run(tmp_path / "nan.nc", load_config(write(tmp_path, func="failed_solve")))
    (tmp_path / "d.csv").write_text("t,y\n" + "\n".join(f"{t},{y}" for t, y in table(0)))
    code, _, err = cli_run(capsys, "update", tmp_path / "nan.nc", tmp_path / "d.csv")
    assert code == 2 and "the likelihood returned NaN for every sample (40 evaluations)" in err
    assert "prior is too far" not in err


def test_an_all_nan_likelihood_under_smc2_blames_the_model_too():
    """Static and drifting parameters together (SMC^2): the same message from the inner filters' estimates."""
    prior = seqbayes.JointPrior({"a": stats.norm(0, 1), "b": stats.norm(0, 1)})
    kernel = seqbayes.MarkovKernel([seqbayes.Drift(0.0, noise_std=0.1), seqbayes.Static()])
    sampler = seqbayes.SMC(prior, kernel, lambda theta, y: np.full(theta.shape[0], np.nan), n_samples=50, rng=0, **from_flat("SMC", n_inner=5))
    with pytest.raises(seqbayes.ZeroLikelihoodError, match="the likelihood returned NaN for every sample"):
        sampler.update(1.0)


def test_status_json_writes_null_not_nan(run, capsys):
    code, out, _ = cli_run(capsys, "status", run, "--json")
    assert code == 0 and "NaN" not in out
    json.loads(out, parse_constant=lambda name: pytest.fail(f"bare {name} in JSON"))
    assert "null" in out          # the run's NaN fields (no jump kernel: jump_size, ...) are null


def test_warnings_are_one_line_each_and_point_at_documentation_that_ships(run, monkeypatch, capsys):
    def warns(args):
        warnings.warn("step 4: prior-data conflict\nsecond line", PriorDataConflictWarning)
        return 0

    monkeypatch.setattr(cli.runs, "cmd_status", warns)
    code, _, err = cli_run(capsys, "status", run)
    assert code == 0 and err == "seqbayes: warning: PriorDataConflictWarning: step 4: prior-data conflict\\nsecond line\n"
    pointer = documented("prior_data_conflict")
    assert "seqbayes/data/WARNINGS.md" in pointer and "prior_data_conflict" in pointer
    root = Path(__file__).parents[2]
    shipped = root / "src" / "seqbayes" / "data" / "WARNINGS.md"
    assert "PriorDataConflictWarning" in shipped.read_text() and "InnerFilterWarning" in shipped.read_text()
    pyproject = (root / "pyproject.toml").read_text()
    assert '"data/*.md"' in pyproject   # WARNINGS.md ships in the wheel


def test_the_coulomb_study_names_its_kernels():
    from seqbayes.models.coulomb import KERNELS
    from seqbayes.studies.coulomb import kernel_legend

    legend = kernel_legend()
    assert legend.startswith("T1 = linear drift") and "T2 = exponential decay" in legend
    assert f"{abs(KERNELS['T1'][1]):g}" in legend and f"exp(-{KERNELS['T2'][1]:g})" in legend


def test_the_reports_acceptance_column_agrees_with_status(run, monkeypatch):
    from seqbayes.store import report

    real = report.status_rows

    def no_moves(store, level=0.95):
        rows = real(store, level)
        rows[1]["acceptance_rate"] = float("nan")       # a step that moved no samples (SMC^2)
        return rows

    monkeypatch.setattr(report, "status_rows", no_moves)
    store = open_run(run)
    page = render_report(store, forecast_steps=0)
    assert "<td class=''>nan</td>" not in page and "<td class=''>-</td>" in page
    assert "accept '-': the step moved no samples" in page
    assert "accept '-': the step moved no samples" in report.format_status(store).replace("\n", " ")


def test_config_messages(tmp_path):
    raw = _raw(tmp_path)
    with pytest.raises(ConfigError) as caught:
        parse_config({**raw, "sampler": {"n_sample": 10}}, check_likelihood=False)
    assert "did you mean 'n_samples'?" in str(caught.value)
    assert all(key in str(caught.value).split("expected one of")[1] for key in ("n_samples", "seed", "type"))
    with pytest.raises(ConfigError, match=r"priors.a.lco: scipy.stats.uniform has no parameter 'lco' \(did you mean "
                                          r"'loc'\?\); it takes loc, scale, lower, upper"):
        parse_config({**raw, "priors": {"a": {"dist": "uniform", "lco": 0, "scale": 1}}}, check_likelihood=False)
    with pytest.raises(ConfigError, match=r"priors.b.shape: scipy.stats.gamma has no parameter 'shape'.*it takes a, "
                                          r"loc, scale"):
        parse_config({**raw, "priors": {"b": {"dist": "gamma", "shape": 2}}}, check_likelihood=False)
    bounds = parse_config({**raw, "priors": {**raw["priors"], "a": {"dist": "uniform", "lower": -2, "upper": 2}}},
                          check_likelihood=False)
    assert bounds.priors["a"] == {"dist": "uniform", "args": [], "kwds": {"loc": -2.0, "scale": 4.0}}
    assert bounds.fingerprint() == parse_config(raw, check_likelihood=False).fingerprint()
    for prior, message in [({"dist": "uniform", "lower": 2, "upper": 1}, "priors.a.upper: must be above lower"),
                           ({"dist": "uniform", "lower": 0, "upper": 1, "loc": 0}, "lower and upper together")]:
        with pytest.raises(ConfigError, match=message):
            parse_config({**raw, "priors": {"a": prior}}, check_likelihood=False)


def test_a_likelihood_that_is_not_vectorised_is_told_theta_is_n_by_d(tmp_path, capsys):
    create_run(tmp_path / "one.nc", load_config(write(tmp_path, func="one_sample")))
    (tmp_path / "d.csv").write_text("t,y\n" + "\n".join(f"{t},{y}" for t, y in table(0)))
    code, _, err = cli_run(capsys, "update", tmp_path / "one.nc", tmp_path / "d.csv")
    assert code == 2 and err.count("\n") == 1
    assert "too many values to unpack (expected 2)" in err and "theta has shape (40, 2) = (N, d)" in err


# ----------------------------------------------------------------- ArviZ
@pytest.mark.slow  # two runs of three steps
def test_arviz_independent_runs_are_chains_and_the_step_a_dimension(tmp_path):
    az = pytest.importorskip("arviz")
    results = []
    for seed in (1, 2):
        config = dataclasses.replace(load_config(write(tmp_path)), seed=seed)
        store = create_run(tmp_path / f"s{seed}.nc", config)
        for k in range(3):
            store.assimilate(table(k), f"d{k}.csv")
        results.append(store.result)
    idata = results[0].to_arviz(runs=results[1:])
    assert idata.posterior["a"].dims == ("chain", "draw", "step") and idata.posterior["a"].shape == (2, 40, 3)
    assert idata.sample_stats["ess"].dims == ("chain", "step")
    assert np.array_equal(idata.sample_stats["log_evidence"].values,
                          [[r.info.log_evidence for r in result.steps] for result in results])
    # one run's chain is the export without runs, draw for draw
    assert np.array_equal(idata.posterior["a"].values[0], results[0].to_arviz().posterior["a"].values[0])
    with warnings.catch_warnings():
        warnings.simplefilter("error")                   # no "Shape validation failed" with two runs
        summary = az.summary(idata, var_names=["a"], coords={"step": [3]})
    assert np.isfinite(summary["r_hat"]).all()
    with pytest.raises(ValueError, match=r"runs\[0\]: expected a run of \('a', 'b'\) with 3 steps"):
        results[0].to_arviz(runs=[dataclasses.replace(results[1], steps=results[1].steps[:2])])
