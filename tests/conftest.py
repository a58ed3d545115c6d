"""Puts ``tests/`` on ``sys.path`` so the test files can ``import _user_model`` whichever
``--import-mode`` pytest runs with (the default, "prepend", already does it for this file)."""

import sys
from pathlib import Path

if str(Path(__file__).parent) not in sys.path:
    sys.path.insert(0, str(Path(__file__).parent))
