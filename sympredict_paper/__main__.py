"""``python -m sympredict_paper``: the ``sympredict-paper`` command."""

import sys

from sympredict_paper.cli import main

sys.exit(main())
