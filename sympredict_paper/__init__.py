"""The paper's code, beside the library (as pyMOR keeps ``pymordemos``): scenarios as functions returning results
(numbers and arrays, no figures), the report and its figures, the runner and the studies.

The library ``sympredict`` never imports this package (an import-linter contract).  Its command is
``sympredict-paper`` (:mod:`sympredict_paper.cli`): ``sympredict-paper run pendulum --quick --out DIR`` runs a
scenario, ``sympredict-paper study NAME`` a study; each scenario module has its own ``main``
(``python -m sympredict_paper.pendulum --quick --out DIR``).
"""

from __future__ import annotations

import sys
from typing import Callable


def scenario_main(scenario: str) -> Callable:
    """The ``main`` of a scenario module: ``main(argv)`` is ``sympredict-paper run SCENARIO ARGV`` (``argv`` by
    default the process's arguments); returns the command's exit status."""

    def main(argv=None) -> int:
        from sympredict_paper.cli import main as paper_main  # the command imports the scenarios: import when called

        return paper_main(["run", scenario, *(sys.argv[1:] if argv is None else argv)])

    main.__doc__ = (
        f"``sympredict-paper run {scenario} [OPTIONS]``: this scenario's models, figures and summary "
        "(``--quick --out DIR``)."
    )
    return main
