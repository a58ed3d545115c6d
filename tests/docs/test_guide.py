"""docs/guide.md is run top to bottom (``tools/docgen.py``): its files, commands and Python
blocks, in an empty folder, and every output it shows must be what the current code prints
(durations aside). ``make docs-regen`` rewrites the outputs after an intended change."""

import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "tools"))
import docgen  # noqa: E402

sys.path.remove(str(ROOT / "tools"))


def test_guide_outputs_are_the_current_code(tmp_path):
    mismatches = docgen.run_guide(ROOT / "docs" / "guide.md", folder=tmp_path)
    assert not mismatches, "docs/guide.md differs from a rerun (`make docs-regen`):\n\n" + "\n\n".join(
        map(str, mismatches))
    # the run really happened: the files the guide creates are there
    for name in ("beam.py", "beam.toml", "month4.csv", "beam.nc", "beam_trend0.nc", "beam.html", "beam_api.nc"):
        assert (tmp_path / name).is_file(), name


def test_readme_example_prints_what_it_shows(tmp_path):
    assert docgen.run_guide(ROOT / "README.md", folder=tmp_path) == []


def test_run_store_page_prints_what_it_shows(tmp_path):
    """docs/run_store.md's SG-EnMCMC section: a shake-table record through init/update/status/report."""
    assert docgen.run_guide(ROOT / "docs" / "run_store.md", folder=tmp_path) == []
    assert (tmp_path / "shake.html").is_file() and "Modal results" in (tmp_path / "shake.html").read_text()


def test_a_changed_output_is_caught(tmp_path):
    page = tmp_path / "page.md"
    page.write_text("```console\n$ echo 41\n42\n```\n")
    (mismatch,) = docgen.run_guide(page, folder=tmp_path)
    assert mismatch.expected == "$ echo 41\n42" and mismatch.actual == "$ echo 41\n41"
    docgen.run_guide(page, write=True, folder=tmp_path)
    assert page.read_text() == "```console\n$ echo 41\n41\n```\n"
    assert docgen.run_guide(page, folder=tmp_path) == []


def test_durations_are_not_compared_but_numbers_are(tmp_path):
    page = tmp_path / "page.md"
    page.write_text("<!-- run -->\n```python\nprint('3 steps in 0.12 s')\n```\n\n"
                    "<!-- output -->\n```text\n3 steps in 9.99 s\n```\n")
    assert docgen.run_guide(page, folder=tmp_path) == []
    page.write_text(page.read_text().replace("3 steps in 9.99", "4 steps in 9.99"))
    assert len(docgen.run_guide(page, folder=tmp_path)) == 1


def test_generated_sections_round_trip(tmp_path):
    page = tmp_path / "page.md"
    page.write_text("intro\n<!-- generated: t -->\nold\n<!-- end generated -->\noutro\n")
    assert docgen.generated_section(page, "t") == "old"
    docgen.write_generated_section(page, "t", "new\ntable\n")
    assert page.read_text() == "intro\n<!-- generated: t -->\nnew\ntable\n<!-- end generated -->\noutro\n"
    with pytest.raises(ValueError, match="no section"):
        docgen.generated_section(page, "missing")
