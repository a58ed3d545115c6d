"""Issue 42, item 2 (the High finding): no command overwrites what it reads, and every output is written whole.

Every ``--json``, ``--report`` and ``--output``/``-o`` target (and the figures of ``report --no-embed``) goes through
:mod:`seqbayes.store.targets`: a target that is an input, the run store or its lock or journal is refused (through
symbolic and hard links, even with ``--force``); an existing file the command did not write, or a link, needs
``--force``; the file is written atomically. A full disk or a read-only folder gives one line and leaves the inputs,
the store and an old output as they were: simulated here (the free space, ``ENOSPC`` in the middle of the write,
``EROFS``) for the fast tier, on a real tmpfs in the slow one.
"""

from __future__ import annotations

import errno
import hashlib
import json
import os
import re
import shutil
from pathlib import Path

import numpy as np
import pytest

from _hostile import fill, mount_tmpfs, remount_read_only, snapshot, unmount
from _user_model import decay_tables, write_config, write_model

from seqbayes import cli
from seqbayes.store import RunStore, load_config
from seqbayes.store import targets
from seqbayes.studies.environment import MASSES, STIFFNESSES, simulate_year, write_year_csv

BUILDING = ["--masses", ",".join(map(str, MASSES[:2])), "--stiffness", ",".join(map(str, STIFFNESSES[:2])),
            "--particles", "10"]


def sha(path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def one_line(capsys, argv, message):
    """``seqbayes ARGV`` exits 2 with one line matching ``message``; returns the line."""
    code = cli.main([str(a) for a in argv])
    out, err = capsys.readouterr()
    assert code == 2 and len(err.splitlines()) == 1 and err.startswith(f"seqbayes {argv[0]}: error: "), (out, err)
    assert re.search(message, err), err
    return err


def ok(capsys, argv) -> str:
    code = cli.main([str(a) for a in argv])
    out, err = capsys.readouterr()
    assert code == 0, err
    return out


def year(folder: Path) -> Path:
    table, truth = simulate_year(np.random.default_rng(5), masses=MASSES[:2], stiffnesses=STIFFNESSES[:2], n_days=2,
                                 sets_per_day=3)
    write_year_csv(folder / "year.csv", table, truth)        # and its truth sidecar, year.json
    return folder / "year.csv"


def make_run(folder: Path, module: str) -> Path:
    """A run of the decay model after one step, its config, module and data file d0.csv in ``folder``."""
    folder.mkdir(parents=True, exist_ok=True)
    write_model(folder, module)
    config = load_config(write_config(folder / "run.toml", module, n_samples=40, seed=3))
    table = decay_tables([1.2], np.linspace(0, 3, 12), 0.1, 0)[0]
    np.savetxt(folder / "d0.csv", table, delimiter=",", header="t,y", comments="")
    RunStore.create(folder / "run.nc", config).update(folder / "d0.csv")
    return folder / "run.nc"


@pytest.fixture(scope="module")
def pristine_run(tmp_path_factory):
    return make_run(tmp_path_factory.mktemp("outputs") / "run", "outputsmodel")


@pytest.fixture
def run(pristine_run, tmp_path):
    """A copy of the run's folder (forecasts and reports need no likelihood)."""
    shutil.copytree(pristine_run.parent, tmp_path / "run")
    return tmp_path / "run" / "run.nc"


# ------------------------------------------------------------------ High: an output over an input
def test_environment_never_writes_its_output_over_its_input(tmp_path, capsys):
    data = year(tmp_path)
    before = sha(data)
    os.symlink(data, tmp_path / "link.json")
    os.link(data, tmp_path / "hard.json")
    for option in ("--json", "--report"):
        for target in (data, tmp_path / "link.json", tmp_path / "hard.json"):
            for force in ((), ("--force",)):
                one_line(capsys, ["environment", data, *BUILDING, option, target, *force],
                         rf"{option} .*(year.csv|link.json|hard.json): is the input .*year.csv; an output never "
                         rf"replaces what the command reads \(give another file name\)")
    assert sha(data) == before
    one_line(capsys, ["environment", data, *BUILDING, "--json", tmp_path / "o", "--report", tmp_path / "o"],
             r"--report .*o: is also the target of --json; give each output its own file")
    assert not (tmp_path / "o").exists()


def test_an_existing_file_the_command_did_not_write_needs_force(tmp_path, capsys):
    data = year(tmp_path)
    truth = sha(tmp_path / "year.json")
    one_line(capsys, ["environment", data, *BUILDING, "--json", tmp_path / "year.json"],
             r"--json .*year.json: exists and is not a file this command wrote; give another name, or --force to "
             r"replace it")
    assert sha(tmp_path / "year.json") == truth                   # the truth sidecar is kept
    (tmp_path / "notes.html").write_text("<p>my notes</p>")
    one_line(capsys, ["environment", data, *BUILDING, "--report", tmp_path / "notes.html"], r"exists and is not a file")
    # its own output is replaced without --force, and --force replaces the others
    ok(capsys, ["environment", data, *BUILDING, "--json", tmp_path / "out.json"])
    first = json.loads((tmp_path / "out.json").read_text())
    (tmp_path / "out.json").chmod(0o640)
    ok(capsys, ["environment", data, *BUILDING, "--json", tmp_path / "out.json", "--seed", "1"])
    assert json.loads((tmp_path / "out.json").read_text())["p_damage"] != first["p_damage"]
    assert (tmp_path / "out.json").stat().st_mode & 0o777 == 0o640     # a replaced file keeps its permissions
    ok(capsys, ["environment", data, *BUILDING, "--json", tmp_path / "year.json", "--force"])
    assert "p_damage" in json.loads((tmp_path / "year.json").read_text())


@pytest.mark.slow   # two year reports rendered
def test_environment_replaces_its_own_report(tmp_path, capsys):
    data = year(tmp_path)
    ok(capsys, ["environment", data, *BUILDING, "--report", tmp_path / "r.html"])
    first = sha(tmp_path / "r.html")
    ok(capsys, ["environment", data, *BUILDING, "--report", tmp_path / "r.html", "--seed", "1"])
    assert sha(tmp_path / "r.html") != first


def test_a_link_at_the_target_needs_force_and_is_replaced_not_written_through(tmp_path, capsys):
    data = year(tmp_path)
    (tmp_path / "other.txt").write_text("keep me")
    os.symlink(tmp_path / "other.txt", tmp_path / "out.json")
    os.symlink(tmp_path / "nowhere", tmp_path / "dangling.json")
    one_line(capsys, ["environment", data, *BUILDING, "--json", tmp_path / "out.json"],
             r"--json .*out.json: is a symbolic link \(to .*other.txt\), which the output would replace; give another "
             r"name, or --force to replace the link")
    one_line(capsys, ["environment", data, *BUILDING, "--json", tmp_path / "dangling.json"], r"is a symbolic link")
    ok(capsys, ["environment", data, *BUILDING, "--json", tmp_path / "out.json", "--force"])
    assert not (tmp_path / "out.json").is_symlink() and (tmp_path / "other.txt").read_text() == "keep me"
    assert not (tmp_path / "nowhere").exists()
    for target, message in ((tmp_path, r"is a folder; give a file name"), ("/dev/null", r"is not a regular file"),
                            (tmp_path / "no" / "x.json", r"the folder .*no does not exist")):
        one_line(capsys, ["environment", data, *BUILDING, "--json", target, "--force"], message)


def test_predict_never_writes_over_the_store_its_side_files_or_the_module(run, capsys):
    folder = run.parent
    store = sha(run)
    module = Path(RunStore.open(run).user_code()[1])          # the module the run recorded (the original's)
    module_before = sha(module)
    os.symlink(run, folder / "alias.csv")
    for target, what in ((run, r"the run store .*run.nc"), (folder / "alias.csv", r"the run store .*run.nc"),
                         (folder / "run.nc.lock", r"the run store's lock \(run.nc.lock\)"),
                         (folder / ".run.nc.journal", r"the run store's journal \(.run.nc.journal\)"),
                         (module, r"the input .*outputsmodel.py")):
        one_line(capsys, ["predict", run, "--steps", "2", "-o", target, "--force"], rf"--output .*: is {what}; an "
                                                                                    r"output never replaces")
    one_line(capsys, ["predict", run, "--steps", "2", "-o", folder / "d0.csv"], r"exists and is not a file this command")
    for name in ("f.csv", "f.nc"):                              # its own forecasts are replaced
        ok(capsys, ["predict", run, "--steps", "2", "-o", folder / name])
        first = sha(folder / name)
        ok(capsys, ["predict", run, "--steps", "3", "-o", folder / name])
        assert sha(folder / name) != first
    assert sha(run) == store and sha(module) == module_before and not (folder / ".run.nc.journal").exists()


def test_report_never_writes_over_a_store_or_its_inputs(run, pristine_run, capsys):
    folder = run.parent
    other = folder / "other.nc"
    shutil.copy(run, other)
    module = RunStore.open(run).user_code()[1]
    for argv, what in ((["-o", run], "the run store .*run.nc"), (["-o", other, "--compare", other], "the run store .*other.nc"),
                       (["-o", folder / "d0.csv", "--data", folder / "d0.csv"], "the input .*d0.csv"),
                       (["-o", module], "the input .*outputsmodel.py")):
        one_line(capsys, ["report", run, "--forecast", "0", "--force", *argv], rf"--output .*: is {what}; an output "
                                                                               r"never replaces")
    (folder / "run_figures").write_text("not a folder")
    one_line(capsys, ["report", run, "--forecast", "0", "--no-embed"],
             r"run_figures: is not a folder; the report's figures go there \(--no-embed\)")
    (folder / "run_figures").unlink()
    (folder / "run_figures").mkdir()
    (folder / "run_figures" / "fig-parameters.png").write_text("my own picture")
    one_line(capsys, ["report", run, "--forecast", "0", "--no-embed"],
             r"--no-embed .*fig-parameters.png: exists and is not a file this command wrote")


@pytest.mark.slow   # four reports rendered: about 6 s
def test_report_replaces_its_own_page_and_figures(run, capsys):
    folder = run.parent
    ok(capsys, ["report", run, "--forecast", "0"])
    ok(capsys, ["report", run, "--forecast", "0"])              # RUN.html again: its own page
    (folder / "foreign.html").write_text("<!DOCTYPE html><html><body>mine</body></html>")
    one_line(capsys, ["report", run, "--forecast", "0", "-o", folder / "foreign.html"], r"exists and is not a file")
    ok(capsys, ["report", run, "--forecast", "0", "--no-embed", "-o", folder / "page.html"])
    figures = snapshot(folder / "page_figures")
    ok(capsys, ["report", run, "--forecast", "0", "--no-embed", "-o", folder / "page.html"])
    assert snapshot(folder / "page_figures").keys() == figures.keys() and len(figures) >= 3
    ok(capsys, ["report", run, "--forecast", "0", "-o", folder / "new" / "sub" / "r.html"])   # folders made for it
    assert (folder / "new" / "sub" / "r.html").is_file()


def test_init_never_creates_the_run_over_its_configuration_or_module(tmp_path, capsys):
    write_model(tmp_path, "initmodel")
    config = write_config(tmp_path / "run.toml", "initmodel", n_samples=40, seed=3)
    before = snapshot(tmp_path)
    one_line(capsys, ["init", config, config, "--force"], r"RUN .*run.toml: is the input .*run.toml")
    one_line(capsys, ["init", config, tmp_path / "initmodel.py", "--force"], r"RUN .*initmodel.py: is the input")
    assert snapshot(tmp_path) == before


def test_update_refuses_the_store_as_a_data_file(run, capsys):
    os.symlink(run, run.parent / "alias.csv")
    before = sha(run)
    for data in (run, run.parent / "alias.csv"):
        one_line(capsys, ["update", run, data], rf"{data.name}: is the run store .*run.nc itself, not a data file")
    assert sha(run) == before


# ------------------------------------------------------------------ written whole
def test_write_output_is_atomic_and_leaves_no_temporary_file(tmp_path, monkeypatch):
    target = tmp_path / "out.json"
    target.write_text("old")
    real = os.write

    def half_then_fail(fd, data):
        real(fd, bytes(data[:len(data) // 2]))
        raise OSError(errno.EIO, "Input/output error")
    monkeypatch.setattr(os, "write", half_then_fail)
    with pytest.raises(targets.OutputError, match=r"out.json: cannot write: Input/output error; nothing was written; "
                                                  r"the old file is kept"):
        targets.write_output(target, "x" * 100_000)
    monkeypatch.undo()
    assert target.read_text() == "old" and [p.name for p in tmp_path.iterdir()] == ["out.json"]
    os.link(target, tmp_path / "hard")                 # a hard link to the target is never written through
    targets.write_output(target, "new")
    assert target.read_text() == "new" and (tmp_path / "hard").read_text() == "old"


# the output options of every command, each: (argv builder, the target, whether the command ran a model first)
def _option_cases(tmp_path, run):
    data = year(tmp_path)
    return {
        "environment --json": (["environment", data, *BUILDING, "--json", tmp_path / "out.json"], tmp_path / "out.json"),
        "environment --report": (["environment", data, *BUILDING, "--report", tmp_path / "r.html"], tmp_path / "r.html"),
        "predict -o csv": (["predict", run, "--steps", "2", "-o", tmp_path / "f.csv"], tmp_path / "f.csv"),
        "predict -o nc": (["predict", run, "--steps", "2", "-o", tmp_path / "f.nc"], tmp_path / "f.nc"),
        "report -o": (["report", run, "--forecast", "0", "-o", tmp_path / "p.html"], tmp_path / "p.html"),
        "report --no-embed": (["report", run, "--forecast", "0", "--no-embed", "-o", tmp_path / "q.html"],
                              tmp_path / "q_figures" / "fig-parameters.png"),
    }


FAST_OPTIONS = ("environment --json", "predict -o csv", "predict -o nc")


def _fail_writes(monkeypatch, how):
    """Simulate a full disk (``free``: the free space; ``enospc``: the write itself) or a read-only folder."""
    if how == "free":
        monkeypatch.setattr(targets.shutil, "disk_usage", lambda folder: shutil._ntuple_diskusage(10 ** 9, 10 ** 9, 0))
        return r"not enough free space in .*: about \d+ KiB needed, 0 KiB free \(No space left on device\); nothing was "\
               r"written"
    real_open, real_write = os.open, os.write
    temporary = set()

    def opened(path, flags, *args, **kwargs):
        if ".tmp-" in os.fspath(path) and how == "read-only":
            raise OSError(errno.EROFS, os.strerror(errno.EROFS), os.fspath(path))
        fd = real_open(path, flags, *args, **kwargs)
        if ".tmp-" in os.fspath(path):
            temporary.add(fd)
        return fd

    def written(fd, data):
        if fd in temporary:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return real_write(fd, data)
    monkeypatch.setattr(os, "open", opened)
    monkeypatch.setattr(os, "write", written)
    return {"enospc": r"cannot write: No space left on device; nothing was written",
            "read-only": r"cannot write: Read-only file system; nothing was written"}[how]


def _failed_write_changes_nothing(run, folder, capsys, monkeypatch, option, how):
    """``option``'s command with its write failing ``how``: one line, and nothing changed but an empty figures'
    folder (``report --no-embed`` makes it before the first figure)."""
    argv, target = _option_cases(folder, run)[option]
    before, store = snapshot(folder), snapshot(run.parent)
    with monkeypatch.context() as patch:
        one_line(capsys, argv, _fail_writes(patch, how))
    after = snapshot(folder)
    if target.parent != folder:
        assert after.pop(target.parent.name) and not any(target.parent.iterdir())
    assert after == before and snapshot(run.parent) == store


HOWS = ("free", "enospc", "read-only")


@pytest.mark.parametrize("option, how", [(o, h) for o in FAST_OPTIONS for h in HOWS]
                         + [("report --no-embed", "read-only")])
def test_a_full_disk_or_read_only_folder_gives_one_line_for_every_output(run, tmp_path, capsys, monkeypatch, option,
                                                                         how):
    _failed_write_changes_nothing(run, tmp_path, capsys, monkeypatch, option, how)


@pytest.mark.slow   # the reports render their figures first
@pytest.mark.parametrize("option", ["environment --report", "report -o", "report --no-embed"])
def test_a_full_disk_or_read_only_folder_gives_one_line_for_the_reports(run, tmp_path, capsys, monkeypatch, option):
    for how in HOWS:
        folder = tmp_path / how
        folder.mkdir()
        _failed_write_changes_nothing(run, folder, capsys, monkeypatch, option, how)


@pytest.mark.slow
def test_every_output_on_a_real_full_or_read_only_disk_gives_one_line(pristine_run, tmp_path, capsys, monkeypatch):
    """The same on a 4 MiB tmpfs holding the inputs, the store and the outputs (root only)."""
    disk = mount_tmpfs(tmp_path / "disk", "4m")
    try:
        shutil.copytree(pristine_run.parent, disk / "run")
        run = disk / "run" / "run.nc"
        cases = _option_cases(disk, run)
        inputs = {"year": sha(disk / "year.csv"), "store": sha(run)}
        filler = fill(disk, 8 * 1024)
        for option, (argv, target) in cases.items():
            one_line(capsys, argv, r"(not enough free space in .*: about \d+ KiB needed, \d+ KiB free|No space left "
                                   r"on device)")
            assert not target.exists(), option
        # the space runs out in the write itself (the free-space check bypassed)
        filler.unlink()
        fill(disk, 0)
        with monkeypatch.context() as patch:
            patch.setattr(targets, "_SLACK", -10 ** 12)
            for option, (argv, target) in cases.items():
                one_line(capsys, argv, r"No space left on device")
                assert not target.exists() and not [p for p in disk.rglob(".*.tmp-*")], option
        (disk / "filler").unlink()
        for option, (argv, target) in cases.items():      # room again: each writes, then the disk goes read-only
            ok(capsys, argv)
        written = {option: sha(target) for option, (argv, target) in cases.items()}
        (disk / "run" / "run.nc.lock").unlink(missing_ok=True)
        remount_read_only(disk)
        for option, (argv, target) in cases.items():
            one_line(capsys, argv, r"Read-only file system")
            assert sha(target) == written[option], option
        assert inputs == {"year": sha(disk / "year.csv"), "store": sha(run)}
    finally:
        unmount(disk)
