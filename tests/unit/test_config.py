"""TOML run configuration and data files: validation errors name the file and the field."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from seqbayes import Decay, Drift, Static
from seqbayes.store.config import ConfigError, load_config, parse_config
from seqbayes.store.datasets import DataError, dataset_digest, read_datafile

from _user_model import write_model

CONFIG = """
[model]
name = "decay"
likelihood = "cfgmodel:loglike"
[data]
columns = ["t", "y"]
[priors]
a = { dist = "uniform", loc = 0.5, scale = 2.0 }
b = { dist = "lognorm", args = [0.5], scale = 0.4 }
c = { dist = "norm", loc = 0.0, scale = 1.0 }
[kernel]
a = { type = "drift", rate = -0.05, noise_std = 0.02 }
b = { type = "decay", rate = 0.1, noise_std = 0.01 }
[sampler]
type = "SEMC"
n_samples = 64
seed = 5
tempering = false
"""


def write(tmp_path, config=CONFIG, name="run.toml"):
    write_model(tmp_path, "cfgmodel", extra="not_callable = 3\n")
    path = tmp_path / name
    path.write_text(config)
    return path


def test_valid_config_builds_prior_kernel_and_sampler(tmp_path):
    cfg = load_config(write(tmp_path))
    assert cfg.names == ("a", "b", "c")
    assert cfg.columns == ("t", "y")
    assert cfg.sampler == "SEMC" and cfg.n_samples == 64 and cfg.seed == 5
    assert cfg.settings == {"tempering": False}
    prior = cfg.build_prior()
    x = np.array([[1.0, 0.3, 0.2]])
    expected = (stats.uniform(0.5, 2.0).logpdf(1.0) + stats.lognorm(0.5, scale=0.4).logpdf(0.3)
                + stats.norm(0, 1).logpdf(0.2))
    assert prior.logpdf(x)[0] == pytest.approx(expected, rel=1e-14)
    kernel = cfg.build_kernel()
    assert [type(c) for c in kernel.components] == [Drift, Decay, Static]   # c not listed -> static
    assert kernel.components[0].rate == -0.05 and kernel.components[1].noise_std == 0.01
    sampler = cfg.build_sampler()
    assert type(sampler.config.tempering).__name__ == "Single" and sampler.config.n_samples == 64
    # the likelihood was imported from the folder next to the config
    assert cfg.load_likelihood()(np.array([[1.0, 0.0, 0.0]]), np.array([[0.0, 1.0]]))[0] == 0.0


def test_fingerprint_ignores_name_and_executor_but_not_the_model(tmp_path):
    base = load_config(write(tmp_path))
    renamed = load_config(write(tmp_path, CONFIG.replace('name = "decay"', 'name = "other"')
                                + "[parallel]\nexecutor = \"processes\"\n", "b.toml"))
    assert renamed.fingerprint() == base.fingerprint()
    changed = load_config(write(tmp_path, CONFIG.replace("rate = -0.05", "rate = -0.06"), "c.toml"))
    assert changed.fingerprint() != base.fingerprint()
    assert type(base).from_dict(base.to_dict()) == base


@pytest.mark.parametrize("old, new, message", [
    ('dist = "norm"', 'dist = "nrom"', r"run.toml: priors.c.dist: unknown scipy.stats distribution 'nrom'"),
    ('dist = "norm"', 'dist = "poisson", mu = 2', r"priors.c.dist: 'poisson' is discrete"),
    ('loc = 0.0, scale = 1.0 }', 'loc = 0.0, scale = -1.0 }', r"priors.c: invalid parameters"),
    ('args = [0.5]', 'args = ["x"]', r"priors.b.args\[0\]: expected a number"),
    ('likelihood = "cfgmodel:loglike"', 'likelihood = "nosuchmodule:loglike"',
     r"run.toml: model.likelihood: cannot import module 'nosuchmodule'"),
    ('likelihood = "cfgmodel:loglike"', 'likelihood = "cfgmodel:missing"',
     r"model.likelihood: module 'cfgmodel' has no attribute 'missing'"),
    ('likelihood = "cfgmodel:loglike"', 'likelihood = "cfgmodel:not_callable"', r"is not callable"),
    ('likelihood = "cfgmodel:loglike"', 'likelihood = "cfgmodel.loglike"', r"model.likelihood: expected \"module:function\""),
    ('type = "drift"', 'type = "drfit"', r"kernel.a.type: expected one of static, drift, decay, jump, got 'drfit'"),
    ('rate = -0.05, noise_std = 0.02', 'noise_std = 0.02', r"kernel.a.rate: missing"),
    ('noise_std = 0.02', 'noise_std = -0.02', r"kernel.a.noise_std: must be >= 0"),
    ('[sampler]', '[sampler]\nstep_sise = 2.0', r"sampler.step_sise: unknown setting"),
    ('type = "SEMC"', 'type = "SMC"\nstep_size = 2.0', r"sampler.step_size: unknown setting"),
    ('type = "SEMC"', 'type = "MCMC"', r"sampler.type: expected \"SEMC\" or \"SMC\""),
    ('n_samples = 64', 'n_samples = 4', r"sampler.n_samples: SEMC needs at least 2 d = 6"),
    ('n_samples = 64', 'n_samples = 64.5', r"sampler.n_samples: expected an integer"),
    ('tempering = false', 'tempering_ess = 1.5', r"sampler: tempering_ess: must lie in \(0, 1\]"),
    ('tempering = false', 'predictive = "history"',
     r"sampler.predictive: predictive: History .* needs a kernel whose every parameter is Static"),
    ('tempering = false', 'predictive = "histroy"', r"sampler: predictive: expected one of"),
    ('columns = ["t", "y"]', 'columns = []', r"data.columns: expected a non-empty list"),
    ('[model]', '[modle]\n[model]', r"<top level>.modle: unknown setting"),
    ('[kernel]', '[kernel]\nd = { type = "static" }', r"kernel.d: not a parameter; the priors define a, b, c"),
])
def test_each_mistake_gives_one_message_naming_the_field(tmp_path, old, new, message):
    assert old in CONFIG
    path = write(tmp_path, CONFIG.replace(old, new, 1))
    with pytest.raises(ConfigError, match=message):
        load_config(path)


def test_missing_file_and_bad_toml(tmp_path):
    with pytest.raises(ConfigError, match="no such file"):
        load_config(tmp_path / "absent.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text("[model\nlikelihood = 1")
    with pytest.raises(ConfigError, match="bad.toml: invalid TOML"):
        load_config(bad)
    with pytest.raises(ConfigError, match=r"\[priors\]: missing section"):
        parse_config({"model": {"likelihood": "m:f"}, "data": {"columns": ["y"]}}, check_likelihood=False)


def test_columns_format_hands_a_dict_to_the_likelihood(tmp_path):
    from seqbayes.store.datasets import as_likelihood_data

    cfg = load_config(write(tmp_path, CONFIG.replace('columns = ["t", "y"]', 'columns = ["t", "y"]\nformat = "columns"')))
    table = np.array([[0.0, 1.0], [1.0, 2.0]])
    data = as_likelihood_data(table, cfg)
    assert set(data) == {"t", "y"} and np.array_equal(data["y"], [1.0, 2.0])


# ------------------------------------------------------------------ data files
def test_csv_and_netcdf_give_the_same_table_and_digest(tmp_path):
    import xarray as xr

    cfg = load_config(write(tmp_path))
    t = np.linspace(0, 1, 7)
    y = np.cos(t)
    (tmp_path / "d.csv").write_text("y,extra,t\n" + "".join(f"{float(b)!r},0,{float(a)!r}\n" for a, b in zip(t, y)))
    xr.Dataset({"t": ("row", t), "y": ("row", y)}).to_netcdf(tmp_path / "d.nc", engine="h5netcdf")
    a = read_datafile(tmp_path / "d.csv", cfg)
    b = read_datafile(tmp_path / "d.nc", cfg)
    np.testing.assert_array_equal(a, np.column_stack([t, y]))   # columns reordered as configured, exact floats
    np.testing.assert_array_equal(a, b)
    assert dataset_digest(a, cfg.columns) == dataset_digest(b, cfg.columns)
    assert dataset_digest(a, cfg.columns) != dataset_digest(a[:-1], cfg.columns)


def test_the_fast_csv_reader_gives_the_cell_readers_numbers(tmp_path, monkeypatch):
    """The numpy path of the CSV reader (separators counted, numbers by loadtxt) and the cell-by-cell
    path give the same arrays bit for bit, whichever the file's shape; files the fast path refuses
    (quotes, ragged or blank-celled lines) go to the cell reader."""
    import seqbayes.store.datasets as datasets

    cfg = load_config(write(tmp_path, CONFIG))
    files = {
        "plain.csv": "t,y\n0,1.5\n1,2.25e-3\n2,-3\n",
        "crlf.csv": "t,y\r\n0,1.5\r\n1,2\r\n",
        "extra.csv": "y,note,t\n1.5,abc,0\n2,x,1\n",           # a text column that is not read
        "blank_lines.csv": "t,y\n0,1\n\n1,2\n\n",
        "no_final_newline.csv": "t,y\n0,1\n1, 2 ",
        "quoted.csv": 't,y\n"0",1\n1,"2"\n',
    }
    fallbacks = []
    cells = datasets._read_csv_cells
    monkeypatch.setattr(datasets, "_read_csv_cells", lambda *a: fallbacks.append(a[0].name) or cells(*a))
    for name, text in files.items():
        (tmp_path / name).write_bytes(text.encode())
        header = [h.strip() for h in text.splitlines()[0].split(",")]
        index = datasets._csv_header(tmp_path / name, header, cfg)
        expected, _ = cells(tmp_path / name, text, cfg.columns, header, index)
        np.testing.assert_array_equal(read_datafile(tmp_path / name, cfg), expected)
    assert sorted(fallbacks) == ["quoted.csv"]
    (tmp_path / "commas_only.csv").write_text("t,y\n0,1\n,\n1,2\n")   # issue 24: refused, not dropped
    with pytest.raises(DataError, match=r"commas_only.csv: line 3 has only empty cells"):
        read_datafile(tmp_path / "commas_only.csv", cfg)
    np.testing.assert_array_equal(read_datafile(tmp_path / "extra.csv", cfg), [[0, 1.5], [1, 2]])
    (tmp_path / "wide.csv").write_text("t,y\n0,1\n1,2,3\n")
    with pytest.raises(DataError, match=r"wide.csv: line 3 has 3 fields, the header has 2"):
        read_datafile(tmp_path / "wide.csv", cfg)


def test_bad_data_files_name_file_column_and_shape(tmp_path):
    import xarray as xr

    cfg = load_config(write(tmp_path, CONFIG.replace('columns = ["t", "y"]', 'columns = ["t", "y"]\nrows = 3')))
    cases = {
        "missing.csv": ("t,z\n0,1\n1,2\n2,3\n", r"missing.csv: missing column\(s\) 'y'; the header has 't', 'z'"),
        "nan.csv": ("t,y\n0,1\n1,nan\n2,3\n", r"nan.csv: column 'y' has 1 NaN/inf value\(s\), first at data row 2"),
        "empty_cell.csv": ("t,y\n0,1\n1,\n2,3\n", r"empty_cell.csv: column 'y' has 1 NaN"),
        "text.csv": ("t,y\n0,1\n1,abc\n2,3\n", r"text.csv: column 'y', line 3: not a number: 'abc'"),
        "rows.csv": ("t,y\n0,1\n1,2\n", r"rows.csv: expected 3 rows \(data.rows\), got shape \(2, 2\)"),
        "ragged.csv": ("t,y\n0,1\n1\n2,3\n", r"ragged.csv: line 3 has 1 fields, the header has 2"),
        "header_only.csv": ("t,y\n", r"header_only.csv: no data rows"),
    }
    for name, (text, message) in cases.items():
        (tmp_path / name).write_text(text)
        with pytest.raises(DataError, match=message):
            read_datafile(tmp_path / name, cfg)
    xr.Dataset({"t": (("row", "k"), np.zeros((3, 2))), "y": ("row", np.zeros(3))}).to_netcdf(
        tmp_path / "dim.nc", engine="h5netcdf")
    with pytest.raises(DataError, match=r"dim.nc: variable 't' has shape \(3, 2\) \(dims \('row', 'k'\)\); "
                                        r"expected a 1-D column"):
        read_datafile(tmp_path / "dim.nc", cfg)
    xr.Dataset({"t": ("a", np.zeros(3)), "y": ("b", np.zeros(4))}).to_netcdf(tmp_path / "len.nc", engine="h5netcdf")
    with pytest.raises(DataError, match=r"len.nc: columns have different lengths \(t: \(3,\), y: \(4,\)\)"):
        read_datafile(tmp_path / "len.nc", cfg)
    (tmp_path / "garbage.nc").write_bytes(b"not netcdf")
    with pytest.raises(DataError, match="garbage.nc: cannot read as NetCDF"):
        read_datafile(tmp_path / "garbage.nc", cfg)
    with pytest.raises(DataError, match="absent.csv: no such file"):
        read_datafile(tmp_path / "absent.csv", cfg)


def test_same_module_name_in_two_folders_loads_each_folders_likelihood(tmp_path):
    """Two runs whose configs both say ``clashmodel:loglike``, in two folders, in one process:
    each gets its own folder's function, not the first one imported (Python's module cache)."""
    from seqbayes.store.config import load_likelihood

    functions = []
    for value in (1.0, 2.0):
        folder = tmp_path / f"run{int(value)}"
        folder.mkdir()
        (folder / "clashmodel.py").write_text(f"def loglike(theta, data):\n    return {value}\n")
        functions.append(load_likelihood("clashmodel:loglike", str(folder)))
    assert [f(None, None) for f in functions] == [1.0, 2.0]
    # and the first folder's again, now that the second one is cached
    assert load_likelihood("clashmodel:loglike", str(tmp_path / "run1"))(None, None) == 1.0
    assert load_likelihood("clashmodel:loglike", str(tmp_path / "run1")) is \
        load_likelihood("clashmodel:loglike", str(tmp_path / "run1"))  # same file: the cached module
