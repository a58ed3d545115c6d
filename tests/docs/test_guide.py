"""docs/guide.md is run top to bottom (``tools/docgen.py``): its files, commands and Python
blocks, in an empty folder, and every output it shows must be what the current code prints
(durations and content hashes aside), its numbers to the precision of their Monte Carlo error (the
``<!-- tolerance: ... -->`` rules above a block; a number no rule covers, to the digit). ``make
docs-regen`` rewrites the outputs after an intended change."""

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


def test_numbers_are_compared_to_their_block_s_tolerance(tmp_path):
    page = tmp_path / "page.md"
    block = "<!-- tolerance: \"ESS @\" rel 0.25; \"increment @\" abs 0.2 -->\n```console\n$ echo {}\n{}\n```\n"
    shown = "step 1: increment -77.08, ESS 81.5 of N = 500"
    for current, fails in [("step 1: increment -77.19, ESS 95.3 of N = 500", False),
                           ("step 1:  increment -77.19, ESS 95.3  of N = 500", False),    # columns shift
                           ("step 1: increment -77.39, ESS 81.5 of N = 500", True),       # beyond 0.2 nats
                           ("step 1: increment -77.08, ESS 110.0 of N = 500", True),      # beyond 25 %
                           ("step 1: increment -77.08, ESS 81.5 of N = 400", True),       # no rule: every digit
                           ("step 2: increment -77.08, ESS 81.5 of N = 500", True),
                           ("step 1: increment -77.08, ESS 81.5 out of N = 500", True)]:  # the text itself
        page.write_text(block.format(f"'{current}'", shown))
        assert len(docgen.run_guide(page, folder=tmp_path)) == fails, current


def test_the_tolerance_rules_parse_and_select_what_they_say():
    rules = docgen.parse_tolerance('"@ \\+-" se 1.8; "\\+- @" factor 4; "^- forecasts" line; col 2-3 abs 0.01 rel 0.1; '
                                   "why: the note; with semicolons")
    assert [r.kind for r in rules] == ["numbers", "numbers", "line", "numbers"]
    assert docgen.compare_numbers("a 1.48 +- 0.13 b", "a 1.70 +- 0.30 b", rules) == []
    (difference,) = docgen.compare_numbers("a 1.48 +- 0.13 b", "a 1.75 +- 0.13 b", rules)
    assert "1.75 where the page shows 1.48" in difference
    assert docgen.compare_numbers("- forecasts: run 0 T4", "- forecasts: run 3 T1 and T2", rules) == []
    assert docgen.compare_numbers("x 1 2.0 3.00", "x 1 2.2 3.00", rules) == []        # columns 2-3
    assert len(docgen.compare_numbers("x 1 2.0 3.00", "x 1 2.0 3.01", rules)) == 1     # column 4: every digit
    assert docgen.compare_numbers("P 1.6e-26", "P 5e-26", "factor 4") == []
    assert len(docgen.compare_numbers("P 1.6e-26", "P 7.0e-26", "factor 4")) == 1
    # a number is not part of a name or a range's sign, and rounding of the printed digits is allowed for
    assert [m.group() for m in docgen.numbers("theta_1 T1 0-199 -3.5 1,234 9.4.")] == ["0", "199", "-3.5", "1,234", "9.4"]
    assert docgen.compare_numbers("p 0.989", "p 0.990", "abs 0") == []
    for bad in ("col x abs 1", '"ESS @" fuzzy 2', "abs", '"a" col 2 line'):
        with pytest.raises(ValueError, match="tolerance rule"):
            docgen.parse_tolerance(bad)


@pytest.mark.parametrize("page", ["README.md", "docs/guide.md", "docs/run_store.md"])
def test_every_tolerance_of_a_page_catches_a_change_beyond_it(page):
    """A real change still fails: each number a rule of the page covers, moved to twice its tolerance in the
    page's own output, is a mismatch (and moved by a tenth of it, none); every rule covers some number."""
    blocks = [b for b in docgen.parse((ROOT / page).read_text().splitlines())
              if not isinstance(b, tuple) and b.tolerance]
    assert blocks, f"{page} states no tolerance"
    for block in blocks:
        rules = docgen.parse_tolerance(block.tolerance)
        used = set()
        text = docgen.normalise("\n".join(block.body))
        for i, line in enumerate(text.splitlines()):
            for p_num, _, marked, column in docgen._numbered(line, line):
                rule = next((r for r in rules if r.selects(marked, column)), None)
                if rule is None or rule.kind != "numbers" or any(r.kind == "line" and r.regex.search(line) for r in rules):
                    continue
                used.add(id(rule))
                value = docgen._value(p_num.group())
                after = line[p_num.end():]
                width = rule.width(p_num.group(), after, line)
                if rule.factor and value > 0:
                    width = max(width, value * (rule.factor - 1))
                for scale, fails in ((2.0, True), (0.1, False)):
                    moved = f"{value + scale * width + (2.5 if fails else 0) * docgen._resolution(p_num.group()):.6g}"
                    changed = text.splitlines()
                    changed[i] = line[:p_num.start()] + moved + after
                    found = docgen.compare_numbers(text, "\n".join(changed), rules)
                    assert bool(found) == fails, (page, block.start, marked, moved, found)
        assert used == {id(r) for r in rules if r.kind == "numbers"}, (page, block.start, "a rule selects nothing")


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
