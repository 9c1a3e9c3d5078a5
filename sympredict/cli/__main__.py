"""``python -m sympredict.cli``: the ``sympredict`` command."""

import sys

from sympredict.cli import main

sys.exit(main())
