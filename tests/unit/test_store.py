"""Run store: exact round trip, bit-identical resumption, duplicate and incompatibility refusal,
store unchanged on failure, ArviZ conversion."""

from __future__ import annotations

import hashlib

import numpy as np
import pytest

from seqbayes.store import DuplicateDatasetError, RunStore, StoreError, load_config, posterior_to_arviz
from seqbayes.store.base import rehash
from seqbayes.store.smc import FORMAT_VERSION

from _user_model import assert_same_steps, decay_tables, write_config, write_model

WRONG_SHAPE = """
def wrong_shape(theta, data):
    return np.zeros(3)
"""


def datasets(n=4, seed=0):
    return decay_tables([1.5 - 0.05 * s for s in range(n)], np.linspace(0, 3, 15), 0.1, seed)


def config(tmp_path, sampler="SEMC", func="loglike", name="run.toml", static=False):
    write_model(tmp_path, "storemodel", extra=WRONG_SHAPE)
    # static: every parameter static, so the sampler uses the exact history prior
    kernel = "" if static else 'a = { type = "drift", rate = -0.05, noise_std = 0.02 }'
    return load_config(write_config(tmp_path / name, "storemodel", func=func, kernel=kernel, sampler=sampler,
                                    n_samples=80, seed=11))


def sha(path):
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.mark.parametrize("sampler", ["SEMC", "SMC"])
def test_reopening_after_each_step_is_bit_identical_to_an_uninterrupted_run(tmp_path, sampler):
    cfg = config(tmp_path, sampler)
    data = datasets()
    reference = cfg.build_sampler()
    for d in data:
        reference.update(d)
    RunStore.create(tmp_path / "run.nc", cfg)
    for i, d in enumerate(data):
        store = RunStore.open(tmp_path / "run.nc")      # a fresh object from disk each time
        assert store.n_steps == i
        store.assimilate(d, f"d{i}")
    store = RunStore.open(tmp_path / "run.nc")
    assert_same_steps(reference.result.steps, store.result.steps)   # every diagnostic too (ancestor ESS, ...)
    # the stored state is the sampler's state: the next forecast and step agree too
    assert store.rng_states[-1] == reference.snapshot()[2]
    np.testing.assert_array_equal(store.predict(2), reference.predict(2))
    assert store.sources == ["d0", "d1", "d2", "d3"]


REMEDY_MODEL = """
import numpy as np
def loglike(theta, data):
    return -0.5 * np.sum((data[:, 0][None, :] - theta[:, [0]]) ** 2, axis=1) / 0.5 ** 2
"""
REMEDY_CONFIG = """
[model]
likelihood = "remedymodel:loglike"
[data]
columns = ["y"]
[priors]
a = { dist = "norm", loc = 0.0, scale = 1.0 }
[kernel]
a = { type = "drift", rate = 0.0, noise_std = 0.05 }
[sampler]
type = "SEMC"
n_samples = 300
seed = 5
predictive = "transition"
"""


@pytest.mark.slow
@pytest.mark.parametrize("remedy_lag", [None, 3])
def test_a_run_through_a_conflict_resumes_with_the_remedys_window_and_paths(tmp_path, remedy_lag):
    """The conflict remedy keeps a window of past steps and, after a path-space step, the particle
    paths; a store reopened before every step rebuilds both (seqbayes.store.snapshot) and gives the
    uninterrupted run bit for bit. A random walk (sd 0.05 per step) observed through 25 points of
    noise 0.5 jumps by 0.6 (12 kernel sds) at step 4, which runs on the path space (as in
    test_conflict_remedy). With ``remedy_lag = 3`` steps 5 and 6 reach back to step 4's first state (anchored
    windows of 4 and 5 states, seqbayes.predictive.lineage.remedy_window) and step 7's window slides back to 2. Whether
    step 6 takes the remedy again is the trigger's call on a random ancestor ESS: sampler seed 5 does (seeds 0-23 with
    the early remedy decision: 5, 7, 12, 13, 18 and 19; the rest remedy steps 5 and 7 instead); seed 0 did on the
    suffix moves alone, seed 6 on the half starts, seed 3 before them."""
    (tmp_path / "remedymodel.py").write_text(REMEDY_MODEL)
    (tmp_path / "run.toml").write_text(REMEDY_CONFIG + ("" if remedy_lag is None else f"remedy_lag = {remedy_lag}\n"))
    cfg = load_config(tmp_path / "run.toml")
    rng = np.random.default_rng(123)
    theta = np.cumsum(0.05 * rng.standard_normal(7))
    theta[3:] += 0.6
    data = [(t + 0.5 * rng.standard_normal(25))[:, None] for t in theta]
    reference = cfg.build_sampler()
    for d in data:
        reference.update(d)
    path_steps = [r.info.path_steps for r in reference.result.steps]
    assert path_steps[3] > 0 and not any(path_steps[:3]), path_steps   # the remedy ran at the jump
    if remedy_lag is not None:
        assert path_steps[3:6] == [3, 4, 5], path_steps
    assert reference.snapshot()[0].memory.paths is not None                  # and its paths were carried on
    RunStore.create(tmp_path / "run.nc", cfg)
    for i, d in enumerate(data):
        RunStore.open(tmp_path / "run.nc").assimilate(d, f"d{i}")
    store = RunStore.open(tmp_path / "run.nc")
    assert_same_steps(reference.result.steps, store.result.steps)
    state = store.state_at(len(data))[0]
    expected = reference.snapshot()[0]
    np.testing.assert_array_equal(state.memory.paths, expected.memory.paths)
    assert len(state.memory.window) == len(expected.memory.window)
    for mine, theirs in zip(state.memory.window, expected.memory.window):
        np.testing.assert_array_equal(mine.dataset, theirs.dataset)
        np.testing.assert_array_equal(mine.posterior, theirs.posterior)
        assert mine.path_space == theirs.path_space
        assert mine.path_states == theirs.path_states
        assert mine.log_evidence_increment == theirs.log_evidence_increment
    assert state.log_evidence_variance == expected.log_evidence_variance
    np.testing.assert_array_equal(store.predict(2), reference.predict(2))


@pytest.mark.slow
@pytest.mark.parametrize("sampler", ["SEMC", "SMC"])
def test_history_prior_run_resumes_bit_for_bit_and_replaces_last(tmp_path, sampler):
    """Static parameters: the store keeps the datasets the history prior re-evaluates and its
    values at the particles, so a run reopened after every step is the uninterrupted run."""
    import xarray as xr

    from seqbayes.predictive.history import HistoryPrior

    cfg = config(tmp_path, sampler, static=True)
    data = datasets(4)
    reference = cfg.build_sampler()
    for d in data:
        reference.update(d)
    assert isinstance(reference.state.prior, HistoryPrior)
    RunStore.create(tmp_path / "run.nc", cfg)
    for i, d in enumerate(data):
        RunStore.open(tmp_path / "run.nc").assimilate(d, f"d{i}")
    store = RunStore.open(tmp_path / "run.nc")
    assert_same_steps(reference.result.steps, store.result.steps)
    assert [set(arrays) for arrays in store.states] == [{"state_log_prior", "state_log_evidence_variance", "state_window",
                                                          "state_paths", "state_lineage"}] * 4
    assert [int(arrays["state_window"]) for arrays in store.states] == [0] * 4   # no remedy for static parameters
    for stored, d in zip(store.tables, data):
        np.testing.assert_array_equal(stored, d)
    np.testing.assert_array_equal(store.states[-1]["state_log_prior"], reference.state.log_prior)
    state = store.state_at(4)[0]
    assert isinstance(state.prior, HistoryPrior) and state.prior.log_normaliser == reference.state.log_evidence
    # one more dataset from the reopened store == one more in the uninterrupted run
    extra = datasets(5, seed=1)[4]
    store.assimilate(extra, "d4")
    reference.update(extra)
    assert_same_steps(reference.result.steps, RunStore.open(tmp_path / "run.nc").result.steps)
    # replacing the last step rolls the history back too
    store.assimilate(data[0] * 1.01, "fixed", replace_last=True)
    rolled = cfg.build_sampler()
    for d in data + [data[0] * 1.01]:
        rolled.update(d)
    assert_same_steps(rolled.result.steps, RunStore.open(tmp_path / "run.nc").result.steps)
    assert len(store.tables) == 5
    # a version-1 store of a static model (kernel-density prior) cannot be continued by the history prior
    ds = store.to_xarray().drop_vars(["state_log_prior", "dataset_values", "dataset_rows"])
    ds["mixture_centres"] = ds["posterior"]
    ds["mixture_bandwidth"] = ds["posterior"].isel(sample=0)
    ds["mixture_log_weights"] = ds["log_weights"]
    ds.attrs["seqbayes_store_format"] = 1
    ds.to_netcdf(tmp_path / "old.nc", engine="h5netcdf")
    with pytest.raises(StoreError, match="old.nc: written by an earlier seqbayes, which gave static parameters a "
                                         "kernel-density prior"):
        RunStore.open(tmp_path / "old.nc")
    assert xr.open_dataset(tmp_path / "run.nc", engine="h5netcdf").attrs["seqbayes_store_format"] == FORMAT_VERSION


def test_exact_round_trip_of_every_stored_array(tmp_path):
    cfg = config(tmp_path)
    store = RunStore.create(tmp_path / "run.nc", cfg)
    for d in datasets(2):
        store.assimilate(d)
    loaded = RunStore.open(tmp_path / "run.nc", config=cfg)
    assert loaded.config == store.config
    np.testing.assert_array_equal(loaded.initial_particles, store.initial_particles)
    # a drifting and a static parameter: SMC^2, whose state is a dict of arrays per step
    assert len(loaded.states) == len(store.states) == 2
    assert all(name.startswith("nested_") for arrays in loaded.states for name in arrays)
    for a, b in zip(loaded.states, store.states):
        assert set(a) == set(b)
        for key in a:
            np.testing.assert_array_equal(a[key], b[key])
    for t1, t2 in zip(loaded.tables, store.tables):
        np.testing.assert_array_equal(t1, t2)
    assert loaded.step_sizes == store.step_sizes and loaded.rng_states == store.rng_states
    assert loaded.digests == store.digests
    state, records, rng_state = loaded.state_at(2)
    assert state.step == 2 and len(records) == 2
    assert state.log_evidence == store.result.steps[-1].info.log_evidence
    np.testing.assert_array_equal(state.log_weights, store.states[-1]["nested_log_weights"])
    np.testing.assert_array_equal(state.cloud["x"], store.states[-1]["nested_cloud_x"])


@pytest.mark.slow
def test_duplicate_dataset_refused_and_replace_last(tmp_path):
    cfg = config(tmp_path)
    data = datasets(3)
    store = RunStore.create(tmp_path / "run.nc", cfg)
    store.assimilate(data[0], "first.csv")
    store.assimilate(data[1], "second.csv")
    before = sha(tmp_path / "run.nc")
    with pytest.raises(DuplicateDatasetError, match=r"already assimilated as step 1 \(from first.csv"):
        store.assimilate(data[0].copy(), "again.csv")
    with pytest.raises(DuplicateDatasetError, match="step 2 .*--replace-last"):
        store.assimilate(data[1], "again.csv")
    with pytest.raises(DuplicateDatasetError, match="step 1"):   # only the last step may be replaced
        store.assimilate(data[0], "again.csv", replace_last=True)
    assert sha(tmp_path / "run.nc") == before and store.n_steps == 2
    # replacing the last step == a run that had the replacement from the start
    store.assimilate(data[2], "fixed.csv", replace_last=True)
    assert store.n_steps == 2 and store.sources == ["first.csv", "fixed.csv"]
    reference = cfg.build_sampler()
    reference.update(data[0])
    reference.update(data[2])
    assert_same_steps(reference.result.steps, RunStore.open(tmp_path / "run.nc").result.steps)
    # the same dataset may be "replaced" by itself: same numbers
    store.assimilate(data[2], "fixed-again.csv", replace_last=True)
    assert_same_steps(reference.result.steps, store.result.steps)


def test_failing_likelihood_leaves_the_store_unchanged(tmp_path):
    cfg = config(tmp_path, func="wrong_shape")
    store = RunStore.create(tmp_path / "run.nc", cfg)
    before = sha(tmp_path / "run.nc")
    with pytest.raises(ValueError, match=r"loglike: returned shape \(3,\) for theta of shape \(80, 2\); "
                                         r"expected \(80,\)"):
        store.assimilate(datasets(1)[0])
    assert store.n_steps == 0 and len(store.rng_states) == 1
    assert sha(tmp_path / "run.nc") == before
    with pytest.raises(ValueError, match=r"table: expected shape \(n_rows, 2\)"):
        store.assimilate(np.zeros((5, 3)))


@pytest.mark.slow
def test_incompatible_version_model_and_damage_are_refused(tmp_path):
    import xarray as xr

    cfg = config(tmp_path)
    store = RunStore.create(tmp_path / "run.nc", cfg)
    store.assimilate(datasets(1)[0])
    ds = store.to_xarray()
    ds.attrs["seqbayes_store_format"] = FORMAT_VERSION + 1
    ds.to_netcdf(tmp_path / "future.nc", engine="h5netcdf")
    with pytest.raises(StoreError, match=rf"future.nc: run-store format version {FORMAT_VERSION + 1}, but this "
                                         rf"seqbayes reads versions 1, 2, 3, 4, {FORMAT_VERSION}"):
        RunStore.open(tmp_path / "future.nc")
    other = config(tmp_path, sampler="SMC", name="other.toml")
    with pytest.raises(StoreError, match=r"run.nc: the run was created for another model .*differing fields: "
                                         r"sampler"):
        RunStore.open(tmp_path / "run.nc", config=other)
    ds = store.to_xarray()
    ds.attrs["config"] = ds.attrs["config"].replace('"seed": 11', '"seed": 12')
    ds.to_netcdf(tmp_path / "edited.nc", engine="h5netcdf")
    with pytest.raises(StoreError, match="edited.nc: damaged run store: the content hash .* does not match"):
        RunStore.open(tmp_path / "edited.nc")
    rehash(ds)       # an edit that also redoes the content hash
    ds.to_netcdf(tmp_path / "edited.nc", engine="h5netcdf")
    with pytest.raises(StoreError, match="edited.nc: model fingerprint does not match"):
        RunStore.open(tmp_path / "edited.nc")
    xr.Dataset({"x": ("i", np.zeros(2))}).to_netcdf(tmp_path / "plain.nc", engine="h5netcdf")
    with pytest.raises(StoreError, match="plain.nc: not a seqbayes run store"):
        RunStore.open(tmp_path / "plain.nc")
    (tmp_path / "torn.nc").write_bytes((tmp_path / "run.nc").read_bytes()[:1000])
    with pytest.raises(StoreError, match="torn.nc: cannot read the run store"):
        RunStore.open(tmp_path / "torn.nc")
    with pytest.raises(StoreError, match="absent.nc: no such run store"):
        RunStore.open(tmp_path / "absent.nc")
    with pytest.raises(StoreError, match="already exists"):
        RunStore.create(tmp_path / "run.nc", cfg)


@pytest.mark.slow
def test_a_format_3_store_opens_and_its_next_update_rewrites_it_in_format_4(tmp_path):
    """Format 3 (one content hash over all text records, no per-step record hashes, no remedy state)
    is still read, verified by its own hash, and the next update writes the whole file in format 4."""
    import xarray as xr

    from seqbayes.store.smc import content_hash_v3

    cfg = config(tmp_path)
    store = RunStore.create(tmp_path / "run.nc", cfg)
    for d in datasets(2):
        store.assimilate(d)
    ds = store.to_xarray().drop_vars(["record_sha256", "state_window", "state_paths", "state_paths_rows",
                                      "state_log_evidence_variance", "state_lineage"], errors="ignore")
    ds.attrs["seqbayes_store_format"] = 3
    variables = {name: ds[name].values for name in ds.variables}
    ds.attrs["content_sha256"] = content_hash_v3(ds.attrs, variables)
    ds.to_netcdf(tmp_path / "v3.nc", engine="h5netcdf")
    old = RunStore.open(tmp_path / "v3.nc")
    assert_same_steps(store.result.steps, old.result.steps)
    assert old.rng_states == store.rng_states and old.digests == store.digests
    edited = ds.copy()
    edited.attrs["config"] = edited.attrs["config"].replace('"seed": 11', '"seed": 12')
    edited.to_netcdf(tmp_path / "v3_edited.nc", engine="h5netcdf")
    with pytest.raises(StoreError, match="v3_edited.nc: damaged run store: the content hash"):
        RunStore.open(tmp_path / "v3_edited.nc")
    old.assimilate(datasets(3)[2], "d3")
    again = RunStore.open(tmp_path / "v3.nc")
    assert again.n_steps == 3 and again.sources[-1] == "d3"
    assert_same_steps(store.result.steps, again.result.steps[:2])
    assert xr.open_dataset(tmp_path / "v3.nc", engine="h5netcdf").attrs["seqbayes_store_format"] == FORMAT_VERSION


@pytest.mark.slow
def test_a_store_written_before_the_lineage_opens_and_continues_with_distinct_labels(tmp_path):
    """A format-4 store without ``state_lineage`` (written before the evidence se's labels) reads as every
    particle its own label (the lineage only enters the log-evidence standard errors); the next update
    writes the lineage of every step, and the sampling is the uninterrupted run's."""
    from seqbayes.store import snapshot

    (tmp_path / "remedymodel.py").write_text(REMEDY_MODEL)
    (tmp_path / "run.toml").write_text(REMEDY_CONFIG)
    cfg = load_config(tmp_path / "run.toml")
    rng = np.random.default_rng(5)
    data = [(0.05 * s + 0.5 * rng.standard_normal(25))[:, None] for s in range(4)]
    reference = cfg.build_sampler()
    for d in data:
        reference.update(d)
    store = RunStore.create(tmp_path / "run.nc", cfg)
    for i, d in enumerate(data[:3]):
        store.assimilate(d, f"d{i}")
    assert all(arrays["state_lineage"].shape == (300, 2) for arrays in store.states)
    store.to_xarray().drop_vars(["state_lineage"]).to_netcdf(tmp_path / "old.nc", engine="h5netcdf")
    old = RunStore.open(tmp_path / "old.nc")
    distinct = np.repeat(np.arange(300.0)[:, None], 2, axis=1)
    for arrays in old.states:
        np.testing.assert_array_equal(arrays["state_lineage"], distinct)
    old.assimilate(data[3], "d3")
    again = RunStore.open(tmp_path / "old.nc")
    assert all("state_lineage" in arrays for arrays in again.states)
    # the new step's own labels are the uninterrupted run's; those of the step before were not stored
    lineage = again.states[-1]["state_lineage"]
    np.testing.assert_array_equal(lineage[:, 0], snapshot.state_arrays(reference.state)["state_lineage"][:, 0])
    np.testing.assert_array_equal(lineage[:, 1], np.arange(300.0))
    for a, b in zip(reference.result.steps, again.result.steps):
        np.testing.assert_array_equal(a.posterior, b.posterior)
        np.testing.assert_array_equal(a.predictive, b.predictive)
        assert a.info.log_evidence == b.info.log_evidence and a.info.ess == b.info.ess


def test_write_removes_stale_temporary_files(tmp_path):
    cfg = config(tmp_path)
    stale = tmp_path / ".run.nc.tmp-99999"
    stale.write_bytes(b"half a file")
    RunStore.create(tmp_path / "run.nc", cfg)
    assert not stale.exists()
    assert sorted(p.name for p in tmp_path.iterdir() if p.name.startswith(".run.nc")) == []


def test_a_step_posterior_as_arviz_data(tmp_path):
    az = pytest.importorskip("arviz")
    cfg = config(tmp_path)
    store = RunStore.create(tmp_path / "run.nc", cfg)
    for d in datasets(2):
        store.assimilate(d)
    idata = store.to_arviz(step=0)
    assert "posterior" in idata.groups()
    post = idata.posterior
    assert post["a"].shape == (1, 80) and post["b"].shape == (1, 80)
    assert post.attrs["step"] == 1
    assert post.attrs["log_evidence"] == store.result.steps[0].info.log_evidence
    # equal-weight draws (systematic resampling) keep the weighted mean up to resampling error:
    # systematic resampling of N = 80 draws moves the mean by at most ~ (range / N); 2 sd / sqrt(N) is generous
    rec = store.result.steps[0]
    tolerance = 2 * rec.std() / np.sqrt(80)
    assert np.all(np.abs(np.array([post["a"].values.mean(), post["b"].values.mean()]) - rec.mean()) < tolerance)
    summary = az.summary(idata, kind="stats")
    assert list(summary.index) == ["a", "b"]
    # reproducible: same default resampling seed
    again = posterior_to_arviz(store.result, 0)
    np.testing.assert_array_equal(again.posterior["a"].values, post["a"].values)


@pytest.mark.slow
def test_a_store_with_older_or_newer_diagnostics_still_opens(tmp_path):
    import dataclasses
    import json

    cfg = config(tmp_path)
    store = RunStore.create(tmp_path / "run.nc", cfg)
    store.assimilate(datasets(1)[0])
    ds = store.to_xarray()
    info = json.loads(str(ds["step_info"].values[0]))
    info.pop("n_nan")                        # a diagnostic the writer did not have yet
    info["from_the_future"] = 1.5            # one this reader does not know
    ds["step_info"] = (("step",), np.array([json.dumps(info)], dtype=object))
    rehash(ds)       # as that writer would have
    ds.to_netcdf(tmp_path / "other.nc", engine="h5netcdf")
    loaded = RunStore.open(tmp_path / "other.nc")
    assert loaded.result.steps[0].info.n_nan == 0
    assert loaded.result.steps[0].info.log_evidence == store.result.steps[0].info.log_evidence
    assert {f.name for f in dataclasses.fields(loaded.result.steps[0].info)} >= {"n_nan", "ess"}
