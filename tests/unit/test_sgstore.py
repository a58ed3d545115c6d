"""SG-EnMCMC runs in the run store (seqbayes.store.sg) and on the command line.

* Resume is bit-identical: blocks assimilated by one object, by a fresh object opened before
  every block, and by a forked ``seqbayes update`` killed at the journal's fault points and
  rerun, give the same arrays and generator states; all equal one uninterrupted
  ``SGEnMCMC.reset`` + ``update`` over the whole record.
* Bad input (wrong channel count, NaN, no rows, a block out of time order, a block given twice,
  a broken configuration) is one line naming the argument, and the store's bytes are unchanged.
* The store's integrity checks hold for the new kind; SEMC's reader refuses it by name.
"""

from __future__ import annotations

import json
import os
import signal

import h5py
import numpy as np
import pytest

from seqbayes import cli
from seqbayes.store.config import ConfigError, load_config
from seqbayes.store.datasets import DataError
from seqbayes.store import SGRunStore
from seqbayes.store.sg_config import parse_sg_config
from seqbayes.store import DuplicateDatasetError, RunStore, StoreError
from seqbayes.store.files import FAULT_ENV, read_file
from seqbayes.structural.structures.shear_building import discretise, simulate
from _sg_model import sg_toml

TOML = sg_toml("two-storey", 48, sensors=True)
TRUTH = np.array([0.9, 0.8])
N_BLOCKS = 3


def record(config, n=240, seed=0):
    """``(t, ag, y)`` of the two-storey building at TRUTH with 0.05 m/s^2 noise."""
    rng = np.random.default_rng(seed)
    ag = rng.standard_normal(n)
    y = simulate(discretise(config.build_building(), TRUTH, config.dt), ag)[0]
    return np.arange(n) * config.dt, ag, y + 0.05 * rng.standard_normal(y.shape)


@pytest.fixture(scope="module")
def workdir(tmp_path_factory):
    root = tmp_path_factory.mktemp("sgstore")
    (root / "run.toml").write_text(TOML)
    config = load_config(root / "run.toml")
    t, ag, y = record(config)
    table = np.column_stack([t, ag, y])
    for k, block in enumerate(np.array_split(table, N_BLOCKS)):
        np.savetxt(root / f"b{k + 1}.csv", block, delimiter=",", header="t,ag,a1,a2", comments="", fmt="%.17g")
    reference = SGRunStore.create(root / "reference.nc", config)   # one object, every block
    for k in range(N_BLOCKS):
        reference.update(root / f"b{k + 1}.csv")
    return root


def arrays(path):
    """Every variable of a store but the per-step wall times (the text of step_info and its hash)."""
    attrs, variables = read_file(path)
    out = {name: value for name, value in variables.items() if name not in ("step_info", "record_sha256")}
    out["infos"] = [{k: v for k, v in json.loads(s).items() if k != "wall_time"} for s in variables["step_info"]]
    return out


def assert_same_store(a, b):
    va, vb = arrays(a), arrays(b)
    assert va.keys() == vb.keys()
    for name in va:
        if isinstance(va[name], np.ndarray):
            assert va[name].dtype == vb[name].dtype and np.array_equal(va[name], vb[name]), name
        else:
            assert va[name] == vb[name], name


def test_config_from_toml(workdir):
    config = load_config(workdir / "run.toml")
    assert config.kind == "sgenmcmc"
    assert config.columns == ("t", "ag", "a1", "a2") and config.names == ("theta_1", "theta_2")
    assert config.lower == (0.5, 0.5) and config.measurement_std == (0.05, 0.05)


def test_reopen_before_every_block_is_bit_identical(workdir, tmp_path, monkeypatch):
    from seqbayes.store import files

    appended = []
    real = files.apply_with_journal
    monkeypatch.setattr(files, "apply_with_journal", lambda *a: (appended.append(1), real(*a)))
    config = load_config(workdir / "run.toml")
    SGRunStore.create(tmp_path / "run.nc", config)
    for k in range(N_BLOCKS):
        SGRunStore.open(tmp_path / "run.nc").update(workdir / f"b{k + 1}.csv")
    assert len(appended) == N_BLOCKS - 1      # blocks after the first are appended in place
    assert_same_store(workdir / "reference.nc", tmp_path / "run.nc")


def test_store_equals_one_uninterrupted_identifier(workdir):
    config = load_config(workdir / "run.toml")
    t, ag, y = record(config)
    sampler = config.build_identifier()
    sampler.reset(np.random.default_rng(config.seed))
    whole = sampler.update(ag, y)
    store = SGRunStore.open(workdir / "reference.nc")
    stored = store.result()
    for name in ("theta_mean", "theta_var", "theta_mpv", "theta_quantiles", "ess", "log_evidence_increments",
                 "state_mean", "drift_mean", "drift_std", "move_steps", "move_acceptance", "final_theta"):
        assert np.array_equal(getattr(whole, name), getattr(stored, name)), name
    snap = sampler.snapshot()
    assert np.array_equal(snap["theta"], store.fixed[-1]["theta"])
    assert snap["rng_state"] == store.rng_states[-1]
    # the block summaries add up to the record's log-evidence and the posterior is near the truth
    assert store.infos[-1]["log_evidence"] == pytest.approx(whole.log_evidence, rel=1e-12)
    post = store.block_posterior()
    for j, name in enumerate(config.names):
        assert abs(post[name]["mean"] - TRUTH[j]) < 6 * post[name]["sd"] + 1e-3


def fork_update(run, block, fault):
    pid = os.fork()
    if pid == 0:  # pragma: no cover - the child
        code = 70
        try:
            os.environ[FAULT_ENV] = fault
            devnull = os.open(os.devnull, os.O_WRONLY)
            os.dup2(devnull, 1)
            os.dup2(devnull, 2)
            code = cli.main(["update", str(run), str(block)])
        finally:
            os._exit(code)
    _, status = os.waitpid(pid, 0)
    return status


@pytest.mark.parametrize("fault", ["mid-write"] + [pytest.param(fault, marks=pytest.mark.slow) for fault in
                                                   ("before-write", "before-replace", "mid-apply", "after-replace")])
def test_killed_update_resumes_bit_identically(workdir, tmp_path, fault):
    config = load_config(workdir / "run.toml")
    run = tmp_path / "run.nc"
    store = SGRunStore.create(run, config)
    store.update(workdir / "b1.csv")
    status = fork_update(run, workdir / "b2.csv", fault)      # the append of step 2 is killed
    assert os.WIFSIGNALED(status) and os.WTERMSIG(status) == signal.SIGKILL
    after = SGRunStore.open(run)
    committed = fault not in ("before-write", "mid-write")   # the journal was complete (fsync-ed)
    assert after.n_steps == (2 if committed else 1)
    for k in range(after.n_steps + 1, N_BLOCKS + 1):
        assert cli.main(["update", str(run), str(workdir / f"b{k}.csv")]) == 0
    assert_same_store(workdir / "reference.nc", run)
    assert not (tmp_path / ".run.nc.journal").exists()


def test_cli_cycle(workdir, tmp_path, capsys):
    run = tmp_path / "cli.nc"
    assert cli.main(["init", str(workdir / "run.toml"), str(run)]) == 0
    assert "SG-EnMCMC run" in capsys.readouterr().out
    blocks = [str(workdir / f"b{k + 1}.csv") for k in range(N_BLOCKS)]
    assert cli.main(["update", str(run), *blocks]) == 0
    out = capsys.readouterr().out
    assert out.count("step ") >= N_BLOCKS and "theta_2" in out
    assert cli.main(["status", str(run)]) == 0
    text = capsys.readouterr().out
    assert "theta_1" in text and "blocks: 3" in text
    assert cli.main(["status", str(run), "--json"]) == 0
    rows = json.loads(capsys.readouterr().out)["steps"]
    reference = SGRunStore.open(workdir / "reference.nc")
    assert [r["parameters"] for r in rows] == [reference.block_posterior(i) for i in range(N_BLOCKS)]
    assert_same_store(workdir / "reference.nc", run)
    assert cli.main(["predict", str(run), "--steps", "2"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "SG-EnMCMC" in err
    with pytest.raises(StoreError, match="SG-EnMCMC run store"):
        RunStore.open(run)


def _bad_files(workdir, tmp_path):
    good = np.loadtxt(workdir / "b2.csv", delimiter=",", skiprows=1)
    files = {}
    np.savetxt(tmp_path / "channels.csv", good[:, :3], delimiter=",", header="t,ag,a1", comments="")
    files["channels"] = (tmp_path / "channels.csv", "'a2'")
    nan = good.copy()
    nan[5, 3] = np.nan
    np.savetxt(tmp_path / "nan.csv", nan, delimiter=",", header="t,ag,a1,a2", comments="")
    files["nan"] = (tmp_path / "nan.csv", "'a2'")
    (tmp_path / "empty.csv").write_text("t,ag,a1,a2\n")
    files["empty"] = (tmp_path / "empty.csv", "empty.csv")
    np.savetxt(tmp_path / "skip.csv", good[10:], delimiter=",", header="t,ag,a1,a2", comments="")
    files["out of order"] = (tmp_path / "skip.csv", "must start at")
    np.savetxt(tmp_path / "again.csv", np.loadtxt(workdir / "b1.csv", delimiter=",", skiprows=1), delimiter=",",
               header="t,ag,a1,a2", comments="", fmt="%.17g")
    files["duplicate"] = (tmp_path / "again.csv", "already assimilated")
    return files


def test_bad_blocks_are_one_line_and_leave_the_store_unchanged(workdir, tmp_path, capsys):
    run = tmp_path / "run.nc"
    SGRunStore.create(run, load_config(workdir / "run.toml")).update(workdir / "b1.csv")
    before = run.read_bytes()
    for what, (path, named) in _bad_files(workdir, tmp_path).items():
        assert cli.main(["update", str(run), str(path)]) == 2, what
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and named in err and err.startswith("seqbayes update: error:"), (what, err)
        assert run.read_bytes() == before, what
    store = SGRunStore.open(run)
    good = np.loadtxt(workdir / "b2.csv", delimiter=",", skiprows=1)
    for table, match in [(good[:, 1:], r"expected shape \(n_rows, 4\)"), (good[:0], "no data rows"),
                         (good[:, 0], r"expected shape"), (np.where(good > 0, np.inf, good), "NaN/inf")]:
        with pytest.raises(DataError, match=match):
            store.assimilate(table)
    with pytest.raises(DuplicateDatasetError):
        store.update(workdir / "b1.csv")
    assert run.read_bytes() == before and store.n_steps == 1
    store.update(workdir / "b2.csv")      # the object is still usable
    assert store.n_steps == 2


@pytest.mark.parametrize("edit, match", [
    (("data", "responses", ["a1"]), "data.responses: expected 2 columns"),
    (("sampler", "n_particles", 10), "sampler.n_particles: unknown setting"),
    (("priors", "upper", 0.4), "priors.upper: must exceed"),
    (("noise", "measurement_std", [0.1, float("nan")]), "noise.measurement_std"),
    (("building", "stiffnesses", [1.0]), "building.stiffnesses: expected 2 values"),
    (("sensors", "accelerations", [3]), "sensors.accelerations"),
    (("data", "dt", 0.5), "data.dt"),
    (("sampler", "n_members", 4), "sampler"),
])
def test_config_errors_name_the_field(edit, match):
    import tomllib

    raw = tomllib.loads(TOML)
    section, key, value = edit
    raw[section][key] = value
    with pytest.raises(ConfigError, match=match):
        parse_sg_config(raw, "run.toml")


def test_edited_store_is_refused(workdir, tmp_path):
    import shutil

    run = tmp_path / "run.nc"
    shutil.copy(workdir / "reference.nc", run)
    with h5py.File(run, "r+") as f:
        info = json.loads(f["step_info"].asstr()[1])
        info["log_evidence_increment"] += 1.0
        f["step_info"][1] = json.dumps(info)
    with pytest.raises(StoreError, match="content hash"):
        SGRunStore.open(run)
    shutil.copy(workdir / "reference.nc", run)
    with h5py.File(run, "r+") as f:
        f["sg_theta"][0, 0, 0] = np.nan
    with pytest.raises(StoreError, match="damaged|checksum"):
        SGRunStore.open(run)


def test_building_from_a_user_module(tmp_path):
    (tmp_path / "mybuilding.py").write_text(
        "from seqbayes.structural.structures import ShearBuilding\n"
        "def building():\n    return ShearBuilding([2e4, 1.6e4], [3e7, 2e7], (0.02, 0.03))\n")
    text = TOML.replace('masses = [20000.0, 16000.0]\nstiffnesses = [3.0e7, 2.0e7]\ndamping_ratios = [0.02, 0.03]',
                        'module = "mybuilding:building"')
    (tmp_path / "run.toml").write_text(text)
    config = load_config(tmp_path / "run.toml")
    assert config.masses == (2e4, 1.6e4) and config.building_module == "mybuilding:building"
    assert len(config.building_sha256) == 64
    (tmp_path / "mybuilding.py").write_text("def building():\n    return 3\n")
    with pytest.raises(ConfigError, match="building.module: .*must return"):
        load_config(tmp_path / "run.toml")


# ------------------------------------------------------------------------------ modal results
def direct_modes(building, theta):
    """Frequencies [Hz], damping ratios and shapes of one ``theta`` by a direct eigen-solution: the
    generalised problem K phi = w^2 M phi (scipy) and the complex eigenvalues of the state matrix."""
    from scipy.linalg import eigh

    K = building.stiffness_matrix(theta)[0]
    w2, shapes = eigh(K, building.mass_matrix())
    A, _ = building.continuous_state_space(theta)
    lam = np.linalg.eigvals(A[0])
    lam = lam[lam.imag > 0]
    lam = lam[np.argsort(np.abs(lam))]
    return np.sqrt(w2) / (2 * np.pi), -lam.real / np.abs(lam), np.abs(lam) / (2 * np.pi), shapes


def test_modal_results_match_a_direct_eigen_solution():
    from seqbayes.structural.structures import ShearBuilding
    from seqbayes.structural.structures.modal import modal_summary

    building = ShearBuilding([3e4, 2.5e4, 2e4], [4e7, 3e7, 2e7], (0.02, 0.05), (1, 3))
    thetas = np.array([[0.9, 0.8, 1.1], [1.0, 0.7, 0.95], [0.85, 0.9, 0.75]])
    weights = np.array([0.5, 0.3, 0.2])
    direct = [direct_modes(building, t) for t in thetas]
    f = np.array([d[0] for d in direct])
    zeta = np.array([d[1] for d in direct])
    assert np.allclose(f, np.array([d[2] for d in direct]), rtol=1e-10)   # classical damping: |lambda| = w
    summary = modal_summary(building, thetas, weights, identified_shapes=direct[0][3][:, ::-1])
    assert np.allclose(summary.frequencies, f, rtol=1e-10)
    assert np.allclose(summary.damping_ratios, zeta, rtol=1e-8)
    assert np.allclose(summary.frequency_mean, weights @ f, rtol=1e-10)
    assert np.allclose(summary.damping_mean, weights @ zeta, rtol=1e-8)
    assert np.allclose(summary.frequency_sd, np.sqrt(weights @ (f - weights @ f) ** 2), rtol=1e-8)
    assert np.all(summary.frequency_interval[0] >= f.min(0) - 1e-12)
    assert np.all(summary.frequency_interval[1] <= f.max(0) + 1e-12)
    # one sample: the mean shapes are the direct ones (MAC 1), the identified shapes given in reverse order
    one = modal_summary(building, thetas[:1], identified_shapes=direct[0][3][:, ::-1])
    from seqbayes.structural.structures.modal import mac

    assert np.allclose(np.diag(mac(one.shapes, direct[0][3])), 1.0, atol=1e-12)
    expected = mac(direct[0][3], direct[0][3][:, ::-1])   # not the identity: the shapes are M-orthogonal
    assert np.allclose(one.mac_identified, expected, atol=1e-12)
    assert np.allclose(np.fliplr(one.mac_identified).diagonal(), 1.0, atol=1e-12)
    assert np.allclose(one.frequency_interval, f[:1].repeat(2, axis=0), rtol=1e-12)
    assert np.all(summary.mac_identified[:, ::-1].diagonal() > 0.99)   # three nearby parameter vectors


@pytest.mark.slow
def test_store_modal_and_the_report_contain_them(workdir, tmp_path, capsys):
    from seqbayes.store.sg_report import modal_rows, render_sg_report
    from seqbayes.structural.structures.modal import modal_summary

    store = SGRunStore.open(workdir / "reference.nc")
    theta, w = store.posterior_samples()
    assert np.allclose(w.sum(), 1.0)
    summary = store.modal()
    direct = modal_summary(store.config.build_building(), theta, w)
    assert np.array_equal(summary.frequency_mean, direct.frequency_mean)
    f_truth = direct_modes(store.config.build_building(), TRUTH)[0]
    assert np.all(np.abs(summary.frequency_mean - f_truth) < 6 * summary.frequency_sd + 1e-4 * f_truth)
    text = render_sg_report(store)
    assert "<h2>Modal results</h2>" in text and "fig-modal" in text and "fig-ratios" in text
    for row in modal_rows(store.modal(-1, store.config.build_building().modes(np.ones(2))[1][0])):
        assert f"{row['frequency_mean']:.4f}" in text and f"{row['damping_mean']:.4f}" in text
        assert f"[{row['frequency_lower']:.4f}, {row['frequency_upper']:.4f}]" in text
        assert f"{row['mac_identified']:.4f}" in text
    # the command line, with identified shapes from a file, and a bad file in one line
    shapes = direct_modes(store.config.build_building(), TRUTH)[3]
    np.savetxt(tmp_path / "modes.csv", shapes, delimiter=",", header="mode1,mode2", comments="")
    out = tmp_path / "report.html"
    assert cli.main(["report", str(workdir / "reference.nc"), "-o", str(out), "--modes",
                     str(tmp_path / "modes.csv")]) == 0
    page = out.read_text()
    assert "identified (modes.csv)" in page
    mac_row = modal_rows(store.modal(-1, shapes))
    assert all(f"{r['mac_identified']:.4f}" in page for r in mac_row)
    assert all(r["mac_identified"] > 0.999 for r in mac_row)
    np.savetxt(tmp_path / "bad.csv", shapes[:1], delimiter=",")
    capsys.readouterr()
    assert cli.main(["report", str(workdir / "reference.nc"), "-o", str(out), "--modes", str(tmp_path / "bad.csv")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "expected 2 rows" in err


def test_blocks_in_g_are_stored_in_si(workdir, tmp_path):
    from seqbayes.structural.structures.records import UNITS

    (tmp_path / "g.toml").write_text(TOML.replace('time = "t"', 'time = "t"\nunits = "g"'))
    config = load_config(tmp_path / "g.toml")
    assert config.units == {"ag": "g", "a1": "g", "a2": "g"}
    block = np.loadtxt(workdir / "b1.csv", delimiter=",", skiprows=1)
    in_g = block.copy()
    in_g[:, 1:] /= UNITS["g"]
    store = SGRunStore.create(tmp_path / "g.nc", config)
    store.assimilate(in_g, "b1_g.csv")
    assert np.array_equal(store.tables[0], in_g * np.array([1.0, UNITS["g"], UNITS["g"], UNITS["g"]]))
    reference = SGRunStore.open(workdir / "reference.nc").block_posterior(0)
    for name, p in store.block_posterior(0).items():
        assert abs(p["mean"] - reference[name]["mean"]) < 0.5 * reference[name]["sd"], name
    import tomllib

    raw = tomllib.loads(TOML)
    raw["data"]["units"] = {"a1": "mm"}
    with pytest.raises(ConfigError, match=r"data.units.a1: an acceleration column takes one of"):
        parse_sg_config(raw, "run.toml")
    raw["data"]["units"] = {"t": "s"}
    with pytest.raises(ConfigError, match=r"data.units.t: not an input or response column"):
        parse_sg_config(raw, "run.toml")


@pytest.mark.slow
def test_noise_parameters_and_a_pinned_surrogate(workdir, tmp_path):
    """[sampler] noise_parameters: the noise scales are stored, shown and resumed with the ratios;
    surrogate = "auto" is measured once, when the configuration is read, and pinned as a level."""
    import tomllib

    from seqbayes.store.sg_report import render_sg_report

    raw = tomllib.loads(TOML)
    raw["sampler"]["noise_parameters"] = "shared"
    config = parse_sg_config(raw, "run.toml")
    assert config.names == config.build_identifier().parameter_names == ("theta_1", "theta_2", "log_noise_scale")
    one = SGRunStore.create(tmp_path / "one.nc", config)
    SGRunStore.create(tmp_path / "two.nc", config)
    for k in range(2):
        one.update(workdir / f"b{k + 1}.csv")
        SGRunStore.open(tmp_path / "two.nc").update(workdir / f"b{k + 1}.csv")
    assert_same_store(tmp_path / "one.nc", tmp_path / "two.nc")
    post = one.block_posterior()
    assert set(post) == set(config.names) and abs(post["log_noise_scale"]["mean"]) < 0.3   # the true noise
    assert one.modal().frequency_mean.shape == (2,)
    assert "log_noise_scale" in render_sg_report(one)
    raw = tomllib.loads(TOML)
    raw["sampler"]["surrogate"] = "auto"
    pinned = parse_sg_config(raw, "run.toml")
    assert "surrogate" not in pinned.settings and "level" in pinned.settings and pinned.surrogate_choice
    assert "surrogate" not in parse_sg_config(raw, "run.toml").settings
