"""Run a page's ``seqbayes ...`` lines as fresh processes that skip the import of the package.

``tools/docgen.py`` runs every ``$ seqbayes ...`` line of the README, docs/guide.md and docs/run_store.md
as a command, and each new Python process spends most of a short command importing ``seqbayes.cli`` (1.5
CPU-s of the 2-4 s of ``seqbayes status``: ``python -c "import seqbayes.cli"`` under ``/usr/bin/time``).
:class:`Commands` starts one server process per page, which imports ``seqbayes.cli`` once and forks a
child for each command: the child is a fresh process in every other respect (its own cwd, argv, stdin
from /dev/null, stdout and stderr into one pipe with no buffering, the exit code of the console script),
so it prints what ``bash -c "seqbayes ..."`` prints. A line with anything a shell would interpret
(a pipe, a redirection, ``$(...)``, globs) still goes to bash, and so does every line when the server
does not start or printed anything while importing (a warning there would be shown by every real
process but only once here).

Run as a script, this file is the server: one JSON request per line on stdin (``{"argv": [...], "cwd":
...}``), one JSON reply per line on stdout (``{"output": ..., "code": ...}``).
"""

from __future__ import annotations

import json
import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

_PLAIN = re.compile(r"[^|&;<>()$`\\*?\[\]{}~'\"#!\n]*")


def plain_argv(line: str) -> list[str] | None:
    """The arguments of a line ``seqbayes ARGS`` that a shell would pass as they are (quotes allowed), or None."""
    try:
        words = shlex.split(line)
    except ValueError:
        return None
    unquoted = re.sub(r"'[^']*'|\"[^\"$`\\]*\"", "", line)
    if not words or words[0] != "seqbayes" or not _PLAIN.fullmatch(unquoted):
        return None
    return words[1:]


class Commands:
    """A server process that forks a ``seqbayes`` command per request (see the module docstring).

    Parameters
    ----------
    env : dict
        The commands' environment (the server's, so fixed for its life).
    cwd : Path
        The server's working folder (each request names its own).
    """

    def __init__(self, env: dict, cwd: Path):
        self._process = None
        try:
            self._process = subprocess.Popen([sys.executable, __file__], cwd=cwd, env=env, stdin=subprocess.PIPE,
                                             stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True, bufsize=1)
            ready = json.loads(self._process.stdout.readline() or "null")
        except (OSError, ValueError):
            ready = None
        if ready != {"ready": True}:
            self.close()

    @property
    def running(self) -> bool:
        return self._process is not None and self._process.poll() is None

    def run(self, argv: list[str], cwd: Path) -> tuple[str, int] | None:
        """The command's stdout and stderr together and its exit code, or None when the server is not running."""
        if not self.running:
            return None
        self._process.stdin.write(json.dumps({"argv": argv, "cwd": str(cwd)}) + "\n")
        self._process.stdin.flush()
        reply = self._process.stdout.readline()
        if not reply:
            self.close()
            return None
        reply = json.loads(reply)
        return reply["output"], reply["code"]

    def close(self) -> None:
        if self._process is not None:
            if self._process.poll() is None:
                self._process.stdin.close()
                self._process.wait(timeout=60)
            self._process.stdout.close()
            self._process = None


def _child(request: dict, write_end: int, main) -> None:
    """In the forked child: become the command's process, run it, and exit with its code."""
    import io
    import traceback

    os.chdir(request["cwd"])
    null = os.open(os.devnull, os.O_RDONLY)
    os.dup2(null, 0)
    os.dup2(write_end, 1)
    os.dup2(write_end, 2)
    os.close(null)
    os.close(write_end)
    encoding = sys.stdout.encoding
    sys.stdin = open(0, closefd=False)
    sys.stdout = io.TextIOWrapper(io.FileIO(1, "w", closefd=False), encoding=encoding, write_through=True)
    sys.stderr = io.TextIOWrapper(io.FileIO(2, "w", closefd=False), encoding=encoding, errors="backslashreplace",
                                  write_through=True)
    sys.argv = [os.path.join(os.path.dirname(sys.executable), "seqbayes"), *request["argv"]]
    try:
        code = main()
    except SystemExit as exit_:
        code = exit_.code
    except BaseException:   # as the interpreter shows an uncaught exception
        traceback.print_exc()
        code = 1
    if code is not None and not isinstance(code, int):
        print(code, file=sys.stderr)
        code = 1
    # what the interpreter does at exit, before the exit itself skips the server's loop: the exit
    # handlers (h5py closes its files there), the collection of what is left, the streams' flush
    import atexit
    import gc

    atexit._run_exitfuncs()
    gc.collect()
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code or 0)


def _serve() -> None:
    # the console script's sys.path: its own folder first, not this file's (nor the working folder)
    import contextlib
    import io

    sys.path[0] = os.path.dirname(sys.executable)
    printed = io.StringIO()
    with contextlib.redirect_stderr(printed), contextlib.redirect_stdout(printed):
        from seqbayes.cli import main
    out = sys.stdout
    print(json.dumps({"ready": not printed.getvalue()}), file=out, flush=True)
    for line in sys.stdin:
        request = json.loads(line)
        read_end, write_end = os.pipe()
        pid = os.fork()
        if pid == 0:
            os.close(read_end)
            _child(request, write_end, main)
        os.close(write_end)
        with os.fdopen(read_end, "rb") as pipe:
            output = pipe.read().decode("utf-8", errors="replace")
        _, status = os.waitpid(pid, 0)
        print(json.dumps({"output": output, "code": os.waitstatus_to_exitcode(status)}), file=out, flush=True)


if __name__ == "__main__":
    _serve()
