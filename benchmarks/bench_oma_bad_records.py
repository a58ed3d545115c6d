"""Bad records through ``seqbayes oma`` (issue 38 "bad records"; issue 42, the OMA items): one line each.

Every case writes a record to a temporary folder and runs the command on it; the table gives the exit
status and what the user reads on stderr (docs/oma.md, "Bad records").

Run::

    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_oma_bad_records.py
"""

from __future__ import annotations

import contextlib
import io
import os
import tempfile
from pathlib import Path

import numpy as np

from seqbayes.cli import main
from seqbayes.structural.oma import building_3d, modal_record

MODEL = building_3d(3, (2.6, 2.626, 3.6), damping=0.01, max_frequency=8.0,
                    sensors=[(3, "A", "X"), (3, "A", "Y"), (2, "B", "X"), (2, "A", "Y")])


def cases(folder: Path):
    y = modal_record(MODEL, 300.0, 0.05, rng=np.random.default_rng(7))
    fast = modal_record(MODEL, 300.0, 0.005, rng=np.random.default_rng(8))

    def npy(name, array):
        path = folder / f"{name}.npy"
        np.save(path, array)
        return str(path)

    timed = folder / "timed.csv"
    np.savetxt(timed, np.column_stack([np.arange(len(y)) * 0.05, y]), delimiter=",", header="time,a,b,c,d",
               comments="", fmt="%.8g")
    nan = y.copy()
    nan[100, 2] = np.nan
    fifo = folder / "pipe.csv"
    os.mkfifo(fifo)
    return [
        ("constant record", [npy("constant", np.full_like(y, 3.0)), "--fs", "20"]),
        ("one constant channel", [npy("flat", np.column_stack([y[:, :3], np.full(len(y), 2.0)])), "--fs", "20"]),
        ("NaN", [npy("nan", nan), "--fs", "20"]),
        ("too short for the band (30 s, band from 1 Hz)", [npy("short", y[:600]), "--fs", "20", "--band", "1,8"]),
        ("too short (2 s)", [npy("tiny", y[:40]), "--fs", "20"]),
        ("one channel", [npy("one", y[:, 0]), "--fs", "20"]),
        ("transposed (p, T)", [npy("transposed", y.T), "--fs", "20"]),
        ("wrong sampling rate (time column says 20 Hz)", [str(timed), "--fs", "40"]),
        ("dt = 1e-300", [npy("ok", y), "--dt", "1e-300"]),
        ("amplitude 1e200", [npy("huge", y * 1e200), "--fs", "20"]),
        ("aliased (200 Hz record, every 10th sample, stated 20 Hz)", [npy("aliased", fast[::10]), "--fs", "20"]),
        ("white noise, band 1-6 Hz", [npy("noise", np.random.default_rng(3).standard_normal((6000, 3))), "--fs", "20",
                                       "--band", "1,6"]),
        ("a FIFO as the record", [str(fifo), "--fs", "20"]),
        ("the output is the record", [str(timed), "--fs", "20", "--out", str(timed)]),
    ]


def main_(argv=None):
    print("| record | exit | what the user reads (stderr) |")
    print("|---|---|---|")
    with tempfile.TemporaryDirectory() as folder:
        for name, argv in cases(Path(folder)):
            err, out = io.StringIO(), io.StringIO()
            with contextlib.redirect_stderr(err), contextlib.redirect_stdout(out):
                code = main(["oma", *argv])
            lines = [line.replace(folder + "/", "") for line in err.getvalue().splitlines() if line.strip()]
            shown = "<br>".join(lines) if lines else f"(none; {out.getvalue().splitlines()[-1]})"
            print(f"| {name} | {code} | {shown} |")


if __name__ == "__main__":
    main_()
