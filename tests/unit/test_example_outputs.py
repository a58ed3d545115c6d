"""The example studies' output folders (issue 42, item 2): ``seqbayes example NAME --out DIR`` never writes over
files it did not write, and says so in one line before any work."""

import os
import re

import pytest

from seqbayes import cli
from seqbayes.store.targets import FOLDER_MARK, OutputError, claim_output_folder


def test_a_new_folder_is_created_and_marked(tmp_path):
    folder = claim_output_folder(tmp_path / "a" / "b", "example coulomb")
    assert folder.is_dir() and (folder / FOLDER_MARK).read_text() == "example coulomb\n"
    assert claim_output_folder(folder, "example coulomb") == folder      # the same study again: taken


def test_a_folder_of_the_users_files_is_refused_and_left_as_it_was(tmp_path):
    (tmp_path / "thesis.tex").write_text("years of work")
    with pytest.raises(OutputError, match=r"--out .*: holds files that seqbayes example coulomb did not write "
                                          r"\(thesis.tex\); give a new or empty folder, or --force"):
        claim_output_folder(tmp_path, "example coulomb")
    assert sorted(os.listdir(tmp_path)) == ["thesis.tex"] and (tmp_path / "thesis.tex").read_text() == "years of work"
    claim_output_folder(tmp_path, "example coulomb", force=True)
    assert (tmp_path / "thesis.tex").read_text() == "years of work"


def test_another_studys_folder_a_file_and_a_folder_holding_an_input_are_refused(tmp_path):
    claim_output_folder(tmp_path / "osc", "example oscillator")
    with pytest.raises(OutputError, match="did not write"):
        claim_output_folder(tmp_path / "osc", "example coulomb")
    (tmp_path / "f.csv").write_text("1\n")
    with pytest.raises(OutputError, match="is not a folder"):
        claim_output_folder(tmp_path / "f.csv", "example coulomb", force=True)
    with pytest.raises(OutputError, match="holds the input"):
        claim_output_folder(tmp_path, "example coulomb", inputs=[tmp_path / "f.csv"], force=True)
    with pytest.raises(OutputError, match="give a folder of its own"):
        claim_output_folder(".", "example coulomb")


@pytest.mark.parametrize("name, option", [("resampling", "--out"), ("coulomb", "--out"), ("oscillator", "--out"),
                                          ("acceptance", "--out"), ("shake-table", "--output")])
def test_every_example_refuses_a_users_folder_in_one_line_before_the_work(tmp_path, capsys, name, option):
    (tmp_path / "notes.txt").write_text("mine")
    code = cli.main(["example", name, option, str(tmp_path)])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1 and f"{option} {tmp_path}: holds files" in err, err
    assert os.listdir(tmp_path) == ["notes.txt"] and (tmp_path / "notes.txt").read_text() == "mine"


@pytest.mark.parametrize("how", ["free", "enospc", "read-only"])
def test_a_full_or_read_only_disk_for_an_examples_folder_is_one_line_before_the_work(tmp_path, capsys, monkeypatch,
                                                                                     how):
    """The folder's mark is the study's first write: a full disk or a read-only folder stops it there, in one line
    (simulated as tests/unit/test_hardening_outputs.py does), and leaves no half-written file."""
    from tests.unit.test_hardening_outputs import _fail_writes

    with monkeypatch.context() as patch:
        expected = _fail_writes(patch, how)
        code = cli.main(["example", "resampling", "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1, err
    assert re.search(expected, err), err
    assert [p.name for p in (tmp_path / "out").iterdir()] == []
