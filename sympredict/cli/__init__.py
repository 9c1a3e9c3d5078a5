"""The ``sympredict`` command: one module per subcommand (argument parsing, progress and files; no numerics here).

``data``, ``train``, ``predict`` and ``report`` work on HDF5 data sets, the user's trajectory files and models
(:mod:`~sympredict.cli.data`, :mod:`~sympredict.cli.train`, :mod:`~sympredict.cli.predict`,
:mod:`~sympredict.cli.report`); ``demo`` (:mod:`~sympredict.cli.demo`) is the README's example as one command.
The options shared by the commands are parsed in :mod:`sympredict.cli._options`.  The paper's experiments have
their own command, ``sympredict-paper`` (the package ``sympredict_paper``, beside the library).

Output paths are checked before any work, and one equal to an input path is refused.  Every error is one
line on stderr with a non-zero exit code.
"""

from __future__ import annotations

import argparse
import sys

from sympredict.cli import data, demo, predict, report, train
from sympredict.cli._console import _one_line_warning, _plain_log_output
from sympredict.cli._options import _Parser

__all__ = ["main", "build_parser"]

#: The subcommands, in the order ``sympredict --help`` lists them.
COMMANDS = (demo, data, train, predict, report)


def build_parser() -> argparse.ArgumentParser:
    from sympredict._version import __version__

    parser = _Parser(prog="sympredict", description="Symplectic large-step kernel predictors for Hamiltonian systems.")
    parser.add_argument("--version", action="version", version=f"sympredict {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)
    for command in COMMANDS:
        command.add_parser(sub)
    return parser


def main(argv=None) -> int:
    """Entry point; user errors end with one line on stderr and exit code 1, never a traceback."""
    return run_command(build_parser(), argv)


def run_command(parser: argparse.ArgumentParser, argv=None, name: str = "sympredict") -> int:
    """Parse ``argv`` with ``parser`` and run the chosen command's ``func``: the log quiet unless ``--verbose``, warnings
    on one line, a user error one line ``NAME: error: ...`` with exit code 1, Ctrl-C exit code 130."""
    import warnings

    from pymor.core.logger import set_log_levels

    from sympredict.exceptions import SympredictError

    args = parser.parse_args(argv)
    # quiet by default: the result line, warnings and errors; --verbose (where a command has it) adds the log
    set_log_levels({"sympredict": "INFO" if getattr(args, "verbose", False) else "WARN", "pymor": "WARN"})
    _plain_log_output()
    formatwarning = warnings.formatwarning
    warnings.formatwarning = _one_line_warning
    try:
        return args.func(args)
    except (ValueError, SympredictError, OSError) as exc:
        message = " ".join(str(exc).split()) or type(exc).__name__
        print(f"{name}: error: {message}", file=sys.stderr)
        return 1
    except KeyboardInterrupt as exc:
        print(f"{name}: interrupted" + (f": {exc}" if str(exc) else ""), file=sys.stderr)
        return 130
    finally:
        warnings.formatwarning = formatwarning  # main() may be called from Python (tests): leave it as found
