"""SIGKILLs during monitor-store updates, each resumed bit for bit against an uninterrupted run: a reduced form of
benchmarks/bench_monitor_kills.py (which makes 100; docs/environment.md)."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))


@pytest.mark.slow
def test_sigkills_during_monitor_updates_resume_bit_for_bit(tmp_path):
    from bench_monitor_kills import run_kills

    out = run_kills(6, n_days=3, particles=24, folder=tmp_path)
    assert out["kills"] == 6 and out["completed_runs"] >= 1
    assert out["before_stored"] + out["after_stored"] == 6
