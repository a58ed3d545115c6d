"""Modal runs through the run store (seqbayes.store.modal, .modal_config, .modal_files) and the command line:
the mast's tracked hours through init/update with no hand-written step, an OMA table and a raw record as
datasets, and the configuration's errors."""

from importlib import resources

import numpy as np
import pytest

from seqbayes.cli import main
from seqbayes.store import ConfigError, DataError, DuplicateDatasetError, load_config, open_run
from seqbayes.store.modal import ModalRunStore, ModalTrackingWarning
from seqbayes.structural.modes_table import read_modes_table, write_modes_table
from seqbayes.structural.oma import ambient_record
from seqbayes.structural.structures import ShearBuilding

MAST = resources.files("seqbayes") / "data" / "guyed_mast"


@pytest.fixture(scope="module")
def tracked(tmp_path_factory):
    """The mast's first four days through seqbayes track (the whole three weeks: tests/statistical)."""
    out = tmp_path_factory.mktemp("mast")
    lines = (MAST / "poles_60min.csv").read_text().splitlines()
    head = [lines[0]] + [line for line in lines[1:] if float(line.split(",")[1]) < 4.0]
    (out / "poles.csv").write_text("\n".join(head) + "\n")
    assert main(["track", str(out / "poles.csv"), "--temperature", str(MAST / "temperature_60min.csv"),
                 "--out", str(out), "--prefix", "hour"]) == 0
    return out


def test_track_writes_datasets_a_summary_and_a_run(tracked, capsys):
    files = sorted(tracked.glob("hour_*.csv"))
    records = len((tracked / "tracking.csv").read_text().splitlines()) - 1
    assert 80 < len(files) <= records < 100
    table = read_modes_table(files[0])
    assert table.mode.tolist() == [1, 2, 3, 4] and np.isfinite(table.covariates["temperature"]).all()
    rows = (tracked / "tracking.csv").read_text().splitlines()
    assert rows[0].startswith("day,poles,spurious,f1,")
    config = load_config(tracked / "run.toml")
    assert config.kind == "modal" and config.names == tuple(f"f{j}" for j in range(1, 8))
    assert config.columns == ("mode", "frequency_hz", "std_frequency_hz")


def test_tracked_hours_go_through_init_and_update(tracked, tmp_path, capsys):
    run = tmp_path / "mast.nc"
    toml = (tracked / "run.toml").read_text().replace("n_samples = 300", "n_samples = 50")
    (tmp_path / "run.toml").write_text(toml)
    assert main(["init", str(tmp_path / "run.toml"), str(run)]) == 0
    hours = [str(tracked / f"hour_00{i}.csv") for i in (1, 2)]
    assert main(["update", str(run), *hours, "-q"]) == 0
    out = capsys.readouterr().out
    assert out.count("mast.nc: step") == 2
    store = open_run(run)
    assert isinstance(store, ModalRunStore) and store.n_steps == 2
    means = store.result.means()[-1]
    hour = read_modes_table(hours[-1])                         # the hour's tracked modes
    assert np.all(np.abs(means[hour.mode - 1] / hour.frequency - 1) < 0.005)
    assert main(["update", str(run), hours[0]]) == 2           # the same hour twice: refused
    assert "already assimilated" in capsys.readouterr().err


@pytest.mark.slow
def test_an_oma_table_is_tracked_against_the_posterior(tracked, tmp_path):
    toml = (tracked / "run.toml").read_text().replace("n_samples = 300", "n_samples = 100")
    (tmp_path / "run.toml").write_text(toml)
    store = ModalRunStore.create(tmp_path / "m.nc", load_config(tmp_path / "run.toml"))
    for i in (1, 2):
        store.update(tracked / f"hour_00{i}.csv")
    hour = read_modes_table(tracked / "hour_003.csv")
    # the hour as an OMA gives it: no mode column, rows shuffled, and a spurious pole
    from dataclasses import replace
    order = np.array([2, 0, 3, 1])[:hour.n_rows]
    oma = replace(hour.take(order), mode=None, covariates={})
    spur = replace(oma.take([0]), frequency=np.array([0.9]))
    from seqbayes.structural.modes_table import PoleTable
    both = PoleTable(**{f: (np.concatenate([getattr(oma, f), getattr(spur, f)]) if f not in
                            ("time_start", "channels", "covariates", "shapes", "std_shapes", "mode") else
                            (oma.time_start + spur.time_start if f == "time_start" else getattr(oma, f)))
                        for f in PoleTable.__dataclass_fields__})
    path = write_modes_table(tmp_path / "oma.csv", both)
    with pytest.warns(ModalTrackingWarning, match="1 of 5 poles assigned to no mode"):
        store.update(path)
    assert store.n_steps == 3
    with pytest.raises(DuplicateDatasetError):
        store.update(path)
    with pytest.warns(ModalTrackingWarning):                   # tracked again against step 2's posterior
        store.update(path, replace_last=True)
    assert store.n_steps == 3 and store.sources[-1] == "oma.csv"


SHEAR_TOML = """
[model]
name = "building"
likelihood = "modal"

[modal]
model = "shear_building"
masses = [2e5, 2e5, 2e5, 1.6e5]
stiffnesses = [3e8, 2.6e8, 2.2e8, 1.8e8]
storeys = [1, 2]
frequency_error = 0.01
shape_error = 0.1
record_dt = 0.02

[priors]
k1 = { dist = "uniform", lower = 0.5, upper = 1.5 }
k2 = { dist = "uniform", lower = 0.5, upper = 1.5 }

[sampler]
n_samples = 100
seed = 3
"""


@pytest.mark.slow
def test_a_raw_record_is_identified_and_tracked(tmp_path):
    (tmp_path / "b.toml").write_text(SHEAR_TOML)
    building = ShearBuilding([2e5, 2e5, 2e5, 1.6e5], [3e8, 2.6e8, 2.2e8, 1.8e8])
    y = ambient_record(building, [0.9, 1.0, 1.0, 1.0], 300.0, 0.02, rng=1)
    np.savetxt(tmp_path / "record.csv", y, delimiter=",", header="1,2,3,4", comments="")
    store = ModalRunStore.create(tmp_path / "b.nc", load_config(tmp_path / "b.toml"))
    table = store.read_datafile(tmp_path / "record.csv")
    assert table.shape[1] == 3 + 8 and np.all(table[:, 0] == 0)       # untracked until the update
    store.update(tmp_path / "record.csv")
    post = store.result.steps[-1]
    assert 0.8 < store.result.means()[-1][0] < 1.0                     # storey 1 at 0.9
    assert post.posterior.shape == (100, 2)


@pytest.mark.parametrize("change, match", [
    (("model = \"shear_building\"", "model = \"beam\""), "modal.model: expected one of"),
    (("storeys = [1, 2]", "storeys = [1, 2, 3]"), "3 storeys but 2 model parameters"),
    (("frequency_error = 0.01", "frequency_errr = 0.01"), "unknown setting.*frequency_error"),
    (("frequency_error = 0.01", "frequency_error = \"sigma\""), "'sigma' is not a parameter"),
    (("shape_error = 0.1", "shape_error = -0.1"), "shape_error: must be >= 0"),
    (("[priors]", "[data]\ncolumns = [\"f\"]\n[priors]"), "remove the \\[data\\] section"),
    (("likelihood = \"modal\"", "likelihood = \"mine:loglike\""), "built-in likelihood"),
    (("storeys = [1, 2]", "storeys = [1, 2]\nchannels = [\"a\", \"b\"]"), "expected 4 distinct names"),
])
def test_configuration_errors_name_the_field(tmp_path, change, match):
    (tmp_path / "b.toml").write_text(SHEAR_TOML.replace(*change))
    with pytest.raises(ConfigError, match=match):
        load_config(tmp_path / "b.toml")


def test_the_floors_channels_name_the_shape_columns(tmp_path):
    (tmp_path / "b.toml").write_text(SHEAR_TOML.replace("storeys = [1, 2]", 'storeys = [1, 2]\nchannels = ["a1", "a2", "a3", "a4"]'))
    config = load_config(tmp_path / "b.toml")
    assert config.columns[3:5] == ("phi_a1", "phi_a2") and config.columns[-1] == "std_phi_a4"
    assert config.build_likelihood().model.channels == ("a1", "a2", "a3", "a4")


def test_a_stored_modal_run_reopens_with_its_table(tmp_path):
    (tmp_path / "b.toml").write_text(SHEAR_TOML)
    config = load_config(tmp_path / "b.toml")
    ModalRunStore.create(tmp_path / "b.nc", config)
    again = open_run(tmp_path / "b.nc")
    assert isinstance(again, ModalRunStore) and again.config.modal == config.modal
    assert again.config.fingerprint() == config.fingerprint()


def test_a_record_table_of_several_days_is_refused(tmp_path):
    (tmp_path / "b.toml").write_text(SHEAR_TOML.replace("shape_error = 0.1\n", "").replace(
        "pairing", "#"))
    store = ModalRunStore.create(tmp_path / "b.nc", load_config(tmp_path / "b.toml"))
    (tmp_path / "two.csv").write_text("day,frequency_hz\n0,2.0\n1,2.1\n")
    with pytest.raises(DataError, match="holds 2 records"):
        store.read_datafile(tmp_path / "two.csv")
