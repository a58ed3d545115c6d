"""``python -m seqbayes.cli``: the ``seqbayes`` command."""

import sys

from . import main

sys.exit(main())
