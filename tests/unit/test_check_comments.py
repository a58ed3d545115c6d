"""tools/check_comments.py: source comments hold no run results or history (numbers with units of a
run's result, seeds, run numbers, issue numbers, commit hashes); they go to docs/ and commit messages."""

import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "tools"))
import check_comments  # noqa: E402

sys.path.remove(str(ROOT / "tools"))



def _rules(source):
    return sorted((f.line, f.rule) for f in check_comments.check_source(source))


@pytest.mark.parametrize("comment, rule", [
    ("# off by 0.12 nats at step 4", "measure"),
    ("# within +- 0.006 sd of the exact mean", "measure"),
    ("# 16 -> 9 ms of profiled time", "measure"),
    ("# about 3.2 s per update", "measure"),
    ("# at most 50,000 calls", "measure"),
    ("# 1.43e8 evaluations", "measure"),
    ("# 15 % of the exact grid", "measure"),
    ("# seed 0: the worst case", "seed"),
    ("# the mean over 40 seeds", "seed"),
    ("# run 0 under T6 takes the remedy", "run"),
    ("# replicate 4 ended 193 nats off", "run"),
    ("# the bar of issue 23", "issue"),
    ("# see #41", "issue"),
    ("# since bcc66ad the cache is shared", "commit"),
])
def test_each_rule_flags_its_kind(comment, rule):
    assert rule in [r for _, r in _rules(f"x = 1\n{comment}\n")]


def test_why_comments_code_and_strings_are_not_flagged():
    source = ('"""Docstring: 0.12 nats, seed 3, issue 23 (not read by default)."""\n'
              "# the tempering bisection needs the log domain: weights span many orders of magnitude\n"
              "x = compute(seed=3, n_calls=500)  # (N, d) convention, Eq. 12 of the paper\n"
              "y = '0.5 s'  # a string is code, not a comment\n"
              "# at step 2 the kernel's mixture has 6 components; sd and s are symbols here\n")
    assert _rules(source) == []


def test_a_figure_split_over_two_comment_lines_is_seen_on_its_line():
    source = "x = 1\n# the estimate ended within 0.1\n# nats of the exact one\n"
    (flag,) = check_comments.check_source(source)
    assert (flag.line, flag.first_line, flag.rule, flag.match) == (2, 2, "measure", "0.1 nats")
    # two trailing comments on consecutive code lines are two comments
    assert _rules("dt = 0.02  # step, in\nn = 5     # s of the window\n") == []


def test_an_inline_exception_needs_a_reason():
    flagged = "WINDOW = 76  # samples per campaign: 1.5 s"
    assert _rules(flagged) == [(1, "measure")]
    assert _rules(flagged + " (comment-ok: a unit conversion, not a result)") == []
    assert _rules(flagged + " (comment-ok:)") == [(1, "measure")]
    assert _rules(flagged + " (comment-ok: x)") == [(1, "measure")]
    # the exception covers the whole block it is in
    assert _rules("# comment-ok: the paper's own rule name\n# the '90% moved' rule\n") == []


def test_docstrings_are_read_only_when_asked():
    source = 'def f():\n    """Summary.\n\n    Measured: the step took\n    3.2 s at seed 4.\n    """\n'
    assert check_comments.check_source(source) == []
    flags = check_comments.check_source(source, include_docstrings=True)
    assert sorted((f.line, f.rule) for f in flags) == [(5, "measure"), (5, "seed")]
    assert check_comments.flagged_comments(flags) == 1


def test_the_command_line_counts_and_fails(tmp_path, capsys):
    (tmp_path / "a.py").write_text("x = 1  # 0.2 nats off at seed 3\n")
    (tmp_path / "b.py").write_text("y = 2  # the why\n")
    assert check_comments.main([str(tmp_path), "--count"]) == 1
    assert capsys.readouterr().out.strip() == "1"
    assert check_comments.main([str(tmp_path / "b.py")]) == 0


@pytest.fixture(scope="module")
def src_flags():
    return check_comments.check_paths([ROOT / "src"])


def test_src_comments_hold_no_run_results_or_history(src_flags):
    """No comment in src/ carries a run's result, a seed, a run count, an issue number or a commit hash."""
    assert not src_flags, "\n".join(map(str, src_flags))
