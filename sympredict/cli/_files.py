"""Output files of the commands: checked before any work, and a trained model never lost."""

from __future__ import annotations

import os
import secrets
from pathlib import Path

__all__ = []


def _check_output_file(out, *inputs, option: str = "--out", force=None) -> None:
    """Refuse an output file that is a directory or special file, lacks its folder (or write permission there),
    has a name longer than the file system takes, or is one of the inputs; with ``force`` given (the command's
    ``--force``), also an existing file unless it is true."""
    from sympredict.container import check_save_path

    try:
        check_save_path(out, writable=True)
    except ValueError as exc:
        raise ValueError(f"{option}: {exc}") from None
    for given in inputs:
        if given is not None and _same_file(out, given):
            raise ValueError(f"{option} {str(out)!r} is also an input ({str(given)!r}): refusing to overwrite an input")
    if force is False and (os.path.exists(out) or os.path.islink(out)):
        raise ValueError(f"{option} {str(out)!r} exists: pass --force to replace it, or give another name")


def _save_model_or_keep(model, out, overwrite: bool = True) -> None:
    """``model.save(out)``; if that fails after training, save it beside ``out`` (or in the temp folder) and say where.
    ``overwrite=False`` (no ``--force``): a file created at ``out`` meanwhile (another run) is not replaced."""
    try:
        model.save(out) if overwrite else model.save(out, overwrite=False)
        return
    except OSError as exc:
        failure = exc
    import tempfile

    name = f"sympredict-model-{os.getpid()}-{secrets.token_hex(4)}.h5"
    for folder in (Path(out).parent, Path(tempfile.gettempdir())):
        try:
            model.save(folder / name)
        except (OSError, ValueError):
            continue
        raise OSError(
            failure.errno,
            f"{failure.strerror or failure}; the trained model was kept in {str(folder / name)!r}: "
            f"move it where you want it",
        )
    raise OSError(
        failure.errno,
        f"{failure.strerror or failure}; the trained model could not be kept anywhere "
        f"(also tried {str(Path(out).parent)!r} and {tempfile.gettempdir()!r})",
    )


def _same_file(a, b) -> bool:
    try:
        return os.path.samefile(a, b)
    except OSError:
        return os.path.realpath(a) == os.path.realpath(b)
