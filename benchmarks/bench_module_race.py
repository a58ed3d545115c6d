"""Load the likelihood's module while another process rewrites it, and count the loads that ran bytes
other than those hashed.

A child process rewrites ``racemodel.py`` every 5 ms, alternating two versions (``VERSION = 1``
and ``VERSION = 2``, each padded so that a write is not one page); the parent locates the module
(:func:`seqbayes.store.modules.locate_module`, which reads and hashes it) and imports it
(:func:`~seqbayes.store.modules.load_located`) ``--loads`` times. A load ran other bytes than it hashed
when the module's ``VERSION`` is not the one whose file has the recorded hash (a torn file that
does not compile counts as a failed load, not a mismatch). Before the fix of issue 24 the module
was read again from disk for the import: 86 of 1,870 loads ran other bytes.

    python benchmarks/bench_module_race.py --loads 2000
"""

from __future__ import annotations

import argparse
import hashlib
import os
import signal
import sys
import tempfile
import time
from pathlib import Path

from seqbayes.store.modules import ConfigError, load_located, locate_module

PAD = "# " + "x" * 200 + "\n"


def version(k: int) -> bytes:
    return (f"VERSION = {k}\n" + PAD * 100 + "def loglike(theta, data):\n    return theta[:, 0] * 0\n").encode()


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--loads", type=int, default=2000)
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        file = Path(tmp) / "racemodel.py"
        file.write_bytes(version(1))
        hashes = {hashlib.sha256(version(k)).hexdigest(): k for k in (1, 2)}
        pid = os.fork()
        if pid == 0:  # pragma: no cover - the rewriting child
            k = 1
            while True:
                k = 3 - k
                with open(file, "wb") as fh:          # truncate, then write: readers may see it torn
                    fh.write(version(k))
                time.sleep(0.005)
        mismatched = failed = torn = 0
        start = time.perf_counter()
        try:
            for _ in range(args.loads):
                try:
                    source = locate_module("racemodel", tmp)
                    load_located("racemodel:loglike", source)
                except (ConfigError, SyntaxError):
                    failed += 1
                    continue
                ran = sys.modules["racemodel"].VERSION
                expected = hashes.get(source.sha256)
                torn += expected is None
                mismatched += expected is not None and ran != expected
        finally:
            os.kill(pid, signal.SIGKILL)
            os.waitpid(pid, 0)
    print(f"{args.loads} loads while another process rewrote the module: {mismatched} ran bytes other than the "
          f"hashed ones; {torn} hashed a torn file that still imported, {failed} failed "
          f"to import a torn file; {time.perf_counter() - start:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
