"""The ``sympredict-paper`` command: the paper's scenarios and studies, beside the library's ``sympredict`` command.

``sympredict-paper run pendulum|wave|henon-heiles|sine-gordon|all --quick --out DIR`` runs the paper's scenarios
(:mod:`sympredict_paper.runner`); ``sympredict-paper study NAME [ARGS ...]`` runs one of the studies in
``sympredict_paper/studies/`` (each writes the JSON the documentation renders its numbers from; its docstring
gives its options).  ``python -m sympredict_paper`` is the same command.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from sympredict.cli import run_command
from sympredict.cli._options import _Parser
from sympredict_paper import runner

__all__ = ["main", "build_parser", "STUDIES"]

#: The folder of the studies (scripts run with their folder on ``sys.path``, as ``python STUDIES/NAME.py``).
STUDIES = Path(__file__).resolve().parent / "studies"


def study_names() -> list[str]:
    """The studies that ``sympredict-paper study`` runs: the scripts of :data:`STUDIES` (helpers start with ``_``)."""
    return sorted(p.stem for p in STUDIES.glob("*.py") if not p.name.startswith("_"))


def _cmd_study(args) -> int:
    """Run the study script ``args.name`` with ``args.args`` as its command line (``python STUDIES/NAME.py ARGS``)."""
    import runpy

    script = STUDIES / f"{args.name}.py"
    argv, path = sys.argv, list(sys.path)
    sys.argv = [str(script), *args.args]
    sys.path.insert(0, str(STUDIES))
    try:
        runpy.run_path(str(script), run_name="__main__")
    except SystemExit as exc:
        return exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
    finally:
        sys.argv, sys.path[:] = argv, path
    return 0


def build_parser() -> argparse.ArgumentParser:
    from sympredict._version import __version__

    parser = _Parser(
        prog="sympredict-paper", description="The paper's experiments on sympredict: scenarios and studies."
    )
    parser.add_argument("--version", action="version", version=f"sympredict-paper {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)
    runner.add_parser(sub)
    study = sub.add_parser("study", help="run a study (its JSON goes under docs/data/; see the script's docstring)")
    study.add_argument("name", choices=study_names(), help="the study: a script of sympredict_paper/studies/")
    study.add_argument("args", nargs=argparse.REMAINDER, help="the study's own options (NAME --help lists them)")
    study.set_defaults(func=_cmd_study)
    return parser


def main(argv=None) -> int:
    """Entry point; user errors end with one line on stderr and exit code 1, never a traceback."""
    return run_command(build_parser(), argv, name="sympredict-paper")
