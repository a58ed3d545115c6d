"""Issue 24 (medium): an SMC^2 run store keeps the sampler's full state (outer particles, inner filters,
likelihood estimates) for its last two steps only, not per step; per step it keeps the posterior record,
the diagnostics and the inner filters' guide. A store of the old layout (format 4, the full state per step)
still opens, and its next update continues it bit for bit in the new layout."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import xarray as xr

from seqbayes.store import RunStore, load_config, snapshot
from seqbayes.store.base import rehash
from seqbayes.store.smc import FORMAT_VERSION

from _user_model import decay_tables, write_config, write_model


def smc2_config(tmp_path, n_samples=60):
    write_model(tmp_path, "smc2layoutmodel")
    # a drifting amplitude and a static rate: SMC^2 (the default predictive of static plus drifting parameters)
    cfg = load_config(write_config(tmp_path / "run.toml", "smc2layoutmodel", n_samples=n_samples, seed=5,
                                   kernel='a = { type = "drift", rate = -0.05, noise_std = 0.02 }'))
    assert cfg.predictive_method == "smc2"
    return cfg


def tables(n):
    return decay_tables([1.5 - 0.05 * s for s in range(n)], np.linspace(0, 3, 15), 0.1, seed=3)


def full_names(arrays):
    return {name for name in arrays if not snapshot.per_step(name)}


@pytest.mark.slow
def test_the_full_state_is_kept_for_the_last_two_steps_and_the_run_resumes_bit_for_bit(tmp_path):
    cfg = smc2_config(tmp_path, n_samples=40)
    data = tables(3)
    reference = cfg.build_sampler()
    per_step = []                            # the full state arrays after every step of an uninterrupted run
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for table in data:
            reference.update(table)
            per_step.append(snapshot.state_arrays(reference.snapshot()[0]))
        RunStore.create(tmp_path / "run.nc", cfg)
        for k, table in enumerate(data):
            RunStore.open(tmp_path / "run.nc").assimilate(table, f"d{k}")
    ds = xr.open_dataset(tmp_path / "run.nc", engine="h5netcdf")
    grows = [name for name in ds.data_vars if ds[name].dims[:1] == ("step",) and name.startswith("nested_")]
    assert sorted(grows) == sorted(snapshot.NESTED_PER_STEP)            # no inner filter per step
    assert ds["nested_full_cloud_x"].shape[0] == 2 and sorted(ds["nested_slot_step"].values) == [2, 3]
    ds.close()
    store = RunStore.open(tmp_path / "run.nc")
    assert [bool(full_names(arrays)) for arrays in store.states] == [False, True, True]
    for mine, theirs in zip(store.states, per_step):
        for name in mine:
            np.testing.assert_array_equal(mine[name], theirs[name])
    for a, b in zip(store.result.steps, reference.result.steps):
        np.testing.assert_array_equal(a.posterior, b.posterior)
        np.testing.assert_array_equal(a.log_weights, b.log_weights)
    assert store.rng_states[-1] == reference.snapshot()[2]
    with pytest.raises(ValueError, match="keeps its sampler's full state for the last two steps only"):
        store.state_at(1)
    np.testing.assert_array_equal(store.sampler(2, loglike=lambda theta, data: None).snapshot()[0].cloud["x"],
                                  per_step[1]["nested_cloud_x"])          # the step before: for replace_last


@pytest.mark.slow
def test_a_format_4_smc2_store_opens_and_continues_in_the_new_layout(tmp_path):
    cfg = smc2_config(tmp_path)
    data = tables(4)
    reference = cfg.build_sampler()
    per_step = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for table in data[:3]:
            reference.update(table)
            per_step.append(snapshot.state_arrays(reference.snapshot()[0]))
        store = RunStore.create(tmp_path / "new.nc", cfg)
        for k, table in enumerate(data[:3]):
            store.assimilate(table, f"d{k}", write=False)
    # the old layout: every nested array per step
    ds = store.to_xarray()
    ds = ds.drop_vars([name for name in ds.variables if name.startswith("nested_full_") or name == "nested_slot_step"])
    for name in full_names(per_step[-1]):
        value = np.stack([arrays[name] for arrays in per_step])
        ds[name] = (("step",) + snapshot.state_dims(name, value.ndim - 1), value)
    ds.attrs["seqbayes_store_format"] = 4
    rehash(ds)
    ds.to_netcdf(tmp_path / "v4.nc", engine="h5netcdf")
    old = RunStore.open(tmp_path / "v4.nc")
    assert [bool(full_names(arrays)) for arrays in old.states] == [False, True, True]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        old.assimilate(data[3], "d3")
        reference.update(data[3])
    again = RunStore.open(tmp_path / "v4.nc")
    assert again.n_steps == 4
    for a, b in zip(again.result.steps, reference.result.steps):
        np.testing.assert_array_equal(a.posterior, b.posterior)
        np.testing.assert_array_equal(a.log_weights, b.log_weights)
        assert a.info.log_evidence == b.info.log_evidence
    assert again.rng_states[-1] == reference.snapshot()[2]
    with xr.open_dataset(tmp_path / "v4.nc", engine="h5netcdf") as written:
        assert written.attrs["seqbayes_store_format"] == FORMAT_VERSION == 5
        assert "nested_cloud_x" not in written and written["nested_full_cloud_x"].shape[0] == 2
