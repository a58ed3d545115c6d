"""Trust boundaries and hardening of the run store (issue 15).

* A store runs only the likelihood module it recorded and hashed: a store copied next to
  another module of the same name does not run it; ``predict`` and ``report`` import no
  likelihood at all; an edited module is noticed and refused unless accepted; nothing is
  put on ``sys.path``.
* User code gets read-only views of ``theta`` and the data.
* Concurrent API updates are all stored; temporary files are matched exactly.
* Bad stores, settings, datasets and priors are refused with one message naming the file
  or the argument.
"""

from __future__ import annotations

import hashlib
import shutil
import sys

import numpy as np
import pytest

from seqbayes.store import DataError, ModelChangedError, RunStore, StoreError, load_config

from _user_model import decay_tables, write_config, write_model

# a module that leaves a mark when it is run: proves whether a command ran it
MARKER = """
import pathlib as _pathlib
_pathlib.Path(__file__).with_suffix(".ran").write_text("ran")
"""


def tables(n=3, seed=0):
    return decay_tables([1.5 - 0.05 * s for s in range(n)], np.linspace(0, 3, 15), 0.1, seed)


def write_cfg(folder, module, **kwargs):
    """The decay model's config with a drifting amplitude and the transition-density predictive prior."""
    kwargs.setdefault("kernel", 'a = { type = "drift", rate = -0.05, noise_std = 0.02 }')
    path = write_config(folder / "run.toml", module, n_samples=40, seed=3, **kwargs)
    path.write_text(path.read_text() + 'predictive = "transition"\n')
    return path


def make_run(folder, module, n_steps=1, extra=""):
    folder.mkdir(parents=True, exist_ok=True)
    write_model(folder, module, extra=extra)
    cfg = load_config(write_cfg(folder, module))
    store = RunStore.create(folder / "run.nc", cfg)
    for table in tables(n_steps):
        store.assimilate(table)
    return store


def sha(path):
    return hashlib.sha256(path.read_bytes()).hexdigest()


# ------------------------------------------------------------------ item 1: code from where a store lies
def test_a_copied_store_runs_no_module_it_did_not_record(tmp_path):
    home, elsewhere = tmp_path / "home", tmp_path / "elsewhere"
    store = make_run(home, "trustmodel_a")
    elsewhere.mkdir()
    shutil.copy(home / "run.nc", elsewhere / "run.nc")
    shutil.rmtree(home)                                   # the recorded folder is gone, as on another machine
    # a different module of the same name lies next to the copy
    write_model(elsewhere, "trustmodel_a", noise=0.3, extra=MARKER)
    copy = RunStore.open(elsewhere / "run.nc")
    before = sha(elsewhere / "run.nc")
    draws = copy.predict(2)                               # forecasts need no likelihood
    np.testing.assert_array_equal(draws, store.predict(2))
    with pytest.raises(ModelChangedError, match=r"run.nc: the likelihood module changed since the run recorded it "
                                                r"\(sha256 [0-9a-f]{12} .*trustmodel_a.py has sha256 [0-9a-f]{12}.*"
                                                r"it is not run"):
        copy.assimilate(tables(2)[1])
    assert not (elsewhere / "trustmodel_a.ran").exists()  # never executed
    assert sha(elsewhere / "run.nc") == before
    # the very file the run recorded, copied next to the store, is run
    write_model(elsewhere, "trustmodel_a")
    RunStore.open(elsewhere / "run.nc").assimilate(tables(2)[1])
    assert RunStore.open(elsewhere / "run.nc").n_steps == 2


@pytest.mark.slow
def test_the_cli_on_a_copied_store_runs_no_foreign_module(tmp_path, capsys):
    """The issue's probe: ``predict``, ``report`` and ``update`` on a store copied next to another
    ``module.py``; none runs it (two work without any likelihood, update refuses in one line)."""
    from seqbayes import cli

    home, elsewhere = tmp_path / "home", tmp_path / "elsewhere"
    make_run(home, "trustmodel_cli")
    elsewhere.mkdir()
    shutil.copy(home / "run.nc", elsewhere / "run.nc")
    shutil.rmtree(home)
    write_model(elsewhere, "trustmodel_cli", extra=MARKER)
    np.savetxt(elsewhere / "next.csv", tables(2)[1], delimiter=",", header="t,y", comments="")
    run = elsewhere / "run.nc"
    assert cli.main(["predict", str(run), "--steps", "2"]) == 0
    assert cli.main(["report", str(run), "--forecast", "1", "-o", str(elsewhere / "r.html")]) == 0
    capsys.readouterr()
    cli_fails(capsys, ["update", run, elsewhere / "next.csv"], r"next.csv: .*run.nc: the likelihood module changed "
                                                                r"since the run recorded it .* it is not run", run)
    assert not (elsewhere / "trustmodel_cli.ran").exists()


def test_a_store_whose_module_is_nowhere_says_where_it_was(tmp_path):
    make_run(tmp_path / "home", "trustmodel_b")
    (tmp_path / "home" / "trustmodel_b.py").unlink()
    store = RunStore.open(tmp_path / "home" / "run.nc")
    with pytest.raises(ModelChangedError, match=r"the likelihood module 'trustmodel_b' the run recorded "
                                                r"\(.*trustmodel_b.py, sha256 [0-9a-f]{12}\) is not there"):
        store.assimilate(tables(2)[1])
    assert store.predict(1).shape == (1, 40, 2)


@pytest.mark.slow
def test_predict_and_report_import_no_likelihood(tmp_path):
    store = make_run(tmp_path, "trustmodel_c", extra=MARKER)
    (tmp_path / "trustmodel_c.ran").unlink()
    sys.modules.pop("trustmodel_c", None)
    opened = RunStore.open(tmp_path / "run.nc")
    opened.predict(3)
    from seqbayes.store.report import render_report

    assert "<html" in render_report(opened, forecast_steps=2)
    assert not (tmp_path / "trustmodel_c.ran").exists() and "trustmodel_c" not in sys.modules
    assert store.n_steps == 1


def test_an_edited_module_is_noticed_and_its_hash_recorded_per_step_once_accepted(tmp_path):
    store = make_run(tmp_path, "trustmodel_d")
    first = store.module_hashes[0]
    assert first == sha(tmp_path / "trustmodel_d.py") == store.config.likelihood_sha256
    write_model(tmp_path, "trustmodel_d", noise=0.2)      # the user edits the model
    with pytest.raises(ModelChangedError, match="--accept-model-change"):
        RunStore.open(tmp_path / "run.nc").assimilate(tables(2)[1])
    accepted = RunStore.open(tmp_path / "run.nc")
    accepted.assimilate(tables(2)[1], accept_model_change=True)
    reopened = RunStore.open(tmp_path / "run.nc")
    assert reopened.module_hashes == [first, sha(tmp_path / "trustmodel_d.py")]
    assert reopened.config.likelihood_sha256 == sha(tmp_path / "trustmodel_d.py")
    reopened.assimilate(tables(3)[2])                     # the new content is now the recorded one
    from seqbayes.store.report import format_status, status_rows

    assert [r["likelihood_sha256"] for r in status_rows(reopened)] == reopened.module_hashes
    assert f"note: the likelihood module changed at step 2 (sha256 {first[:12]} -> " in format_status(reopened)


def test_loading_the_likelihood_leaves_sys_path_alone_and_shadows_nothing(tmp_path):
    before = list(sys.path)
    (tmp_path / "json.py").write_text("raise RuntimeError('a json.py next to a config was imported')\n")
    store = make_run(tmp_path, "trustmodel_e", n_steps=2)
    assert sys.path == before
    import json

    assert json.dumps([1]) == "[1]" and store.n_steps == 2


def test_a_garbled_or_edited_search_path_does_not_pass(tmp_path):
    store = make_run(tmp_path, "trustmodel_f")
    ds = store.to_xarray()
    ds.attrs["config"] = ds.attrs["config"].replace(str(tmp_path), "/somewhere/else")
    ds.to_netcdf(tmp_path / "edited.nc", engine="h5netcdf")
    with pytest.raises(StoreError, match="edited.nc: damaged run store: the content hash"):
        RunStore.open(tmp_path / "edited.nc")


# ------------------------------------------------------------------ item 3: user code cannot corrupt the run
WRITES_THETA = """
def writes_theta(theta, data):
    theta[:, 1] = abs(theta[:, 1])       # "just making sure b is positive"
    return loglike(theta, data)
"""


def test_a_likelihood_that_writes_into_theta_fails_clearly_and_changes_nothing(tmp_path):
    write_model(tmp_path, "mutatingmodel", extra=WRITES_THETA)
    cfg = load_config(write_cfg(tmp_path, "mutatingmodel", func="writes_theta"))
    store = RunStore.create(tmp_path / "run.nc", cfg)
    before, particles = sha(tmp_path / "run.nc"), store.initial_particles.copy()
    with pytest.raises(ValueError, match=r"loglike: wrote into its input theta or data \(assignment destination is "
                                         r"read-only\); .*copy them first"):
        store.assimilate(tables(1)[0])
    assert sha(tmp_path / "run.nc") == before
    np.testing.assert_array_equal(store.initial_particles, particles)


def test_user_code_gets_read_only_views_of_theta_and_every_kind_of_data():
    from concurrent.futures import ThreadPoolExecutor

    from seqbayes.parallel import evaluate_loglike

    theta, table = np.ones((6, 2)), np.arange(4.0).reshape(2, 2)
    columns = {"t": np.arange(3.0), "y": np.ones(3)}
    seen = []

    def inspect(th, data):
        seen.append((th.flags.writeable, *(a.flags.writeable for a in (data.values() if isinstance(data, dict)
                                                                        else [data]))))
        if isinstance(data, dict):
            data["extra"] = 1.0                       # a new key in the likelihood's own dict only
        return th[:, 0]                               # a view of theta: returned as a copy

    for data in (table, columns):
        for executor in (None, ThreadPoolExecutor(2)):
            values = evaluate_loglike(inspect, theta, data, executor)
            values[:] = -1.0                          # the sampler may write into the result ...
            assert theta[0, 0] == 1.0                 # ... without touching theta
    assert seen and not any(any(flags) for flags in seen)
    assert set(columns) == {"t", "y"} and theta.flags.writeable and table.flags.writeable
    with pytest.raises(ValueError, match="loglike: returned complex values"):
        evaluate_loglike(lambda th, d: th[:, 0] + 1j, theta, table)


def test_the_dask_cluster_a_config_starts_listens_on_localhost_only(tmp_path, monkeypatch):
    distributed = pytest.importorskip("distributed")
    seen = {}

    class FakeCluster:
        def __init__(self, **kwargs):
            seen.update(kwargs)

        def close(self):
            pass

    class FakeClient:
        def __init__(self, cluster):
            pass

        def close(self):
            pass

    monkeypatch.setattr(distributed, "LocalCluster", FakeCluster)
    monkeypatch.setattr(distributed, "Client", FakeClient)
    write_model(tmp_path, "daskcfgmodel")
    path = write_cfg(tmp_path, "daskcfgmodel")
    path.write_text(path.read_text() + '[parallel]\nexecutor = "dask"\n')
    client, close = load_config(path).make_executor()
    close()
    assert seen["dashboard_address"].startswith("127.0.0.1:") and seen["host"] == "127.0.0.1"


# ------------------------------------------------------------------ item 2: concurrent updates, temporary files
def test_two_store_objects_opened_before_either_update_both_keep_their_dataset(tmp_path):
    make_run(tmp_path, "lockmodel_a", n_steps=0)
    first, second = RunStore.open(tmp_path / "run.nc"), RunStore.open(tmp_path / "run.nc")
    data = tables(2)
    first.assimilate(data[0], "first")
    second.assimilate(data[1], "second")            # takes in the first's step, then adds its own
    final = RunStore.open(tmp_path / "run.nc")
    assert final.sources == ["first", "second"] and final.n_steps == 2
    with pytest.raises(StoreError, match="changed since it was opened"):
        first.assimilate(data[1] * 1.01, "fix", replace_last=True)   # would replace the other's step


def test_two_processes_updating_at_once_are_both_stored(tmp_path):
    import os

    make_run(tmp_path, "lockmodel_b", n_steps=0)
    data = tables(2)
    pids = []
    for i in range(2):
        pid = os.fork()
        if pid == 0:  # pragma: no cover - the child
            code = 1
            try:
                RunStore.open(tmp_path / "run.nc").assimilate(data[i], f"process{i}")
                code = 0
            finally:
                os._exit(code)
        pids.append(pid)
    assert [os.waitstatus_to_exitcode(os.waitpid(pid, 0)[1]) for pid in pids] == [0, 0]
    final = RunStore.open(tmp_path / "run.nc")
    assert sorted(final.sources) == ["process0", "process1"]


def test_temporary_files_of_other_stores_are_left_alone(tmp_path):
    """``run[1].nc`` as a glob pattern matches ``run1.nc``: only this store's own names are removed."""
    store = make_run(tmp_path, "tmpmodel", n_steps=0)
    shutil.copy(tmp_path / "run.nc", tmp_path / "run[1].nc")
    others = [tmp_path / ".run1.nc.tmp-123", tmp_path / ".run[1].nc.tmp-123.bak", tmp_path / ".run[1].nc.tmp-x"]
    mine = tmp_path / ".run[1].nc.tmp-99999"
    for path in [*others, mine]:
        path.write_bytes(b"a temporary file")
    bracketed = RunStore.open(tmp_path / "run[1].nc")
    bracketed.assimilate(tables(1)[0])
    assert not mine.exists() and all(p.exists() for p in others)
    assert store.n_steps == 0


# ------------------------------------------------------------------ items 4 and 5: one clear line each
def cli_fails(capsys, args, message, store=None):
    """``seqbayes ARGS`` exits 2 with one line matching ``message`` and leaves ``store`` byte-identical."""
    import re

    from seqbayes import cli

    before = sha(store) if store is not None and store.exists() else None
    code = cli.main([str(a) for a in args])
    out, err = capsys.readouterr()
    assert code == 2, (args, out, err)
    assert len(err.strip().splitlines()) == 1, err       # one line, no traceback
    assert re.search(message, err), err
    if before is not None:
        assert sha(store) == before
    return err


def rewrite(store_path, edit, target):
    """Write ``target``: the store at ``store_path`` changed by ``edit(ds)``, its content hash redone."""
    import xarray as xr

    from seqbayes.store.base import rehash

    with xr.open_dataset(store_path, engine="h5netcdf") as ds:
        ds = ds.load()
    edit(ds)
    rehash(ds)
    ds.to_netcdf(target, engine="h5netcdf")
    return target


@pytest.mark.slow
def test_damaged_stores_get_one_line_naming_the_file(tmp_path, capsys):
    import json

    make_run(tmp_path, "damagemodel", n_steps=2)
    run = tmp_path / "run.nc"
    (tmp_path / "d3.csv").write_text("t,y\n0,1\n1,0.5\n")

    def set_attr(key, value):
        return lambda ds: ds.attrs.__setitem__(key, value)

    def garble(name, index, text):
        def edit(ds):
            values = ds[name].values.copy()
            values[index] = text
            ds[name] = (ds[name].dims, values)
        return edit

    def nan_posterior(ds):
        values = ds["posterior"].values.copy()
        values[1, 5, 0] = np.nan
        ds["posterior"] = (ds["posterior"].dims, values)

    cases = {
        "steps.nc": (set_attr("n_steps", 3), r"steps.nc: inconsistent store \(2 steps, 3 generator states, 2 "
                                             r"dataset hashes, n_steps = 3\)"),
        "dropped.nc": (lambda ds: ds.__delitem__("predictive"),
                       r"dropped.nc: damaged run store: missing variable\(s\) predictive"),
        "config.nc": (set_attr("config", '{"name": '), r"config.nc: damaged run store: unreadable config attribute"),
        "rng.nc": (garble("rng_state", 1, json.dumps({"state": 1})),
                   r"rng.nc: damaged run store: rng_state\[1\] is not a numpy generator state"),
        "info.nc": (garble("step_info", 0, "{oops"), r"info.nc: damaged run store: step_info\[0\] is not valid JSON"),
        "nan.nc": (nan_posterior, r"nan.nc: damaged run store: posterior holds 1 NaN/inf value\(s\), first at index "
                                  r"\(1, 5, 0\)"),
    }
    for name, (edit, message) in cases.items():
        target = rewrite(run, edit, tmp_path / name)
        for command in (["update", target, tmp_path / "d3.csv"], ["status", target], ["predict", target, "--steps", 1]):
            cli_fails(capsys, command, message, target)
    # garbled without redoing the hash: the content hash says so
    import xarray as xr

    with xr.open_dataset(run, engine="h5netcdf") as ds:
        ds = ds.load()
    ds.attrs["config"] = ds.attrs["config"].replace('"seed": 3', '"seed": 4')
    ds.to_netcdf(tmp_path / "edited.nc", engine="h5netcdf")
    cli_fails(capsys, ["status", tmp_path / "edited.nc"], r"edited.nc: damaged run store: the content hash",
              tmp_path / "edited.nc")
    # NetCDF-3 and a folder
    xr.Dataset({"x": ("i", np.zeros(2))}).to_netcdf(tmp_path / "classic.nc", engine="scipy")
    cli_fails(capsys, ["status", tmp_path / "classic.nc"], r"classic.nc: a NetCDF-3 \(classic\) file; run stores are "
                                                           r"NetCDF-4")
    # a folder is a fleet (docs/fleet.md): its status lists every damaged store with its one line, exit status 1
    from seqbayes import cli

    code = cli.main(["status", str(tmp_path)])
    out = capsys.readouterr().out
    assert code == 1 and "stores with errors" in out, out
    assert all(name in out for name in cases) and "inconsistent store" in out, out


def test_a_flipped_bit_in_the_stored_arrays_is_detected(tmp_path):
    import h5py

    make_run(tmp_path, "bitmodel", n_steps=2)
    run = tmp_path / "run.nc"
    with h5py.File(run, "r") as fh:
        dataset = fh["mixture_centres"]
        assert dataset.fletcher32
        offset = dataset.id.get_chunk_info(0).byte_offset + 24
    raw = bytearray(run.read_bytes())
    raw[offset] ^= 0x10                                  # one bit of one stored centre
    run.write_bytes(bytes(raw))
    with pytest.raises(StoreError, match=r"run.nc: cannot read the run store: .*a checksum failed"):
        RunStore.open(run)


def test_a_flipped_bit_in_an_appended_step_is_detected_on_open(tmp_path):
    """Steps 2 and 3 are appended in place (their chunks rewritten, their records hashed alone): a
    flipped bit in step 3's numbers or in its text record is still refused when the store is opened."""
    import h5py

    make_run(tmp_path, "appendbitmodel", n_steps=3)
    run = tmp_path / "run.nc"
    pristine = run.read_bytes()
    with h5py.File(run, "r") as fh:
        posterior = fh["posterior"]
        assert posterior.fletcher32 and posterior.shape[0] == 3
        # step 3's first value in the chunk of steps 1-8 (row-major: 2 steps of 40 x 2 values before it)
        offset = posterior.id.get_chunk_info(0).byte_offset + 2 * 40 * 2 * 8
    raw = bytearray(pristine)
    raw[offset] ^= 0x01
    run.write_bytes(bytes(raw))
    with pytest.raises(StoreError, match=r"run.nc: cannot read the run store: .*a checksum failed"):
        RunStore.open(run)
    raw = bytearray(pristine)
    where = raw.find(b'"step": 3,')
    assert where > 0 and raw.find(b'"step": 3,', where + 1) < 0
    raw[where + len(b'"step": ')] ^= 0x04                 # '3' -> '7': the JSON stays valid
    run.write_bytes(bytes(raw))
    with pytest.raises(StoreError, match=r"run.nc: damaged run store: the content hash of its configuration and "
                                         r"records does not match \(the records of step 3\)"):
        RunStore.open(run)
    run.write_bytes(pristine)
    assert RunStore.open(run).n_steps == 3


def test_bad_paths_get_one_line(tmp_path, capsys):
    make_run(tmp_path, "pathmodel", n_steps=1)
    run = tmp_path / "run.nc"
    (tmp_path / "out").mkdir()
    (tmp_path / "cfgdir.toml").mkdir()
    cli_fails(capsys, ["init", tmp_path / "cfgdir.toml", tmp_path / "new.nc"], r"cfgdir.toml: is a folder, not a TOML")
    cli_fails(capsys, ["report", run, "-o", tmp_path / "out", "--forecast", 0], r"out: is a folder; give the report's "
                                                                                 r"file name", run)
    cli_fails(capsys, ["predict", run, "--steps", 1, "-o", tmp_path / "out"], r"out: is a folder", run)
    cli_fails(capsys, ["init", tmp_path / "run.toml", tmp_path / "out"], r"out: is a folder; give the run store's")
    cli_fails(capsys, ["update", run, tmp_path / "out"], r"out: is a folder, not a data file", run)


def test_a_bad_second_file_says_what_was_committed(tmp_path, capsys):
    make_run(tmp_path, "multimodel", n_steps=0)
    run = tmp_path / "run.nc"
    for i, table in enumerate(tables(2)):
        np.savetxt(tmp_path / f"m{i}.csv", table, delimiter=",", header="t,y", comments="")
    shutil.copy(tmp_path / "m0.csv", tmp_path / "again.csv")   # passes the reader, refused by the store
    cli_fails(capsys, ["update", run, tmp_path / "m0.csv", tmp_path / "again.csv", tmp_path / "m1.csv"],
              r"again.csv: .*already assimilated as step 1.*; the run store keeps the steps committed before it "
              r"\(m0.csv \(step 1\)\); this file and the ones after it were not assimilated")
    assert RunStore.open(run).n_steps == 1


def test_settings_values_and_datasets_of_the_wrong_type_are_refused(tmp_path):
    from seqbayes.store.config import ConfigError

    write_model(tmp_path, "typemodel")
    base = write_cfg(tmp_path, "typemodel").read_text()
    for setting, message in (('tempering = "false"', r"sampler.tempering: expected true or false, got 'false'"),
                             ("max_stages = 10.5", r"sampler.max_stages: expected an integer, got 10.5"),
                             ('step_size = "2"', r"sampler.step_size: expected a number, got '2'"),
                             ("n_samples = 100.5", r"sampler.n_samples: expected an integer, got 100.5")):
        text = base.replace("n_samples = 40\n", "") if setting.startswith("n_samples") else base
        (tmp_path / "bad.toml").write_text(text.replace("[sampler]\n", f"[sampler]\n{setting}\n"))
        with pytest.raises(ConfigError, match=message):
            load_config(tmp_path / "bad.toml")
    store = make_run(tmp_path / "run", "typemodel_b", n_steps=1)
    with pytest.raises(TypeError, match=r"n_steps: expected an integer, got 1.7"):
        store.predict(1.7)
    table = tables(2)[1]
    with pytest.raises(DataError, match=r"table: complex values"):
        store.assimilate(table + 0j)
    bad = table.copy()
    bad[3, 1] = np.nan
    with pytest.raises(DataError, match=r"table: column 'y' has 1 NaN/inf value\(s\), first at data row 4"):
        store.assimilate(bad)
    assert store.n_steps == 1


def test_a_posterior_piled_up_at_a_prior_bound_is_reported(tmp_path, capsys):
    from seqbayes.store import BoundWarning

    store = make_run(tmp_path, "boundmodel", n_steps=0)
    millivolts = tables(1)[0] * [1.0, 1000.0]             # y in mV instead of V: amplitude ~1500
    with pytest.warns(BoundWarning, match=r"step 1: 100% of the posterior of 'a' lies at the prior's upper bound "
                                          r"2.5; check the data's units"):
        store.assimilate(millivolts)
    assert store.bound_messages() and not make_run(tmp_path / "fine", "boundmodel_b").bound_messages()


def test_invalid_priors_are_refused_with_the_parameter_named():
    from scipy import stats

    from seqbayes.priors import JointPrior

    with pytest.raises(TypeError, match=r"distributions\['k'\]: scipy.stats.norm is not frozen"):
        JointPrior({"k": stats.norm})
    with pytest.raises(ValueError, match=r"distributions\['k'\]: scipy.stats.uniform: scale must be positive"):
        JointPrior({"k": stats.uniform(0.0, 0.0)})
    with pytest.raises(ValueError, match=r"distributions\['c'\]: scipy.stats.norm: scale must be positive"):
        JointPrior({"k": stats.uniform(0.0, 1.0), "c": stats.norm(0.0, -1.0)})
    with pytest.raises(ValueError, match=r"distributions\['s'\]: scipy.stats.lognorm: invalid shape"):
        JointPrior({"s": stats.lognorm(-0.5)})
    assert JointPrior({"k": stats.uniform(0.0, 1.0)}).dim == 1


@pytest.mark.slow
def test_report_keeps_user_strings_out_of_the_markup(tmp_path):
    from seqbayes.store.report import write_report

    store = make_run(tmp_path, "escapemodel", n_steps=1)
    page = write_report(store, tmp_path / "a'b onerror=alert(1) x.html", embed=False, forecast_steps=0)
    text = page.read_text()
    assert "onerror=alert(1)" not in text.replace("onerror%3Dalert%281%29", "")
    assert "src='a%27b%20onerror%3Dalert%281%29%20x_figures/fig-parameters.png'" in text


def test_the_store_keeps_its_permission_bits(tmp_path):
    import os
    import stat

    store = make_run(tmp_path, "modemodel", n_steps=0)
    os.chmod(tmp_path / "run.nc", 0o600)
    for table in tables(2):                     # a whole write (the first step), then an append
        store.assimilate(table)
        assert stat.S_IMODE(os.stat(tmp_path / "run.nc").st_mode) == 0o600


# ------------------------------------------------------------------ filesystem faults on a small tmpfs
@pytest.fixture
def small_disk(tmp_path):
    """A 2 MiB tmpfs (root only; skipped where mounting is not permitted)."""
    import os
    import subprocess

    mount = tmp_path / "disk"
    mount.mkdir()
    if os.geteuid() != 0:
        pytest.skip("mounting a tmpfs needs root")
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=2m", "tmpfs", str(mount)], capture_output=True,
                          text=True)
    if done.returncode:
        pytest.skip(f"cannot mount a tmpfs here: {done.stderr.strip()}")
    yield mount
    subprocess.run(["umount", "-l", str(mount)], capture_output=True)


def fill(folder, leave_bytes):
    import os

    free = os.statvfs(folder).f_bavail * os.statvfs(folder).f_frsize
    with open(folder / "filler", "wb") as fh:
        fh.write(b"\0" * max(0, free - leave_bytes))


@pytest.mark.slow
def test_a_full_disk_gives_one_line_and_keeps_the_store(small_disk, capsys, monkeypatch):
    import seqbayes.store.files as store_files

    make_run(small_disk, "diskmodel", n_steps=1)
    run = small_disk / "run.nc"
    np.savetxt(small_disk / "next.csv", tables(2)[1], delimiter=",", header="t,y", comments="")
    np.savetxt(small_disk / "d1.csv", tables(1)[0], delimiter=",", header="t,y", comments="")
    fill(small_disk, 8 * 1024)
    cli_fails(capsys, ["update", run, small_disk / "next.csv"],
              r"next.csv: .*run.nc: not enough free space in .*disk: about \d+ KiB needed, \d+ KiB free", run)
    # and when the space runs out during the write itself (the check bypassed): an OS error, no crash.
    # An appended step: the store's growth is allocated before the journal is written
    monkeypatch.setattr(store_files, "check_free_space", lambda *args: None)
    (small_disk / "filler").unlink()
    fill(small_disk, 0)
    cli_fails(capsys, ["update", run, small_disk / "next.csv"],
              r"next.csv: .*run.nc: cannot write the run store: No space left on device; the previous store is kept",
              run)
    # a whole write (replacing the last step): the temporary file
    cli_fails(capsys, ["update", run, small_disk / "d1.csv", "--replace-last"],
              r"d1.csv: .*run.nc: cannot write the run store: No space left on device; the previous store is kept",
              run)
    assert [p.name for p in small_disk.iterdir() if ".tmp-" in p.name or p.name.endswith(".journal")] == []
    (small_disk / "filler").unlink()
    monkeypatch.undo()
    assert RunStore.open(run).n_steps == 1
    RunStore.open(run).update(small_disk / "next.csv")   # room again: the run goes on
    assert RunStore.open(run).n_steps == 2


@pytest.mark.slow
def test_a_read_only_folder_gives_one_line(small_disk, capsys):
    import subprocess

    make_run(small_disk, "romodel", n_steps=1)
    run = small_disk / "run.nc"
    np.savetxt(small_disk / "next.csv", tables(2)[1], delimiter=",", header="t,y", comments="")
    (small_disk / "run.nc.lock").unlink()
    subprocess.run(["mount", "-o", "remount,ro", str(small_disk)], check=True)
    cli_fails(capsys, ["init", small_disk / "run.toml", small_disk / "new.nc"],
              r"new.nc: cannot take the lock .*new.nc.lock: Read-only file system")
    cli_fails(capsys, ["update", run, small_disk / "next.csv"], r"run.nc: cannot take the lock .*Read-only file system",
              run)
    cli_fails(capsys, ["report", run, "--forecast", 0], r"Read-only file system", run)
    assert RunStore.open(run).n_steps == 1                 # reading needs no write access


def test_netcdf3_data_files_are_read(tmp_path):
    import xarray as xr

    from seqbayes.store.datasets import read_datafile

    store = make_run(tmp_path, "classicmodel", n_steps=0)
    table = tables(1)[0]
    xr.Dataset({"t": ("row", table[:, 0]), "y": ("row", table[:, 1])}).to_netcdf(tmp_path / "classic.nc",
                                                                               engine="scipy")
    assert (tmp_path / "classic.nc").read_bytes()[:3] == b"CDF"
    np.testing.assert_array_equal(read_datafile(tmp_path / "classic.nc", store.config), table)


# ------------------------------------------------------------------ item 7: a step is appended, not the whole file
@pytest.mark.slow
def test_a_step_is_appended_in_place_and_reads_back_as_a_whole_write(tmp_path, monkeypatch):
    import seqbayes.store.files as store_files

    calls = []
    original = RunStore._append

    def spy(self):
        calls.append(original(self))
        return calls[-1]

    monkeypatch.setattr(RunStore, "_append", spy)
    store = make_run(tmp_path, "appendmodel", n_steps=3)
    assert calls == [False, False, True, True]     # creation and the first step write it whole; then appends
    journal_bytes = []
    apply = store_files.apply_with_journal
    monkeypatch.setattr(store_files, "apply_with_journal",
                        lambda path, journal: journal_bytes.append(sum(len(p) for _, p in journal[2])) or apply(path, journal))
    sizes = []
    inode = (tmp_path / "run.nc").stat().st_ino
    for table in tables(6)[3:]:
        before = (tmp_path / "run.nc").stat().st_size
        store.assimilate(table)
        sizes.append((tmp_path / "run.nc").stat().st_size - before)
    assert calls[-3:] == [True, True, True]
    assert (tmp_path / "run.nc").stat().st_ino == inode   # written in place, not replaced
    one_step = 3 * 40 * 2 * 8 + 40 * 8 * 2           # posterior, predictive, centres; two weight vectors
    assert max(sizes) < 4 * one_step + 8192, sizes     # the file grows by about one step, not by a rewrite
    # what an append writes (the journal's pages, then the same pages in the store) does not grow with the run
    assert len(journal_bytes) == 3 and max(journal_bytes) <= 1.2 * min(journal_bytes), journal_bytes
    appended = RunStore.open(tmp_path / "run.nc")
    whole = RunStore.open(tmp_path / "run.nc")
    whole.path, whole._disk_steps = tmp_path / "whole.nc", 0
    whole.write()                                      # the same content written in one piece
    again = RunStore.open(tmp_path / "whole.nc")
    assert calls[-1] is False
    for a, b in zip(appended.result.steps, again.result.steps):
        np.testing.assert_array_equal(a.posterior, b.posterior)
        np.testing.assert_array_equal(a.log_weights, b.log_weights)
    assert appended.rng_states == again.rng_states and appended.digests == again.digests
    np.testing.assert_array_equal(appended.predict(2), again.predict(2))
    # replace_last rewrites the whole file (its last rows change) and the run goes on appending
    appended.assimilate(tables(6)[5] * 1.01, "fixed", replace_last=True)
    assert calls[-1] is False and RunStore.open(tmp_path / "run.nc").sources[-1] == "fixed"
    assert RunStore.growing["step"] > 1