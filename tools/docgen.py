"""Keep the documentation's outputs and tables equal to what the current code produces.

Two mechanisms, rewritten by ``make docs-regen`` (``python tools/docgen.py --write``) and checked
against a rerun by ``make docs-check`` (``python tools/docgen.py sections``) and by the tests
(``tests/docs/test_guide.py``, ``tests/studies/test_coulomb_study.py``, and the reduced oscillator
study in ``tests/studies/test_oscillator_study.py``):

1. **Executable guide.** ``docs/guide.md`` (and the README and ``docs/run_store.md``) is run top to
   bottom in an empty folder. An HTML
   comment right before a fenced block says what the block is (the comments do not show in the
   rendered site):

   - ``<!-- file: beam.py -->``: the block is written to that file;
   - ``<!-- run -->``: the Python block is executed (one namespace for the whole guide, the
     folder as working directory); when the next block is preceded by ``<!-- output -->`` it must
     equal what the Python block printed;
   - ``<!-- shell: CMD -->`` (no block needed): a set-up command run silently;
   - every ``console`` block is run: each ``$ command`` line is executed and the lines after it,
     up to the next ``$``, must equal its output (stdout and stderr, as a terminal shows them).

   Durations (``in 0.47 s``) are the only text not compared: they depend on the machine.

2. **Generated sections** of any page, between ``<!-- generated: KEY -->`` and
   ``<!-- end generated -->``, hold text that a producer registered under ``KEY`` renders
   (for example the Coulomb study's tables from :func:`seqbayes.studies.coulomb.tables_markdown`).

Written here rather than with a doctest or ``pytest-markdown`` plugin because the guide mixes
shell sessions of an installed command, files the later commands read, and Python blocks whose
printed output is shown in a separate block; no maintained plugin runs all three in one folder.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import os
import re
import shutil
import subprocess
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
GUIDE = ROOT / "docs" / "guide.md"

_FENCE = re.compile(r"^```(\w*)\s*$")
_DIRECTIVE = re.compile(r"^<!--\s*(file|run|output|shell|norun)\s*:?\s*(.*?)\s*-->\s*$")
_DURATION = re.compile(r"\b\d+(?:\.\d+)? (?:s|ms)\b")


@dataclass(frozen=True)
class Block:
    """A fenced block of a Markdown page: its language, body lines, the directive before it,
    and the line range ``[start, stop)`` of its body in the page."""

    lang: str
    body: tuple[str, ...]
    directive: tuple[str, str] | None
    start: int
    stop: int


@dataclass(frozen=True)
class Mismatch:
    """Where the page and the current code differ."""

    where: str
    expected: str
    actual: str

    def __str__(self) -> str:
        return f"{self.where}:\n--- page\n{self.expected}\n+++ current code\n{self.actual}"


def parse(lines: list[str]) -> list[Block | tuple[str, str]]:
    """The page's fenced blocks and stand-alone ``shell`` directives, in order."""
    items: list[Block | tuple[str, str]] = []
    pending = None
    i = 0
    while i < len(lines):
        line = lines[i]
        directive = _DIRECTIVE.match(line)
        if directive:
            kind, arg = directive.group(1), directive.group(2)
            if kind == "shell":
                items.append(("shell", arg))
            else:
                pending = (kind, arg)
            i += 1
            continue
        fence = _FENCE.match(line)
        if fence:
            stop = i + 1
            while stop < len(lines) and lines[stop].rstrip() != "```":
                stop += 1
            if stop == len(lines):
                raise ValueError(f"line {i + 1}: unclosed code fence")
            items.append(Block(fence.group(1), tuple(lines[i + 1:stop]), pending, i + 1, stop))
            pending = None
            i = stop + 1
            continue
        if line.strip():
            pending = None
        i += 1
    return items


def normalise(text: str) -> str:
    """Text as compared: durations masked, trailing blanks and blank end lines dropped."""
    lines = [_DURATION.sub("<duration>", line.rstrip()) for line in text.splitlines()]
    while lines and not lines[-1]:
        lines.pop()
    return "\n".join(lines)


def _command(line: str, folder: Path) -> str:
    """Run one shell line in ``folder`` with this interpreter's ``seqbayes`` first on the PATH;
    stdout and stderr together, as a terminal shows them."""
    env = dict(os.environ, PYTHONUNBUFFERED="1", OPENBLAS_NUM_THREADS="1", MPLBACKEND="Agg",
               COLUMNS="100", NO_COLOR="1")
    env["PATH"] = os.pathsep.join([str(Path(sys.executable).parent), env.get("PATH", "")])
    done = subprocess.run(["bash", "-c", line], cwd=folder, env=env, stdin=subprocess.DEVNULL,
                          stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, timeout=600)
    return done.stdout


def _console(block: Block, folder: Path) -> list[str]:
    """Run a console block; return it with the current outputs in place of the page's."""
    out: list[str] = []
    for line in block.body:
        if line.startswith("$ "):
            out.append(line)
            out.extend(_command(line[2:], folder).rstrip("\n").splitlines())
    return out


def _run_python(code: str, namespace: dict) -> str:
    buffer = io.StringIO()
    with contextlib.redirect_stdout(buffer):
        exec(compile(code, "<guide>", "exec"), namespace)  # noqa: S102 - the guide's own code
    return buffer.getvalue()


def run_guide(path: Path = GUIDE, write: bool = False, folder: Path | None = None) -> list[Mismatch]:
    """Run the guide; return what differs (and, with ``write``, rewrite the page with it).

    Parameters
    ----------
    path : Path
        The Markdown page.
    write : bool
        Replace the page's outputs with the current ones (durations included).
    folder : Path, optional
        Working folder (a fresh temporary one by default).
    """
    lines = path.read_text().splitlines()
    items = parse(lines)
    replacements: dict[tuple[int, int], list[str]] = {}
    mismatches: list[Mismatch] = []
    with contextlib.ExitStack() as stack:
        if folder is None:
            folder = Path(stack.enter_context(tempfile.TemporaryDirectory(prefix="seqbayes-guide-")))
        old_cwd = Path.cwd()
        os.chdir(folder)
        stack.callback(os.chdir, old_cwd)
        import matplotlib

        matplotlib.use("Agg")
        namespace: dict = {"__name__": "__guide__"}
        sys.path.insert(0, str(folder))  # `from beam import loglike` in the guide's API section
        stack.callback(sys.path.remove, str(folder))
        last_printed = None
        for item in items:
            if isinstance(item, tuple):
                _command(item[1], folder)
                continue
            kind = item.directive[0] if item.directive else None
            where = f"{path.name}:{item.start}"
            if kind == "file":
                (folder / item.directive[1]).write_text("\n".join(item.body) + "\n")
            elif kind == "run":
                last_printed = _run_python("\n".join(item.body), namespace)
                continue
            elif kind == "output":
                if last_printed is None:
                    raise ValueError(f"{where}: an output block must follow a run block")
                actual = last_printed.rstrip("\n").splitlines()
                if normalise("\n".join(item.body)) != normalise("\n".join(actual)):
                    mismatches.append(Mismatch(where, "\n".join(item.body), "\n".join(actual)))
                replacements[(item.start, item.stop)] = actual
            elif item.lang == "console" and kind != "norun":
                actual = _console(item, folder)
                if normalise("\n".join(item.body)) != normalise("\n".join(actual)):
                    mismatches.append(Mismatch(where, "\n".join(item.body), "\n".join(actual)))
                replacements[(item.start, item.stop)] = actual
            last_printed = None
    if write and replacements:
        new = list(lines)
        for (start, stop), body in sorted(replacements.items(), reverse=True):
            new[start:stop] = body
        path.write_text("\n".join(new) + "\n")
    return mismatches


# ---------------------------------------------------------------- generated sections

_BEGIN = "<!-- generated: {key} -->"
_END = "<!-- end generated -->"


def _split_section(page: Path, key: str) -> tuple[str, str, str]:
    """The page's text before, inside and after the section ``key`` (markers in the outer parts)."""
    text = page.read_text()
    begin = _BEGIN.format(key=key)
    if begin not in text:
        raise ValueError(f"{page}: no section '{begin}'")
    head, rest = text.split(begin, 1)
    if _END not in rest:
        raise ValueError(f"{page}: section {key!r} has no '{_END}'")
    body, tail = rest.split(_END, 1)
    return head + begin, body, _END + tail


def generated_section(page: Path, key: str) -> str:
    """The text between ``<!-- generated: key -->`` and the next ``<!-- end generated -->``."""
    return _split_section(page, key)[1].strip("\n")


def write_generated_section(page: Path, key: str, content: str) -> None:
    """Replace the section's text with ``content``."""
    head, _, tail = _split_section(page, key)
    page.write_text(f"{head}\n{content.strip(chr(10))}\n{tail}")


def coulomb_tables(write: bool = False) -> str:
    """The Coulomb study's tables as ``docs/coulomb_friction.md`` shows them: the full study at the
    command's defaults (10 runs, seed 2023). With ``write`` its figures replace the page's."""
    from seqbayes.studies import coulomb

    with tempfile.TemporaryDirectory(prefix="seqbayes-coulomb-") as out:
        study = coulomb.run_study(progress=False, out_dir=Path(out))
        if write:
            for figure in Path(out).glob("fig*.png"):  # the figures the page shows
                target = ROOT / "docs" / "figures" / f"coulomb_{figure.name}"
                if target.exists():
                    shutil.copyfile(figure, target)
        return coulomb.tables_markdown(study)


def oscillator_correctness(write: bool = False) -> str:
    """The damped-oscillator study's timing-free results (against the exact grid reference, and the
    checks) for the command's defaults (10 runs, N = 1000, seed 0), as docs/damped_oscillator.md shows."""
    from seqbayes.studies import oscillator

    return oscillator.correctness_report(oscillator.run_study(progress=False))


def oscillator_reduced(write: bool = False) -> str:
    """The same account for the reduced study that ``make test`` reruns (2 runs x 6 kernels x 2
    samplers, N = 300, seed 0, one process): run 0 takes the conflict remedy, so the path-space step
    is covered too. The default study (about 8 CPU minutes) is checked by ``make docs-check``."""
    from seqbayes.studies import oscillator

    return oscillator.correctness_report(oscillator.run_study(runs=2, n_samples=300, workers=1, progress=False))


SECTIONS = {("coulomb_friction.md", "coulomb-tables"): coulomb_tables,
            ("damped_oscillator.md", "oscillator-correctness"): oscillator_correctness,
            ("damped_oscillator.md", "oscillator-reduced"): oscillator_reduced}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--write", action="store_true", help="rewrite the pages with the current outputs")
    parser.add_argument("what", nargs="*", default=["guide", "sections"], help="guide and/or sections")
    args = parser.parse_args(argv)
    failed = False
    if "guide" in args.what:
        for page in (GUIDE, ROOT / "README.md", ROOT / "docs" / "run_store.md"):
            mismatches = run_guide(page, write=args.write)
            for m in mismatches:
                print(m, "\n")
            print(f"{page.relative_to(ROOT)}: {len(mismatches)} block(s) differ{' (rewritten)' if args.write else ''}")
            failed |= bool(mismatches) and not args.write
    if "sections" in args.what:
        for (page, key), render in SECTIONS.items():
            path = ROOT / "docs" / page
            content = render(write=args.write)
            same = content.strip("\n") == generated_section(path, key)
            if args.write and not same:
                write_generated_section(path, key, content)
            print(f"docs/{page} [{key}]: {'same' if same else 'differs'}{' (rewritten)' if args.write and not same else ''}")
            failed |= not same and not args.write
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())
