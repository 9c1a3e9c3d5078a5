"""HDF5 container files: atomic writing and checked reading.

Layout (schema version :data:`SCHEMA_VERSION`)::

    /                      attrs: format, schema_version, package_version, checksum, settings
    /arrays/<name>         the arrays (float64 / int64), exactly as in memory

``format`` names what the file holds (``'sympredict-model'``,
``'sympredict-dataset'``); ``settings`` is JSON.  The checksum is the SHA-256
of the arrays' names, dtypes, shapes and bytes, so a damaged file is detected
on load.  Saving is atomic: the file is written next to the target under a
temporary name and renamed over it, so an interrupted save never destroys a
previous file.

This module knows nothing of models: the estimators turn themselves into
``(settings, arrays)`` and back (:mod:`sympredict.predictor`), and
:mod:`sympredict.io` names the formats.
"""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
from pathlib import Path

import h5py
import numpy as np

from sympredict._version import __version__
from sympredict.exceptions import ModelFileError

__all__ = ["SCHEMA_VERSION", "write_container", "read_container"]

SCHEMA_VERSION = 1


def _checksum(arrays: dict) -> str:
    digest = hashlib.sha256()
    for name in sorted(arrays):
        arr = np.ascontiguousarray(arrays[name])
        digest.update(f"{name}|{arr.dtype.str}|{arr.shape}|".encode())
        digest.update(arr.tobytes())
    return digest.hexdigest()


def write_container(path, fmt: str, settings: dict, arrays: dict) -> None:
    path = Path(path)
    if path.is_dir():
        raise ValueError(f"path {str(path)!r} is a directory; give a file name such as model.h5")
    directory = path.parent if str(path.parent) else Path(".")
    if not directory.exists():
        raise ValueError(f"directory {str(directory)!r} does not exist")
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=directory)
    os.close(fd)
    try:
        with h5py.File(tmp, "w") as f:
            f.attrs["format"] = fmt
            f.attrs["schema_version"] = SCHEMA_VERSION
            f.attrs["package_version"] = __version__
            f.attrs["checksum"] = _checksum(arrays)
            f.attrs["settings"] = json.dumps(settings)
            grp = f.create_group("arrays")
            for name, arr in arrays.items():
                grp.create_dataset(name, data=np.asarray(arr))
        with open(tmp, "rb+") as fh:
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.remove(tmp)
        raise


def read_container(path, fmt: str):
    path = Path(path)
    if not path.is_file():
        raise ModelFileError(f"{str(path)!r} does not exist or is not a file")
    try:
        with h5py.File(path, "r") as f:
            found = f.attrs.get("format")
            if found is None:
                raise ModelFileError(f"{str(path)!r} is an HDF5 file but not a sympredict file (no 'format' attribute)")
            if found != fmt:
                raise ModelFileError(f"{str(path)!r} is a {found!r} file, expected {fmt!r}")
            version = int(f.attrs["schema_version"])
            if version > SCHEMA_VERSION:
                raise ModelFileError(
                    f"{str(path)!r} has schema version {version}, written by sympredict "
                    f"{f.attrs.get('package_version')}; this sympredict reads up to version {SCHEMA_VERSION}: upgrade sympredict"
                )
            settings = json.loads(f.attrs["settings"])
            arrays = {name: ds[()] for name, ds in f["arrays"].items()}
            checksum = f.attrs["checksum"]
    except ModelFileError:
        raise
    except (OSError, KeyError, ValueError, TypeError) as exc:
        raise ModelFileError(f"{str(path)!r} cannot be read as a sympredict file (truncated or corrupted?): {exc}") from None
    if _checksum(arrays) != checksum:
        raise ModelFileError(f"{str(path)!r} is corrupted: its arrays do not match the stored checksum")
    return settings, arrays
