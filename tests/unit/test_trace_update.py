"""A reader's path through one update (issue 39): a traced SEMC update under the transition mixture crosses at most
15 source files of the package (``tools/trace_update.py`` traces it with ``sys.setprofile``)."""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "tools"))

import trace_update  # noqa: E402


def test_a_semc_update_with_the_transition_mixture_crosses_at_most_15_files():
    update, root = trace_update.semc_transition_update()
    files, n_functions, switches = trace_update.traced_files(update, root)
    assert len(files) <= 15, files
    # the path it names: the driver, the core loop and likelihood, the mixture predictive, the moves
    assert {"engine/drivers.py", "core/tempering.py", "predictive/transition.py", "moves/stretch.py"} <= set(files)
    assert n_functions > 0 and switches > 0
