"""What the commands print: progress on a terminal, durations, one-line warnings and errors, plain log output."""

from __future__ import annotations

import math
import os
import sys
import time

__all__ = []  # private to the command-line packages (sympredict.cli, sympredict_paper.cli)


def _info(args, line: str) -> None:
    """A line of what the command does: printed with ``--verbose`` only (the default output is the result line)."""
    if getattr(args, "verbose", False):
        print(line, file=sys.stderr)


class _Working:
    """One line on a terminal while a long call runs (``what ...``), erased when it ends; nothing when piped."""

    def __init__(self, what: str, stream=None, quiet: bool = False):
        self.stream = stream or sys.stderr
        # not with --verbose (``quiet``): the log's lines would run into it
        self.enabled = bool(getattr(self.stream, "isatty", lambda: False)()) and not quiet
        self.what = what

    def __enter__(self):
        if self.enabled:
            self.stream.write(f"{self.what} ...")
            self.stream.flush()
        return self

    def __exit__(self, *exc):
        if self.enabled:
            self.stream.write("\r\033[K")
            self.stream.flush()
        return False


class _Progress:
    """``step k/K (p %), elapsed, left`` on one line of stderr, redrawn at most twice a second, from 1 s on.

    Only on a terminal: piped or redirected output gets no progress lines.
    """

    def __init__(self, what: str, stream=None):
        self.what, self.stream = what, stream or sys.stderr
        self.enabled = bool(getattr(self.stream, "isatty", lambda: False)())
        self.start = self.last = time.perf_counter()
        self.shown = False

    def __call__(self, done: int, total: int) -> None:
        now = time.perf_counter()
        if not self.enabled or now - self.start < 1.0 or (now - self.last < 0.5 and done < total):
            return
        self.last, elapsed = now, now - self.start
        left = elapsed * (total - done) / done if done else float("inf")
        self.stream.write(
            f"\r{self.what}: step {done:,}/{total:,} ({100 * done / total:.1f} %), "
            f"{_duration(elapsed)} elapsed, about {_duration(left)} left   "
        )
        self.stream.flush()
        self.shown = True

    def close(self) -> None:
        if self.shown:
            self.stream.write("\n")
            self.stream.flush()


def _duration(seconds: float) -> str:
    if not math.isfinite(seconds):
        return "?"
    if seconds < 60:
        return f"{seconds:.0f} s"
    if seconds < 3600:
        return f"{seconds // 60:.0f} min {seconds % 60:02.0f} s"
    return f"{seconds // 3600:.0f} h {seconds % 3600 // 60:02.0f} min"


def _use_color(stream) -> bool:
    """Colour only on a terminal, and never with ``NO_COLOR`` set (https://no-color.org)."""
    return bool(getattr(stream, "isatty", lambda: False)()) and not os.environ.get("NO_COLOR")


def _plain_log_output() -> None:
    """pyMOR's log formatter colours by the terminal type, not by where the output goes: decide here."""
    import logging

    from pymor.core.logger import ColoredFormatter

    color = _use_color(sys.stderr)
    loggers = [logging.getLogger()] + [
        lg for lg in logging.Logger.manager.loggerDict.values() if isinstance(lg, logging.Logger)
    ]
    for lg in loggers:
        for handler in lg.handlers:
            if isinstance(handler.formatter, ColoredFormatter):
                handler.formatter.use_color = color


def _one_line_warning(message, category, filename, lineno, line=None) -> str:
    """A warning as one line: ``sympredict: warning: Category: message`` (no source line, no path)."""
    return f"sympredict: warning: {category.__name__}: {' '.join(str(message).split())}\n"
