"""HDF5 container files: safe atomic writing and hostile-input reading.

Layout (schema version :data:`SCHEMA_VERSION`)::

    /                      attrs: format, schema_version, package_version, checksum, settings
    /arrays/<name>         the arrays (float / int / bool), exactly as in memory, contiguous, unfiltered

``format`` names what the file holds (``'sympredict-model'``,
``'sympredict-dataset'``); ``settings`` is JSON.  Nothing else is written.

Integrity
    Schema 2: ``checksum`` is the SHA-256 of ``format``, ``schema_version``,
    ``package_version``, the settings JSON and every array's name, dtype,
    shape and bytes (each piece length-prefixed).  Schema 1 files (written
    before) carry the SHA-256 of the arrays only; they are still read.  The
    checksum detects damage, not tampering: anyone can recompute it.

Writing (:func:`write_container`)
    The whole HDF5 image is built in memory (``io.BytesIO``; no timestamps, so
    the same settings and arrays give the same bytes), then written with
    ``os.write`` + ``fsync`` to a hidden temporary sibling
    ``.NAME.PID-XXXXXXXX.tmp`` (``.sp-HASH.PID-XXXXXXXX.tmp``, ``HASH`` 16 hex
    digits of the name's SHA-256, when that would exceed the file system's
    name limit: every valid name can be saved) and renamed over the target.  A failed write
    (disk full, quota, I/O error) raises one :class:`OSError` and leaves the
    previous file untouched; the temporary file is removed on every exit path
    Python sees (exceptions, Ctrl-C).  A kill -9 can still leave one: the next
    save to the same target removes temporary files of that target that match
    the naming pattern, are older than :data:`STALE_GRACE_S` and whose owner
    process is gone (or that are older than :data:`STALE_MAX_AGE_S`, for pid
    reuse and other hosts), plus the ``.NAME.XXXXXXXX.tmp`` files of the
    former ``mkstemp`` naming older than :data:`STALE_MAX_AGE_S`.
    A symlink is written through (the link stays, its target is replaced
    atomically); a path that is a directory, FIFO, device or socket is refused
    with :class:`ValueError`.  New files get ``0666 & ~umask``; an overwritten
    file keeps its permission bits (not its owner).

Reading (:func:`read_container`)
    The file is hostile input.  It must be a regular file (checked on the open
    descriptor, opened non-blocking, so a FIFO or device never hangs).  Before
    any data is read, the structure must be exactly what the writer writes:
    the five root attributes (scalars of the right types), one group
    ``arrays`` without attributes holding only hard-linked datasets without
    attributes, of numeric dtype, contiguous (or compact) layout, no filters
    (compression), no external storage, not virtual, and each dataset's
    declared size must equal its allocated storage and lie inside the file.
    Soft and external links are never followed.  The schema version must be
    an integer in ``1..SCHEMA_VERSION``.  Everything wrong raises
    :class:`~sympredict.exceptions.ModelFileError` naming the problem, never a
    raw h5py, NumPy or Python error.

This module knows nothing of models: the estimators turn themselves into
``(settings, arrays)`` and back (:mod:`sympredict.estimators.predictor`), and
:mod:`sympredict.io` names the formats.
"""

from __future__ import annotations

import contextlib
import errno
import hashlib
import io
import json
import os
import re
import secrets
import stat
import time
from pathlib import Path

import h5py
import numpy as np
from pymor.core.logger import getLogger

from sympredict._version import __version__
from sympredict.exceptions import ModelFileError

__all__ = [
    "SCHEMA_VERSION",
    "MAX_SETTINGS_BYTES",
    "STALE_GRACE_S",
    "STALE_MAX_AGE_S",
    "write_container",
    "atomic_output",
    "read_container",
    "check_save_path",
    "is_stale",
    "entries_matching",
]

logger = getLogger("sympredict.container")

#: Current schema; 1 = checksum over the arrays only, 2 = checksum over attributes, settings and arrays.
SCHEMA_VERSION = 2
#: A temporary file of a dead process is removed only when at least this old (seconds).
STALE_GRACE_S = 60.0
#: A temporary file this old is removed whatever its pid says (pid reuse, other hosts).
STALE_MAX_AGE_S = 24 * 3600.0

#: Largest settings JSON (an attribute in the root's object header, whose messages hold < 64 KiB).
MAX_SETTINGS_BYTES = 60000

_ROOT_ATTRS = {"format": str, "schema_version": int, "package_version": str, "checksum": str, "settings": str}
_ARRAY_KINDS = "fiub"
_COMPACT_MAX = 64 * 1024  # HDF5 limit of compact dataset storage


# --------------------------------------------------------------------------- checksums
def _checksum_v1(arrays: dict) -> str:
    """Schema 1: SHA-256 of the arrays' names, dtypes, shapes and bytes."""
    digest = hashlib.sha256()
    for name in sorted(arrays):
        arr = np.ascontiguousarray(arrays[name])
        digest.update(f"{name}|{arr.dtype.str}|{arr.shape}|".encode())
        digest.update(arr.tobytes())
    return digest.hexdigest()


def _checksum_v2(fmt: str, version: int, package_version: str, settings_json: str, arrays: dict) -> str:
    """Schema 2: SHA-256 over every attribute and every array, each piece length-prefixed."""
    digest = hashlib.sha256()

    def put(data) -> None:
        view = memoryview(data).cast("B")
        digest.update(len(view).to_bytes(8, "little"))
        digest.update(view)

    put(b"sympredict-container")
    for text in (fmt, str(int(version)), package_version, settings_json):
        put(text.encode())
    for name in sorted(arrays):
        arr = _c_order(arrays[name])
        put(name.encode())
        put(arr.dtype.str.encode())
        put(repr(tuple(arr.shape)).encode())
        put(arr.reshape(-1).view(np.uint8) if arr.size else b"")
    return digest.hexdigest()


def _c_order(arr) -> np.ndarray:
    """``arr`` as a C-contiguous array of the same shape (``np.ascontiguousarray`` makes 0-d arrays 1-d)."""
    arr = np.asarray(arr)
    return arr if arr.flags.c_contiguous else arr.copy(order="C")


# --------------------------------------------------------------------------- writing
def _image(fmt: str, settings_json: str, arrays: dict) -> bytes:
    """The complete HDF5 file as bytes (deterministic: no timestamps, fixed order)."""
    buffer = io.BytesIO()
    with h5py.File(buffer, "w") as f:
        # fixed-length strings, stored in the object header: variable-length ones live in
        # HDF5's global heap, whose damaged copies can hang HDF5's reader
        f.attrs["format"] = _fixed_string(fmt)
        f.attrs["schema_version"] = np.int64(SCHEMA_VERSION)
        f.attrs["package_version"] = _fixed_string(__version__)
        f.attrs["checksum"] = _fixed_string(_checksum_v2(fmt, SCHEMA_VERSION, __version__, settings_json, arrays))
        f.attrs["settings"] = _fixed_string(settings_json)
        grp = f.create_group("arrays")
        for name, arr in arrays.items():
            grp.create_dataset(name, data=arr, track_times=False)
    return buffer.getvalue()


def _fixed_string(text: str) -> np.ndarray:
    data = text.encode("ascii")
    return np.array(data, dtype=f"S{max(1, len(data))}")


def _checked_arrays(arrays: dict) -> dict:
    out = {}
    for name, arr in arrays.items():
        if not isinstance(name, str) or not name or "/" in name or name in (".", ".."):
            raise ValueError(f"array name {name!r} must be a non-empty string without '/'")
        arr = _c_order(arr)
        if arr.dtype.kind not in _ARRAY_KINDS:
            raise ValueError(f"array {name!r} must be numeric (float, int or bool), got dtype {arr.dtype}")
        out[name] = arr
    return out


def _target(path: Path) -> tuple[Path, os.stat_result | None]:
    """The file to replace (symlinks resolved) and its stat, or None if new; ValueError if unusable."""
    if os.path.islink(path):
        real = Path(os.path.realpath(path))
        if os.path.islink(real):  # a loop: realpath gives up on it
            raise ValueError(f"{str(path)!r} is a symbolic link that cannot be resolved (a loop?)")
    else:
        real = path
    try:
        st = os.stat(real)
    except FileNotFoundError:
        st = None
    except OSError as exc:
        raise ValueError(f"cannot save to {str(path)!r}: {exc.strerror}") from None
    if st is not None:
        if stat.S_ISDIR(st.st_mode):
            raise ValueError(f"path {str(path)!r} is a directory; give a file name such as model.h5")
        if not stat.S_ISREG(st.st_mode):
            kind = _kind(st.st_mode)
            raise ValueError(f"refusing to save to {str(path)!r}: it is a {kind}, not a regular file")
    directory = real.parent if str(real.parent) else Path(".")
    if not directory.is_dir():
        raise ValueError(f"directory {str(directory)!r} does not exist")
    return real, st


def check_save_path(path, *, writable: bool = False) -> Path:
    """Check that ``path`` can take a saved file, before any work; returns it with symlinks resolved.

    Parameters
    ----------
    writable
        Also check that the folder can take new files (``os.access``; the
        temporary sibling is created there).

    Raises
    ------
    ValueError
        ``path`` is a directory, FIFO, device or socket, an unresolvable
        symlink, its directory does not exist (or is not writable), or its
        name is longer than the file system allows.
    """
    path = Path(path)
    parent = path.parent if path.parent.is_dir() else Path(".")
    limit, size = _name_max(parent), len(os.fsencode(path.name))
    if size > limit:
        raise ValueError(
            f"the file name {path.name[:40]!r}... is {size} bytes long; the file system allows {limit}: "
            "give a shorter name"
        )
    target = _target(path)[0]
    directory = target.parent if str(target.parent) else Path(".")
    if writable and not os.access(directory, os.W_OK | os.X_OK):
        raise ValueError(f"no permission to create files in {str(directory)!r}")
    return target


def _name_max(directory: Path) -> int:
    """The longest file name (bytes) the file system of ``directory`` takes (255 where it cannot be asked)."""
    try:
        return int(os.pathconf(directory if str(directory) else ".", "PC_NAME_MAX"))
    except (OSError, ValueError, AttributeError):
        return 255


def _temp_stem(directory: Path, name: str) -> str:
    """The part of the temporary file name that names the target: the name, or a hash where it would not fit."""
    longest = len(os.fsencode(f".{name}.")) + 10 + 1 + 8 + len(".tmp")  # pid up to 10 digits
    if longest <= _name_max(directory):
        return name
    return "sp-" + hashlib.sha256(os.fsencode(name)).hexdigest()[:16]


def _kind(mode: int) -> str:
    for test, name in (
        (stat.S_ISFIFO, "FIFO"),
        (stat.S_ISCHR, "character device"),
        (stat.S_ISBLK, "block device"),
        (stat.S_ISSOCK, "socket"),
        (stat.S_ISDIR, "directory"),
    ):
        if test(mode):
            return name
    return "special file"


def _temp_pattern(name: str) -> re.Pattern:
    return re.compile(r"\." + re.escape(name) + r"\.(?:(?P<pid>\d+)-[0-9a-f]{8}|[a-z0-9_]{8})\.tmp")


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OverflowError, ValueError):
        return True  # exists (another user's), or not a pid we can judge: keep the file
    return True


def is_stale(pid, mtime: float, now: float | None = None) -> bool:
    """Whether a temporary file or folder of ours may be removed (the rule of the module docstring).

    Parameters
    ----------
    pid : int or None
        The owner's process id from the name (None for names without one).
    mtime : float
        Its modification time (seconds since the epoch).
    """
    age = (time.time() if now is None else now) - mtime
    dead = pid is not None and not _pid_alive(int(pid))
    return age >= STALE_MAX_AGE_S or (dead and age >= STALE_GRACE_S)


def entries_matching(directory, pattern: re.Pattern) -> list:
    """``(entry, match)`` for the entries of ``directory`` whose whole name matches ``pattern``; none if it cannot be listed."""
    try:
        entries = list(os.scandir(directory))
    except OSError:
        return []
    return [(entry, match) for entry in entries if (match := pattern.fullmatch(entry.name)) is not None]


def _remove_stale_temps(directory: Path, name: str) -> None:
    """Remove our own temporary files of ``name`` left by killed saves (see the module docstring)."""
    pattern = _temp_pattern(_temp_stem(directory, name))
    now = time.time()
    for entry, match in entries_matching(directory, pattern):
        try:
            st = entry.stat(follow_symlinks=False)
        except OSError:
            continue
        if not stat.S_ISREG(st.st_mode):
            continue
        pid = match.group("pid")
        if is_stale(None if pid is None else int(pid), st.st_mtime, now):
            try:
                os.unlink(entry.path)
                logger.info(f"removed stale temporary file {entry.path} (left by an interrupted save)")
            except OSError:
                pass


def _write_all(fd: int, data: bytes) -> None:
    view = memoryview(data)
    while view:
        written = os.write(fd, view)
        if written <= 0:
            raise OSError(errno.EIO, "write returned 0 bytes")
        view = view[written:]


@contextlib.contextmanager
def atomic_output(path, *, overwrite: bool = True):
    """Write a file atomically: a binary file object on a hidden temporary sibling, renamed over ``path`` at the end.

    The one way the package writes its outputs (model and data files, trajectories, reports).  On a clean exit of
    the ``with`` block the temporary file is flushed, ``fsync``-ed and renamed over ``path`` (the folder is then
    ``fsync``-ed); on any exception, Ctrl-C included, it is removed and ``path`` is left as it was.  The naming and
    the clean-up of temporary files left by killed processes are those of the module docstring; a symlink is
    written through.

    Parameters
    ----------
    path : str or path-like
        The target file.
    overwrite : bool
        ``True``: replace an existing file (the last of two concurrent writers wins, each file whole).
        ``False``: the file must not exist, checked when it is published (a hard link, which fails if the name
        exists): of two concurrent writers one gets :class:`FileExistsError`, never both "win".

    Yields
    ------
    file object
        Opened ``"wb"``; write the whole content.

    Raises
    ------
    ValueError
        An unusable path (directory, FIFO, device, missing folder).
    FileExistsError
        ``overwrite=False`` and ``path`` exists (before or after the content was written).
    OSError
        The write failed (disk full, file size limit, permissions, I/O error): ``could not save PATH: REASON;
        the previous file, if any, is unchanged``.
    KeyboardInterrupt
        Re-raised with a message naming the file that was not written.
    """
    path = Path(path)
    target, st = _target(path)
    if not overwrite and st is not None:
        raise FileExistsError(
            errno.EEXIST,
            f"{str(path)!r} exists: not replaced (pass overwrite=True, or --force on the command line, to replace it)",
        )
    _remove_stale_temps(target.parent, target.name)
    tmp = target.parent / f".{_temp_stem(target.parent, target.name)}.{os.getpid()}-{secrets.token_hex(4)}.tmp"
    fh = None
    try:
        fd = os.open(
            tmp,
            os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_CLOEXEC", 0),
            0o666,
        )
        fh = os.fdopen(fd, "wb")
        if st is not None:
            os.fchmod(fd, stat.S_IMODE(st.st_mode))
        yield fh
        fh.flush()
        os.fsync(fh.fileno())
        fh.close()
        if overwrite:
            os.replace(tmp, target)
        else:
            _publish_new(tmp, target, path)
    except BaseException as exc:
        if fh is not None:
            try:
                fh.close()
            except OSError:
                pass
        try:
            os.unlink(tmp)
        except OSError:
            pass
        if isinstance(exc, FileExistsError) and str(path) in str(exc):
            raise
        if isinstance(exc, OSError):
            reason = exc.strerror or str(exc)
            raise OSError(
                exc.errno, f"could not save {str(path)!r}: {reason}; the previous file, if any, is unchanged"
            ) from None
        if isinstance(exc, KeyboardInterrupt):
            raise KeyboardInterrupt(f"{str(path)!r} was not written; the previous file, if any, is unchanged") from None
        raise
    _fsync_directory(target.parent)


def _publish_new(tmp: Path, target: Path, path: Path) -> None:
    """Give the written ``tmp`` the name ``target`` only if no file has it (a hard link fails on an existing name)."""
    try:
        os.link(tmp, target, follow_symlinks=False)
    except FileExistsError:
        raise FileExistsError(
            errno.EEXIST,
            f"{str(path)!r} was created by someone else while this file was written: "
            f"not replaced (pass overwrite=True, or --force, to replace it)",
        ) from None
    except OSError as exc:
        if exc.errno not in (errno.EPERM, errno.ENOTSUP, errno.EOPNOTSUPP, errno.EXDEV, errno.EMLINK):
            raise
        # a file system without hard links: claim the name first (O_EXCL), then rename over the claim
        try:
            os.close(os.open(target, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_NOFOLLOW", 0), 0o666))
        except FileExistsError:
            raise FileExistsError(
                errno.EEXIST,
                f"{str(path)!r} was created by someone else while this file was "
                f"written: not replaced (pass overwrite=True, or --force)",
            ) from None
        os.replace(tmp, target)
        return
    os.unlink(tmp)


def write_container(path, fmt: str, settings: dict, arrays: dict, *, overwrite: bool = True) -> None:
    """Write a container file atomically (see the module docstring for the guarantees).

    Parameters
    ----------
    path : str or path-like
        Target file; a symlink is written through.
    fmt : str
        Format name stored in the ``format`` attribute.
    settings : dict
        JSON-serializable settings.
    arrays : dict of str -> ndarray
        Numeric arrays (float, int or bool), any shapes.
    overwrite : bool
        Replace an existing file (default); ``False`` refuses one, also one created meanwhile
        (:func:`atomic_output`).

    Raises
    ------
    ValueError
        Unusable path (directory, FIFO, device, missing directory) or settings
        that are not JSON-serializable / arrays that are not numeric.
    OSError
        The write failed (disk full, permissions, I/O error); the previous file is unchanged.

    Notes
    -----
    Memory: the file image (about the arrays' size) is held once in memory.
    """
    path = Path(path)
    try:
        settings_json = json.dumps(settings)  # ASCII (ensure_ascii)
    except (TypeError, ValueError) as exc:
        raise ValueError(
            f"settings must be JSON-serializable (plain str, int, float, bool, list, dict): {exc}"
        ) from None
    if len(settings_json) > MAX_SETTINGS_BYTES:
        raise ValueError(
            f"settings take {len(settings_json)} bytes as JSON, at most {MAX_SETTINGS_BYTES} fit in the file header"
        )
    if not isinstance(fmt, str) or not fmt.isascii() or not fmt:
        raise ValueError(f"fmt must be a non-empty ASCII string, got {fmt!r}")
    arrays = _checked_arrays(arrays)
    _target(path)
    image = _image(fmt, settings_json, arrays)
    with atomic_output(path, overwrite=overwrite) as fh:
        _write_all(fh.fileno(), image)


def _fsync_directory(directory: Path) -> None:
    """Make the rename durable (best effort: not every platform can open a directory)."""
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


# --------------------------------------------------------------------------- reading
def _open_regular(path: Path):
    """A binary file object of ``path`` if it is a regular file (never blocks on FIFOs); and its size."""
    try:
        fd = os.open(
            path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_NOCTTY", 0) | getattr(os, "O_CLOEXEC", 0)
        )
    except FileNotFoundError:
        raise ModelFileError(f"{str(path)!r} does not exist or is not a file") from None
    except OSError as exc:
        raise ModelFileError(f"{str(path)!r} cannot be opened: {exc.strerror}") from None
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise ModelFileError(f"{str(path)!r} is a {_kind(st.st_mode)}, not a regular file: refusing to read it")
        return os.fdopen(fd, "rb"), st.st_size
    except BaseException:
        os.close(fd)
        raise


def _scalar_attr(f, name: str, path: Path, file_size: int, allow_vlen: bool = False):
    """Root attribute ``name``, checked to be a scalar of the writer's type and size, before reading it.

    Variable-length strings (schema 1 only, ``allow_vlen``) must have passed
    :func:`_check_global_heaps` first.
    """
    aid = h5py.h5a.open(f.id, name.encode())
    if aid.shape != ():
        raise ModelFileError(f"{str(path)!r}: attribute {name!r} must be a scalar, has shape {aid.shape}")
    want = _ROOT_ATTRS[name]
    info = h5py.check_string_dtype(aid.dtype)
    if want is str and info is None:
        raise ModelFileError(f"{str(path)!r}: attribute {name!r} must be a string, has type {aid.dtype}")
    if want is int and (info is not None or aid.dtype.kind not in "iu"):
        raise ModelFileError(f"{str(path)!r}: attribute {name!r} must be an integer, has type {aid.dtype}")
    if info is not None and info.length is None and not allow_vlen:
        raise ModelFileError(
            f"{str(path)!r}: attribute {name!r} is a variable-length string, which this schema never writes"
        )
    if aid.dtype.itemsize > file_size or aid.get_storage_size() > file_size:
        raise ModelFileError(f"{str(path)!r}: attribute {name!r} declares more bytes than the file has")
    value = f.attrs[name]
    if want is str:
        if isinstance(value, bytes):
            value = value.decode("ascii")
        if not isinstance(value, str):
            raise ModelFileError(f"{str(path)!r}: attribute {name!r} must be a string")
        return value
    return int(value)


def _check_global_heaps(fh, file_size: int, path: Path) -> None:
    """Check every HDF5 global heap collection in the file before HDF5 parses one (schema 1 files).

    HDF5 reads variable-length strings from global heap collections (signature
    ``GCOL``); its parser loops forever on an object of size 0 and trusts the
    sizes it finds.  Every ``GCOL`` occurrence (HDF5 checks the signature at the
    address it follows, so a collection it can read is among them) must have
    version 1, lie inside the file, and its objects must tile it: each
    advances, none crosses the end.  ``O(file size)``.
    """
    fh.seek(0)
    data = fh.read(file_size)
    start = data.find(b"GCOL")
    while start >= 0:
        problem = None
        if start + 16 > len(data) or data[start + 4] != 1:
            problem = "header"
        else:
            size = int.from_bytes(data[start + 8 : start + 16], "little")
            end = start + size
            if size < 16 or end > len(data):
                problem = f"size {size}"
            p = start + 16
            while problem is None and p + 16 <= end:
                index = int.from_bytes(data[p : p + 2], "little")
                obj = int.from_bytes(data[p + 8 : p + 16], "little")
                need = obj if index == 0 else 16 + (obj + 7) // 8 * 8
                if need <= 0 or p + need > end:
                    problem = f"object {index} of size {obj}"
                p += max(need, 1)
        if problem is not None:
            raise ModelFileError(
                f"{str(path)!r} is damaged: global heap collection at byte {start} is invalid ({problem})"
            )
        start = data.find(b"GCOL", start + 1)
    fh.seek(0)


def _check_version(f, path: Path, file_size: int) -> int:
    if "schema_version" not in f.attrs:
        raise ModelFileError(f"{str(path)!r} has no schema_version attribute")
    version = _scalar_attr(f, "schema_version", path, file_size)
    if version > SCHEMA_VERSION:
        try:  # only a fixed-length string is read here (no heap access in a file we cannot check)
            writer = f"sympredict {_scalar_attr(f, 'package_version', path, file_size)}"
        except Exception:
            writer = "a newer sympredict"
        raise ModelFileError(
            f"{str(path)!r} has schema version {version}, written by {writer}; "
            f"this sympredict reads up to version {SCHEMA_VERSION}: upgrade sympredict"
        )
    if version < 1:
        raise ModelFileError(f"{str(path)!r} has an invalid schema version {version} (valid: 1..{SCHEMA_VERSION})")
    return version


def _checked_datasets(f, path: Path, file_size: int) -> dict:
    """The datasets of ``/arrays``, after checking links, layout, filters and declared sizes."""
    names = list(f.keys())
    if names != ["arrays"]:
        extra = sorted(set(names) - {"arrays"})
        raise ModelFileError(
            f"{str(path)!r} contains objects the writer never writes: {extra[:5]}"
            if extra
            else f"{str(path)!r} has no 'arrays' group"
        )
    link = f.get("arrays", getlink=True)
    if not isinstance(link, h5py.HardLink):
        raise ModelFileError(f"{str(path)!r}: 'arrays' is a {type(link).__name__}, links are refused")
    grp = f["arrays"]
    if not isinstance(grp, h5py.Group):
        raise ModelFileError(f"{str(path)!r}: 'arrays' is not a group")
    if len(grp.attrs):
        raise ModelFileError(
            f"{str(path)!r}: group 'arrays' has attributes the writer never writes: {list(grp.attrs)[:5]}"
        )
    datasets, total = {}, 0
    for name in grp.keys():
        where = f"{str(path)!r}: array {name!r}"
        link = grp.get(name, getlink=True)
        if not isinstance(link, h5py.HardLink):
            raise ModelFileError(f"{where} is a {type(link).__name__}; soft and external links are refused")
        ds = grp[name]
        if not isinstance(ds, h5py.Dataset):
            raise ModelFileError(f"{where} is not a dataset")
        if len(ds.attrs):
            raise ModelFileError(f"{where} has attributes the writer never writes")
        dcpl = ds.id.get_create_plist()
        layout = dcpl.get_layout()
        if layout == h5py.h5d.VIRTUAL or ds.is_virtual:
            raise ModelFileError(f"{where} is a virtual dataset (data in other files): refused")
        if dcpl.get_external_count() or ds.external:
            raise ModelFileError(f"{where} uses external storage (data in other files): refused")
        if dcpl.get_nfilters():
            raise ModelFileError(
                f"{where} is compressed or filtered ({ds.compression or 'filter'}); the writer never filters: refused"
            )
        if layout not in (h5py.h5d.CONTIGUOUS, h5py.h5d.COMPACT):
            raise ModelFileError(f"{where} has a chunked or unknown layout; the writer writes contiguous data: refused")
        if ds.shape is None:
            raise ModelFileError(f"{where} has no dataspace")
        dtype = ds.dtype
        if (
            dtype.kind not in _ARRAY_KINDS
            or dtype.itemsize > 8
            or dtype.fields is not None
            or dtype.subdtype is not None
        ):
            raise ModelFileError(f"{where} has dtype {dtype}; only numeric arrays are written")
        nbytes = int(np.prod([int(n) for n in ds.shape], dtype=object)) * dtype.itemsize
        storage = int(ds.id.get_storage_size())
        if nbytes > file_size or storage != nbytes:
            raise ModelFileError(
                f"{where} declares shape {ds.shape} ({nbytes} bytes) but stores {storage} bytes in a file of {file_size} bytes"
            )
        if layout == h5py.h5d.CONTIGUOUS and nbytes:
            offset = ds.id.get_offset()
            if offset is None or offset + nbytes > file_size:
                raise ModelFileError(
                    f"{where} points outside the file (offset {offset}, {nbytes} bytes, file {file_size} bytes)"
                )
        elif layout == h5py.h5d.COMPACT and nbytes > _COMPACT_MAX:
            raise ModelFileError(f"{where}: compact storage of {nbytes} bytes is impossible")
        total += nbytes
        if total > file_size:
            raise ModelFileError(
                f"{str(path)!r}: its arrays declare {total} bytes, more than the file's {file_size} bytes"
            )
        datasets[name] = ds
    return datasets


def read_container(path, fmt: str):
    """Read a container file written by :func:`write_container`, checking everything first.

    Parameters
    ----------
    path : str or path-like
    fmt : str
        Expected format name.

    Returns
    -------
    settings : dict
    arrays : dict of str -> ndarray

    Raises
    ------
    ModelFileError
        Missing, special, foreign, damaged, newer, inconsistent or unsafe file (the message says which).

    Notes
    -----
    Reads the file once; memory about the arrays' size.
    """
    path = Path(path)
    fh, file_size = _open_regular(path)
    try:
        with fh, h5py.File(fh, "r") as f:
            if "format" not in f.attrs:
                raise ModelFileError(f"{str(path)!r} is an HDF5 file but not a sympredict file (no 'format' attribute)")
            version = _check_version(f, path, file_size)
            if version == 1:  # written with variable-length strings: check the heaps HDF5 will parse
                _check_global_heaps(fh, file_size, path)
            found = _scalar_attr(f, "format", path, file_size, allow_vlen=version == 1)
            if found != fmt:
                raise ModelFileError(f"{str(path)!r} is a {found!r} file, expected {fmt!r}")
            names = set(f.attrs.keys())
            if names != set(_ROOT_ATTRS):
                extra, missing = sorted(names - set(_ROOT_ATTRS)), sorted(set(_ROOT_ATTRS) - names)
                raise ModelFileError(
                    f"{str(path)!r} has unexpected root attributes {extra[:5]}"
                    if extra
                    else f"{str(path)!r} lacks the attributes {missing}"
                )
            attrs = {name: _scalar_attr(f, name, path, file_size, allow_vlen=version == 1) for name in _ROOT_ATTRS}
            datasets = _checked_datasets(f, path, file_size)
            arrays = {name: ds[()] for name, ds in datasets.items()}
    except ModelFileError:
        raise
    except Exception as exc:  # h5py/HDF5/NumPy on a damaged structure: RuntimeError, OSError, KeyError, ...
        raise ModelFileError(
            f"{str(path)!r} cannot be read as a sympredict file (truncated or corrupted?): {type(exc).__name__}: {exc}"
        ) from None
    if version == 1:
        expected = _checksum_v1(arrays)
    else:
        expected = _checksum_v2(attrs["format"], version, attrs["package_version"], attrs["settings"], arrays)
    if expected != attrs["checksum"]:
        covered = "arrays" if version == 1 else "settings or arrays"
        raise ModelFileError(f"{str(path)!r} is corrupted: its {covered} do not match the stored checksum")
    try:
        settings = json.loads(attrs["settings"])
    except (ValueError, RecursionError) as exc:
        raise ModelFileError(f"{str(path)!r}: its settings are not valid JSON: {exc}") from None
    if not isinstance(settings, dict):
        raise ModelFileError(f"{str(path)!r}: its settings are not a JSON object")
    return settings, arrays
