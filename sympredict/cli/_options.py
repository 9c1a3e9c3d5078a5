"""Option parsing shared by the commands: one-line parser errors and the argument types (numbers, kernels)."""

from __future__ import annotations

import argparse
import math

from sympredict._checks import as_positive_int, as_real

__all__ = []  # private to the command-line packages (sympredict.cli, sympredict_paper.cli)


class _Parser(argparse.ArgumentParser):
    """argparse with errors on one line (``prog: error: message``), exit code 2."""

    def error(self, message):
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def _checked(rule, value, **kwargs):
    """``rule(value, "value", ...)``, the library's one check of a number (:mod:`sympredict._checks`), its
    ``ValueError`` an argparse type error (argparse names the option)."""
    try:
        return rule(value, "value", **kwargs)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc).removeprefix("value ")) from None


def _int_at_least(minimum: int):
    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer >= {minimum}, got {text!r}") from None
        return _checked(as_positive_int, value, minimum=minimum)

    parse.__name__ = f"integer >= {minimum}"
    return parse


def _finite_float(positive: bool = False, nonnegative: bool = False):
    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
        return _checked(as_real, value, positive=positive, nonnegative=nonnegative)

    parse.__name__ = "number"
    return parse


def _number_list(text: str) -> str:
    """An argparse type: comma-separated finite numbers, kept as text (parsed by :func:`_parse_numbers`)."""
    try:
        _parse_numbers(text, "")
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated finite numbers, got {text!r}") from None
    return text


def _add_backend_and_force(parser: argparse.ArgumentParser, solver: str) -> None:
    """``--backend`` (``solver``: what it sets) and ``--force`` (replace an existing ``--out``) of train and predict."""
    parser.add_argument(
        "--backend",
        choices=["auto", "numpy", "numba"],
        default="auto",
        help=f"{solver}: NumPy or compiled (numba); 'auto' (default) picks by the size of the work",
    )
    parser.add_argument("--force", action="store_true", help="replace an existing --out file")


def _add_verbose(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "-v",
        "--verbose",
        action="store_true",
        help="print what is read and the training log (default: one result line)",
    )


def _parse_numbers(text: str, option: str):
    """``"1.0,0.5"`` -> array; an error naming the option and the bad entry."""
    import numpy as np

    values = []
    for i, part in enumerate(text.split(","), start=1):
        try:
            value = float(part)
        except ValueError:
            raise ValueError(
                f"{option} takes comma-separated numbers, e.g. {option} 1.0,0.0; entry {i} of {text!r} "
                f"is {part.strip()!r}"
            ) from None
        if not math.isfinite(value):
            raise ValueError(f"{option}: entry {i} of {text!r} is not finite")
        values.append(value)
    return np.array(values)


def _parse_kernel(spec: str):
    """``family:eps`` (e.g. ``imq:0.15``) -> kernel; ``none`` -> None."""
    from sympredict.kernels import KERNEL_FAMILIES

    if spec.lower() == "none":
        return None
    family, _, eps = spec.partition(":")
    if family not in KERNEL_FAMILIES or not eps:
        raise ValueError(f"kernel spec {spec!r} must be FAMILY:EPS with FAMILY in {sorted(KERNEL_FAMILIES)}, or 'none'")
    try:
        return KERNEL_FAMILIES[family](float(eps))
    except ValueError as exc:
        raise ValueError(f"kernel spec {spec!r}: {exc}") from None
