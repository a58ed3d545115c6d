"""Issue 42's property test: hostile tables through every command that reads one.

Each table is a command's valid table with one to three of the issue's classes of trouble combined at random
(:mod:`_hostile`: unsorted, negative, duplicated, huge and gapped days, extra columns, '#' inside rows, extreme
frequencies and temperatures, a BOM, upper-case headers, ';' separators, header only, FIFOs, /dev/zero and a
sparse file over the reader's bound, NaN/inf, non-numeric cells, huge numbers, binary bytes, ragged rows, CRLF).
Every run must end in a result (exit 0, something on stdout; for ``oma`` also exit 1, a result that found no mode
and says why) or one line (exit 2, ``seqbayes CMD: error: ...``);
no input file may change; on a refusal the run store (and the command's output) must be as before; nothing but
``seqbayes ...`` lines (errors, and warnings in our words) may reach stderr (no traceback, no raw warning).

A new command is one line in :data:`COMMANDS` (the columns of its valid table and its argv).
"""

from __future__ import annotations

import os
import zlib
from collections import Counter
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
import pytest

from _hostile import base_table, hostile_table, record_table, snapshot, write_table
from _user_model import decay_tables, write_config, write_model

from seqbayes import cli
from seqbayes.store import RunStore, load_config
from seqbayes.store.datasets import MAX_FILE_BYTES

MASSES, STIFFNESS = "2e5,2e5", "3e8,2.6e8"   # natural frequencies 3.98 and 10.06 Hz
N_TABLES = int(os.environ.get("SEQBAYES_HOSTILE_TABLES", "120"))


@dataclass(frozen=True)
class Case:
    """One run: the table's path, the case's folder, the run store (None for commands without one)."""

    table: Path
    folder: Path
    store: Path | None


@dataclass(frozen=True)
class Command:
    """A command that reads a table: the header of its valid table, whether the second column is a covariate
    (temperature), the typical measurements, its argv for a case, what a result prints on stdout, whether it
    writes the case's run store, the classes of trouble it must always refuse, its output files (absent
    after a refusal) and, where the valid table is not a monitoring table, how to make it
    (``base(columns, rng) -> Table``, e.g. :func:`_hostile.record_table` for a response record)."""

    columns: tuple
    covariate: bool
    values: tuple
    argv: Callable[[Case], list]
    result: str
    store: bool = False
    refuses: frozenset | None = None     # None: every class but a BOM and CRLF
    outputs: tuple = ()
    base: Callable | None = None
    accepts: frozenset = frozenset()       # classes that may end in a result (by default only BOM and CRLF)
    empty_code: int | None = None        # an exit status that is a result saying it found nothing (oma: 1)


#: Classes every reader refuses whatever the command's rules.
READER_REFUSES = frozenset({"FIFO", "/dev/zero", "sparse 1 GiB", "header only", "upper-case header",
                            "';' separators", "ragged row", "binary bytes", "comment line"})

#: A record (``oma``) always refused: its time column must increase by a uniform step; every cell a finite
#: number; a column beyond the channels is constant (or text, or unnamed).
RECORD_REFUSES = frozenset({"unsorted days", "duplicated day", "day 1e20", "gap of 1e9 days", "negative day",
                            "'#' inside a row", "non-numeric", "NaN/inf", "extra column 'f3'", "extra column 'note'",
                            "extra column ''", "extra column 'f1'"})
#: A poles table (``track``) always refused: days in time order within 100 years, no '#', text or unnamed column.
POLES_REFUSES = frozenset({"unsorted days", "day 1e20", "gap of 1e9 days", "'#' inside a row", "non-numeric",
                           "extra column 'note'", "extra column ''"})

COMMANDS = {
    "update": Command(("t", "y"), False, (1.0,), lambda c: ["update", c.store, c.table, "-q"], "step 2 from",
                      store=True, refuses=READER_REFUSES),
    "environment": Command(("day", "temperature", "f1", "f2"), True, (4.0, 10.0),
                           lambda c: ["environment", c.table, "--masses", MASSES, "--stiffness", STIFFNESS,
                                      "--particles", "10", "--json", c.folder / "out.json"], "alarm day:",
                           outputs=("out.json",),
                           # an empty frequency cell is a mode not identified in that set (a valid table);
                           # a cell spelt nan or inf is refused (tests/unit/test_monitor_cli.py)
                           accepts=frozenset({"NaN/inf"})),
    # a response record: 20 s at 100 Hz of two channels (modes at 5 and 12 Hz); no mode found is exit 1 with its line
    "oma": Command(("t", "a1", "a2"), False, (), lambda c: ["oma", c.table, "--fs", "100", "--out",
                                                           c.folder / "modes.csv"], "status:",
                   refuses=(READER_REFUSES - {"upper-case header"}) | RECORD_REFUSES, outputs=("modes.csv",),
                   base=lambda columns, rng: record_table(columns, rng, n_rows=2000, dt=0.01, frequencies=(5.0, 12.0)),
                   empty_code=1),
    # a poles table: one pole near 4 Hz per record, six records a day
    "track": Command(("day", "frequency_hz", "std_frequency_hz"), False, (4.0, 0.04),
                     lambda c: ["track", c.table, "--out", c.folder / "tracked"], "modes tracked",
                     refuses=READER_REFUSES | POLES_REFUSES, outputs=("tracked",)),
}


@pytest.fixture(scope="module")
def pristine_store(tmp_path_factory):
    """A run of the decay model after one step; its bytes are put back before each case."""
    folder = tmp_path_factory.mktemp("hostile_store")
    write_model(folder, "hostilemodel")
    config = load_config(write_config(folder / "run.toml", "hostilemodel", n_samples=40, seed=3))
    store = RunStore.create(folder / "run.nc", config)
    store.assimilate(decay_tables([1.2], np.linspace(0, 3, 12), 0.1, 0)[0])
    return folder / "run.nc", (folder / "run.nc").read_bytes()


def run_case(name: str, index: int, root: Path, pristine, capsys) -> tuple:
    """Generate table ``index`` of command ``name``, run it, check the properties; ``(families, exit code)``."""
    command = COMMANDS[name]
    rng = np.random.default_rng([42, index, zlib.crc32(name.encode())])
    base = (command.base(command.columns, rng) if command.base is not None
            else base_table(command.columns, rng, covariate=command.covariate, frequencies=command.values))
    table = hostile_table(base, rng)
    folder = root / f"{name}-{index}"
    folder.mkdir()
    path = write_table(table, folder / "table.csv", MAX_FILE_BYTES)
    store = None
    if command.store:
        store, content = pristine
        store.write_bytes(content)
    before = snapshot(folder)
    store_before = snapshot(store.parent) if store else {}
    code = cli.main([str(a) for a in command.argv(Case(path, folder, store))])
    out, err = capsys.readouterr()
    what = f"{name} table {index} ({', '.join(table.classes)}): exit {code}, stderr {err!r}"
    assert code in (0, 2, command.empty_code), what
    assert "Traceback" not in err and all(line.startswith(("seqbayes ", "seqbayes: warning: ")) for line in err.splitlines()), what
    after = snapshot(folder)
    for output in command.outputs:                       # written only by a result
        assert (output in after) == (code != 2), what
        after.pop(output, None)
    assert after == before, what                         # the table (or FIFO, link, sparse file) untouched
    if code == 2:
        assert len(err.splitlines()) == 1 and err.startswith(f"seqbayes {name}: error: "), what
        if store:
            assert snapshot(store.parent) == store_before, what     # the store (and its folder) unchanged
    else:                                                # a result, or (empty_code) one saying it found nothing
        assert command.result in out, what
        if store:
            assert RunStore.open(store).n_steps == 2, what
    refuses = (command.refuses if command.refuses is not None
               else set(table.classes) - {"BOM", "CRLF"} - set(command.accepts))
    if set(table.classes) & refuses:
        assert code == 2, f"expected a refusal: {what}"
    elif command.refuses is None and not set(table.classes) & set(command.accepts):
        assert code == 0, f"expected a result: {what}"
    if code == command.empty_code:
        assert code != 0 and err.strip(), what           # and it says why
    return table.families, code


def _run_all(names, n_tables, tmp_path, pristine, capsys) -> Counter:
    outcomes = Counter()
    for name in names:
        for index in range(n_tables):
            families, code = run_case(name, index, tmp_path, pristine, capsys)
            outcomes[name, code] += 1
            for family in families:
                outcomes[name, family] += 1
    return outcomes


def test_a_few_hostile_tables_end_in_a_result_or_one_line(tmp_path, pristine_store, capsys):
    """The fast tier: 6 tables per command."""
    outcomes = _run_all(COMMANDS, 6, tmp_path, pristine_store, capsys)
    assert all(outcomes[name, 2] > 0 for name in COMMANDS), outcomes


@pytest.mark.slow
def test_many_hostile_tables_per_command_end_in_a_result_or_one_line(tmp_path, pristine_store, capsys):
    """120 tables per command (``SEQBAYES_HOSTILE_TABLES=240`` runs the 240 of issue 42): the first tables of
    the same seeded sequence, in which every class is met at least 3 times per command (oma's least-met class;
    6 for update and 5 for environment, 17 and 12 in 240), so each class still meets each command several times
    in different combinations."""
    from _hostile import CLASSES

    outcomes = _run_all(COMMANDS, N_TABLES, tmp_path, pristine_store, capsys)
    for name in COMMANDS:
        # every class met at least 3 times per 120 tables of a command (the covariate's only where there is
        # one), and both outcomes: some tables are refused and some (a BOM, CRLF; for update more) give a result
        met = {f.__name__: outcomes[name, f.__name__] for f in CLASSES
               if COMMANDS[name].covariate or f.__name__ != "extreme_temperatures"}
        assert min(met.values()) >= 3 * N_TABLES // 120, (name, met)
        assert outcomes[name, 2] > 0 and outcomes[name, 0] > 0, outcomes
    print(sorted(outcomes.items(), key=str))


def test_the_generator_is_reproducible_and_combines_classes():
    from _hostile import CLASSES

    drawn = []
    for index in range(200):
        rng = np.random.default_rng([42, index, 7])
        table = hostile_table(base_table(("day", "temperature", "f1", "f2"), rng), rng)
        again = np.random.default_rng([42, index, 7])
        assert hostile_table(base_table(("day", "temperature", "f1", "f2"), again), again) == table
        drawn.append(table.families)
    assert max(map(len, drawn)) == 3 and min(map(len, drawn)) >= 1
    assert {family for families in drawn for family in families} == {f.__name__ for f in CLASSES}
