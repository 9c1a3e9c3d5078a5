"""Reading the user's trajectories and flow-map samples from ``.npz``, HDF5 and ``.csv`` files.

:func:`read_trajectories` is the one entry point; every file is treated as hostile input: shapes, dtypes,
sizes and finiteness are checked before arrays are allocated, and every error names the file, the key or
column, and the expected layout.
"""

from __future__ import annotations

import csv
import io
import re
import zipfile
from pathlib import Path
from typing import Optional

import logging

import numpy as np

from sympredict._checks import as_real_array, as_states, as_trajectories
from sympredict.container import atomic_output
from sympredict.data import FlowMapData, TrajectoryData
from sympredict.io.formats import load_dataset

__all__ = ["read_trajectories", "write_trajectories", "read_states", "LAYOUT", "MAX_BYTES"]

#: The layouts :func:`read_trajectories` accepts (quoted in its error messages).
LAYOUT = (
    "expected layout: .npz/.h5 with 'states' (P, K+1, 2n) [or (K+1, 2n) for one trajectory] and 'dt' (scalar) "
    "or 'times' (P, K+1) or (K+1,), optional 'mu' (P,) or (P, d); or pairs 'x0', 'x1' (M, 2n), 'dt' (scalar or "
    "(M,)), optional 'mu' (M,) or (M, d); .csv with a header row and columns traj, t, q1..qn, p1..pn (q, p for "
    "n = 1), optional mu or mu1..mud"
)

#: Default largest size of the numbers read from one file (bytes of float64): 4 GiB.
MAX_BYTES = 4 * 2**30

logger = logging.getLogger(__name__)

_SUFFIXES = {".npz": "npz", ".h5": "hdf5", ".hdf5": "hdf5", ".csv": "csv"}


def read_trajectories(
    path,
    *,
    states_key: str = "states",
    times_key: str = "times",
    dt_key: str = "dt",
    mu_key: str = "mu",
    max_bytes: int = MAX_BYTES,
):
    """Read trajectories (or flow-map pairs) from a ``.npz``, HDF5 (``.h5``, ``.hdf5``) or ``.csv`` file.

    Parameters
    ----------
    path : str or path-like
        The file; its suffix picks the format.
    states_key : str, default="states"
        Name of the states array in ``.npz``/HDF5 files (the pair keys are ``x0``, ``x1``).
    times_key : str, default="times"
        Name of the sample times array.
    dt_key : str, default="dt"
        Name of the uniform step.
    mu_key : str, default="mu"
        Name of the parameters array.
    max_bytes : int, default=4 * 2**30
        Largest size (float64 bytes) of the numbers read; larger declared arrays are refused before
        anything is allocated.

    Returns
    -------
    TrajectoryData or FlowMapData
        Trajectories; pairs for files that hold ``x0``/``x1``.

    Raises
    ------
    ValueError
        An unreadable, malformed or unsafe file; the message names the file, the key or column (and the
        CSV row) and the expected layout.

    Notes
    -----
    The layouts read:

    ``.npz`` and HDF5 (datasets at the file's root):

    * trajectories: ``states`` of shape ``(P, K+1, 2n)`` (or ``(K+1, 2n)``: one trajectory), states
      ordered ``(q1..qn, p1..pn)``; ``dt`` (a positive scalar, uniform steps) or ``times`` of shape
      ``(P, K+1)`` or ``(K+1,)`` (strictly increasing); optional ``mu`` of shape ``(P,)`` or ``(P, d)``;
    * pairs: ``x0`` and ``x1`` of shape ``(M, 2n)``, ``dt`` a scalar or ``(M,)``, optional ``mu``
      ``(M,)`` or ``(M, d)``;
    * a data set written by ``sympredict data`` or :func:`sympredict.io.save_dataset` (HDF5) is
      read as its pairs.

    ``.csv``: a header row, then one row per state; columns ``traj`` (trajectory label: rows of one
    trajectory need not be adjacent but must be in increasing time), ``t`` (time), the state columns
    ``q1..qn, p1..pn`` (``q``, ``p`` for ``n = 1``), optional ``mu`` or ``mu1..mud`` (constant within a
    trajectory).  All trajectories have the same number of states.
    """
    path = Path(path)
    kind = _SUFFIXES.get(path.suffix.lower())
    if kind is None:
        raise ValueError(
            f"{str(path)!r}: unknown data file type {path.suffix!r}; use .npz, .h5/.hdf5 or .csv ({LAYOUT})"
        )
    if not path.is_file():
        raise ValueError(f"{str(path)!r} does not exist or is not a regular file")
    keys = {"states": states_key, "times": times_key, "dt": dt_key, "mu": mu_key}
    if kind == "csv":
        return _read_csv(path, max_bytes)
    if kind == "npz":
        arrays = _NpzArrays(path, max_bytes)
    elif _is_sympredict_dataset(path):
        return load_dataset(path)[0]
    else:
        arrays = _Hdf5Arrays(path, max_bytes)
    with arrays:
        return _from_arrays(path, arrays, keys)


# --------------------------------------------------------------------------- arrays by key
def _where(path: Path, key: str) -> str:
    return f"{str(path)!r}, key {key!r}"


def _check_declared(path: Path, key: str, shape, dtype, budget: list) -> None:
    """Refuse non-numeric dtypes, negative, empty or overflowing shapes and sizes over the budget before reading ``key``."""
    dtype = np.dtype(dtype)
    if dtype.kind not in "fiu" or dtype.fields is not None or dtype.subdtype is not None:
        raise ValueError(f"{_where(path, key)} has dtype {dtype}; a real numeric array is expected ({LAYOUT})")
    if not isinstance(shape, tuple) or not all(
        isinstance(n, (int, np.integer)) and not isinstance(n, bool) for n in shape
    ):
        raise ValueError(
            f"{_where(path, key)} declares the shape {shape!r}: a tuple of integers is expected ({LAYOUT})"
        )
    if any(int(n) < 0 for n in shape):
        raise ValueError(
            f"{_where(path, key)} declares the shape {tuple(shape)} with a negative dimension: refused "
            f"(a damaged or crafted file); {LAYOUT}"
        )
    count = 1
    for n in shape:  # Python integers: no overflow
        count *= int(n)
    if count == 0:
        raise ValueError(f"{_where(path, key)} declares the shape {tuple(shape)}: it holds no numbers ({LAYOUT})")
    budget[0] -= max(8, dtype.itemsize) * count
    if budget[0] < 0:
        raise ValueError(
            f"{_where(path, key)} declares shape {tuple(shape)}: the arrays exceed max_bytes; "
            "pass a larger max_bytes if the file is meant to be this large"
        )


#: The compressions of ``.npz`` members read (stored, deflate, as ``np.savez``/``np.savez_compressed`` write).
_NPZ_COMPRESSIONS = {zipfile.ZIP_STORED: "stored", zipfile.ZIP_DEFLATED: "deflate"}


class _NpzArrays:
    """The arrays of an ``.npz`` file, read one by one after their headers are checked."""

    def __init__(self, path: Path, max_bytes: int):
        self.path, self.budget = path, [int(max_bytes)]
        try:
            self.zip = zipfile.ZipFile(path)
        except (zipfile.BadZipFile, OSError) as exc:
            raise ValueError(f"{str(path)!r} is not a readable .npz file: {exc}") from None
        self.members = {name[:-4]: name for name in self.zip.namelist() if name.endswith(".npy")}

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.zip.close()

    def keys(self):
        return set(self.members)

    def get(self, key: str) -> np.ndarray:
        info = self.zip.getinfo(self.members[key])
        if info.flag_bits & 0x1:
            raise ValueError(
                f"{_where(self.path, key)} is encrypted: save the arrays without a password "
                "(numpy.savez or numpy.savez_compressed)"
            )
        if info.compress_type not in _NPZ_COMPRESSIONS:
            names = {9: "Deflate64", zipfile.ZIP_BZIP2: "bzip2", zipfile.ZIP_LZMA: "LZMA"}
            method = names.get(info.compress_type, f"method {info.compress_type}")
            raise ValueError(
                f"{_where(self.path, key)} is compressed with {method}; .npz members stored or "
                "deflate-compressed are read: save with numpy.savez or numpy.savez_compressed"
            )
        try:
            with self.zip.open(info) as fh:
                version = np.lib.format.read_magic(fh)
                if version == (1, 0):
                    shape, fortran, dtype = np.lib.format.read_array_header_1_0(fh)
                elif version == (2, 0):
                    shape, fortran, dtype = np.lib.format.read_array_header_2_0(fh)
                else:
                    raise ValueError(f"unsupported .npy format version {version} (1.0 and 2.0 are read)")
                _check_declared(self.path, key, shape, dtype, self.budget)
                count = int(np.prod(shape, dtype=np.int64))
                raw = fh.read(count * dtype.itemsize + 1)
        except ValueError as exc:
            if str(self.path) in str(exc):
                raise
            raise ValueError(f"{_where(self.path, key)} is not a valid .npy array: {exc}") from None
        except (zipfile.BadZipFile, OSError, EOFError, RuntimeError, NotImplementedError, zipfile.LargeZipFile) as exc:
            raise ValueError(
                f"{_where(self.path, key)} cannot be read (truncated, corrupted or unsupported?): {exc}"
            ) from None
        if len(raw) != count * dtype.itemsize:
            raise ValueError(f"{_where(self.path, key)} declares shape {shape} but holds {len(raw)} bytes")
        arr = np.frombuffer(raw, dtype=dtype, count=count)
        return arr.reshape(shape[::-1]).T if fortran else arr.reshape(shape)


def _is_sympredict_dataset(path: Path) -> bool:
    """Whether ``path`` is an HDF5 file with the package's data-set ``format`` attribute."""
    import h5py

    try:
        with h5py.File(path, "r") as f:
            return "format" in f.attrs and "arrays" in f
    except OSError as exc:
        raise ValueError(f"{str(path)!r} is not a readable HDF5 file: {exc}") from None


class _Hdf5Arrays:
    """The root datasets of an HDF5 file, checked (storage, dtype, size) before they are read."""

    def __init__(self, path: Path, max_bytes: int):
        import h5py

        self.path, self.budget, self.h5py = path, [int(max_bytes)], h5py
        try:
            self.file = h5py.File(path, "r")
        except OSError as exc:
            raise ValueError(f"{str(path)!r} is not a readable HDF5 file: {exc}") from None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.file.close()

    def keys(self):
        return {k for k in self.file.keys() if isinstance(self.file.get(k, getlink=True), self.h5py.HardLink)}

    def get(self, key: str) -> np.ndarray:
        ds = self.file[key]
        if not isinstance(ds, self.h5py.Dataset):
            raise ValueError(f"{_where(self.path, key)} is a group, a dataset is expected ({LAYOUT})")
        if ds.is_virtual or ds.external:
            raise ValueError(f"{_where(self.path, key)} keeps its data in other files: refused")
        if ds.shape is None:
            raise ValueError(f"{_where(self.path, key)} has no dataspace")
        _check_declared(self.path, key, ds.shape, ds.dtype, self.budget)
        try:
            return np.asarray(ds[()])
        except Exception as exc:  # HDF5 on a damaged file: OSError, RuntimeError, ...
            raise ValueError(f"{_where(self.path, key)} cannot be read (truncated or corrupted?): {exc}") from None


def _real(path: Path, key: str, arr: np.ndarray) -> np.ndarray:
    return as_real_array(arr, _where(path, key))


def _from_arrays(path: Path, arrays, keys: dict):
    present = arrays.keys()
    states_key, times_key, dt_key, mu_key = keys["states"], keys["times"], keys["dt"], keys["mu"]
    if states_key in present and ("x0" in present or "x1" in present):
        raise ValueError(f"{str(path)!r} holds both {states_key!r} and pairs 'x0'/'x1': keep one ({LAYOUT})")
    mu = _real(path, mu_key, arrays.get(mu_key)) if mu_key in present else None
    if "x0" in present or "x1" in present:
        missing = [k for k in ("x0", "x1", dt_key) if k not in present]
        if missing:
            raise ValueError(f"{str(path)!r} holds pairs but lacks {missing} ({LAYOUT})")
        x0, x1, dt = (_real(path, k, arrays.get(k)) for k in ("x0", "x1", dt_key))
        for k, a in (("x0", x0), ("x1", x1)):
            as_states(a, _where(path, k), allow_single=False)
        if x1.shape != x0.shape:
            raise ValueError(f"{_where(path, 'x1')} has shape {x1.shape}, 'x0' has {x0.shape}: they must agree")
        return _named(path, lambda: FlowMapData(x0, x1, mu, dt), {"mu": mu_key, "dt": dt_key})
    if states_key not in present:
        raise ValueError(f"{str(path)!r} has no key {states_key!r} (found {sorted(present)[:10]}); {LAYOUT}")
    states = as_trajectories(arrays.get(states_key), _where(path, states_key), allow_single=True)
    has_dt, has_times = dt_key in present, times_key in present
    if has_dt == has_times:
        raise ValueError(
            f"{str(path)!r} must hold exactly one of {dt_key!r} (a uniform step) and {times_key!r} "
            f"((P, K+1) or (K+1,)), found {'both' if has_dt else 'neither'} ({LAYOUT})"
            + (
                ""
                if has_dt
                else f"; add the sampling step when saving, e.g. np.savez({Path(path).name!r}, {states_key}=states, "
                f"mu=mu, {dt_key}=0.1)"
                if str(path).lower().endswith(".npz")
                else f"; add the sampling step as a scalar data set, e.g. h5file[{dt_key!r}] = 0.1"
            )
        )
    dt = _real(path, dt_key, arrays.get(dt_key)) if has_dt else None
    if dt is not None and dt.size != 1:
        raise ValueError(
            f"{_where(path, dt_key)} must be one positive number (uniform steps; give {times_key!r} "
            f"otherwise), got shape {dt.shape}"
        )
    times = _real(path, times_key, arrays.get(times_key)) if has_times else None
    return _named(
        path,
        lambda: TrajectoryData(states, mu, None if dt is None else float(dt.reshape(-1)[0]), times),
        {"mu": mu_key, "dt": dt_key, "times": times_key},
    )


def _named(path: Path, build, names: dict):
    """``build()``, its ``ValueError`` prefixed with the file (the message names the argument)."""
    try:
        return build()
    except ValueError as exc:
        message = str(exc)
        for arg, key in names.items():
            if key != arg:
                message = re.sub(rf"\b{arg}\b", key, message)
        raise ValueError(f"{str(path)!r}: {message} ({LAYOUT})") from None


# --------------------------------------------------------------------------- CSV
def _state_columns(header: list, path: Path):
    """Indices of the state columns ``q1..qn, p1..pn`` (or ``q, p``) and of ``mu`` / ``mu1..mud``."""
    names = {name: i for i, name in enumerate(header)}
    if "q" in names or "p" in names:
        q_names, p_names = ["q"], ["p"]
    else:
        n = 0
        while f"q{n + 1}" in names:
            n += 1
        q_names, p_names = [f"q{i}" for i in range(1, n + 1)], [f"p{i}" for i in range(1, n + 1)]
    missing = [c for c in ["traj", "t", *q_names, *p_names] if c not in names]
    if not q_names or missing:
        raise ValueError(
            f"{str(path)!r}: the header lacks the column(s) {missing or ['q1', 'p1']}; got {header[:12]} ({LAYOUT})"
        )
    if "mu" in names:
        mu_names = ["mu"]
    else:
        d = 0
        while f"mu{d + 1}" in names:
            d += 1
        mu_names = [f"mu{i}" for i in range(1, d + 1)]
    known = {"traj", "t", *q_names, *p_names, *mu_names}
    unknown = [c for c in header if c not in known]
    if unknown:
        raise ValueError(
            f"{str(path)!r}: unexpected column(s) {unknown[:5]} (for 2n = {2 * len(q_names)} states and "
            f"{len(mu_names)} parameter(s)); {LAYOUT}"
        )
    if len(header) != len(names):
        raise ValueError(f"{str(path)!r}: the header repeats a column name: {header[:12]}")
    return names, [names[c] for c in ["t", *q_names, *p_names, *mu_names]], len(q_names), len(mu_names)


#: Longest CSV line read (characters); a longer line is refused before it is split into cells.
MAX_CSV_LINE = 1 << 20
#: Rows parsed into one NumPy block at a time while a CSV file is streamed.
_CSV_BLOCK = 4096


def _csv_lines(fh, path: Path):
    """The lines of ``fh``, each refused if longer than :data:`MAX_CSV_LINE` (memory per line stays bounded)."""
    while True:
        line = fh.readline(MAX_CSV_LINE + 1)
        if not line:
            return
        if len(line) > MAX_CSV_LINE:
            raise ValueError(
                f"{str(path)!r}: a line is longer than {MAX_CSV_LINE} characters; one row per state, "
                "with short cells, is expected"
            )
        yield line


def _decimals(cell: str) -> int:
    """Digits after the decimal point of a number written without an exponent (a large number otherwise)."""
    cell = cell.strip()
    return 99 if "e" in cell.lower() else len(cell.partition(".")[2])


def _csv_table(path: Path, max_bytes: int, layout: str, select, decimals: list = None):
    """Stream a CSV file: its header, then every non-blank row's numbers (checked against ``max_bytes`` as parsed).

    Parameters
    ----------
    select : callable
        ``select(header) -> (columns, label_column)``: the indices of the numeric columns read, and the column
        of trajectory labels (or None).

    Returns
    -------
    header : list of str
    table : ndarray of shape (N, len(columns))
    ids : ndarray of shape (N,) of int64
        Each row's label as an index into ``labels`` (zeros without a label column).
    labels : list of str
        The distinct labels in order of first appearance.
    lines : ndarray of shape (N,) of int64
        Each row's line in the file.

    ``decimals``, a list ``[0]``, gets the most digits after the decimal point in the first column read.

    Notes
    -----
    Memory: the parsed numbers, ids and line numbers, ``8 (c + 2)`` bytes per row, counted against
    ``max_bytes`` row by row (a file that would exceed it is refused at the row where it does), plus one line
    (at most :data:`MAX_CSV_LINE` characters) and one block of :data:`_CSV_BLOCK` rows of Python floats.
    """
    try:
        fh = open(path, encoding="utf-8-sig", newline="")
    except OSError as exc:
        raise ValueError(f"{str(path)!r} cannot be opened: {exc.strerror or exc}") from None
    with fh:
        reader = csv.reader(_csv_lines(fh, path))
        try:
            header = next(reader, None)
            if not header:
                raise ValueError(f"{str(path)!r} is empty: a header row is expected ({layout})")
            header = [h.strip() for h in header]
            columns, label_column = select(header)
            budget = int(max_bytes)
            per_row = 8 * (len(columns) + 2)
            blocks, id_blocks, line_blocks = [], [], []
            rows, ids, lines, labels = [], [], [], {}
            for row in reader:
                if not row or all(not c.strip() for c in row):
                    continue
                line = reader.line_num
                if len(row) != len(header):
                    raise ValueError(
                        f"{str(path)!r}, row {line}: {len(row)} cells, the header has {len(header)} columns"
                    )
                budget -= per_row
                if budget < 0:
                    raise ValueError(
                        f"{str(path)!r}, row {line}: the numbers read so far need more than max_bytes = "
                        f"{max_bytes} bytes; pass a larger max_bytes if the file is meant to be this large"
                    )
                rows.append(_csv_numbers(path, header, line, row, columns))
                lines.append(line)
                if decimals is not None:
                    decimals[0] = max(decimals[0], _decimals(row[columns[0]]))
                if label_column is not None:
                    label = row[label_column].strip()
                    if not label:
                        raise ValueError(
                            f"{str(path)!r}, row {line}, column {header[label_column]!r}: the trajectory label is empty"
                        )
                    index = labels.get(label)
                    if index is None:
                        budget -= 64 + 4 * len(label)
                        index = labels[label] = len(labels)
                    ids.append(index)
                if len(rows) == _CSV_BLOCK:
                    blocks.append(np.array(rows, dtype=float).reshape(len(rows), len(columns)))
                    line_blocks.append(np.array(lines, dtype=np.int64))
                    id_blocks.append(np.array(ids, dtype=np.int64))
                    rows, ids, lines = [], [], []
        except csv.Error as exc:
            raise ValueError(f"{str(path)!r}, row {reader.line_num}: not a valid CSV row ({exc}); {layout}") from None
        except UnicodeDecodeError as exc:
            raise ValueError(f"{str(path)!r} is not a readable UTF-8 text file: {exc}") from None
        except OSError as exc:
            raise ValueError(f"{str(path)!r} cannot be read: {exc.strerror or exc}") from None
    blocks.append(np.array(rows, dtype=float).reshape(len(rows), len(columns)))
    line_blocks.append(np.array(lines, dtype=np.int64))
    id_blocks.append(np.array(ids, dtype=np.int64))
    table, lines = np.concatenate(blocks), np.concatenate(line_blocks)
    ids = np.concatenate(id_blocks) if label_column is not None else np.zeros(len(table), dtype=np.int64)
    return header, table, ids, list(labels), lines


def _csv_numbers(path: Path, header: list, line: int, row: list, columns: list) -> list:
    """The cells ``columns`` of one CSV row as finite floats; ``ValueError`` naming the row and column otherwise."""
    numbers = []
    for c in columns:
        cell = row[c].strip()
        try:
            value = float(cell)
        except ValueError:
            raise ValueError(
                f"{str(path)!r}, row {line}, column {header[c]!r}: {cell[:40]!r} is not a number"
            ) from None
        if not np.isfinite(value):
            raise ValueError(f"{str(path)!r}, row {line}, column {header[c]!r}: {cell[:40]!r} is not finite")
        numbers.append(value)
    return numbers


def _read_csv(path: Path, max_bytes: int) -> TrajectoryData:
    picked = {}

    def select(header):
        names, columns, n, d = _state_columns(header, path)
        picked.update(n=n, d=d)
        return columns, names["traj"]

    decimals = [0]
    header, table, ids, traj_ids, lines = _csv_table(path, max_bytes, LAYOUT, select, decimals)
    n, d = picked["n"], picked["d"]
    if not len(table):
        raise ValueError(f"{str(path)!r} has a header but no data rows ({LAYOUT})")
    counts = np.bincount(ids, minlength=len(traj_ids))
    for i, label in enumerate(traj_ids):
        if counts[i] != counts[0]:
            raise ValueError(
                f"{str(path)!r}: trajectory {label!r} has {counts[i]} rows, trajectory {traj_ids[0]!r} has "
                f"{counts[0]}; all trajectories need the same number of states"
            )
    if counts[0] < 2:
        raise ValueError(f"{str(path)!r}: every trajectory needs at least 2 states (rows), got 1")
    order = np.argsort(ids, kind="stable").reshape(len(traj_ids), counts[0])  # rows of each trajectory, in file order
    block = table[order]  # (P, K+1, 1 + 2n + d)
    times, states, mu = block[:, :, 0], block[:, :, 1 : 1 + 2 * n], block[:, :, 1 + 2 * n :]
    steps = np.diff(times, axis=1)
    bad = np.flatnonzero(~(steps > 0).all(axis=1))
    if len(bad):
        label = traj_ids[bad[0]]
        k = int(np.flatnonzero(steps[bad[0]] <= 0)[0])
        raise ValueError(
            f"{str(path)!r}: trajectory {label!r} is not in increasing time: row {int(lines[order[bad[0], k + 1]])} "
            f"has t = {float(times[bad[0], k + 1])!r} after t = {float(times[bad[0], k])!r}; sort its rows by t"
        )
    if d:
        varying = np.flatnonzero(np.ptp(mu, axis=1).max(axis=1) > 0)
        if len(varying):
            raise ValueError(
                f"{str(path)!r}: the parameter columns must be constant within a trajectory; trajectory "
                f"{traj_ids[varying[0]]!r} has several values"
            )
    step = _rounded_uniform_step(times, decimals[0])
    if step is not None:
        return TrajectoryData(states, mu[:, 0] if d else None, dt=step)
    return TrajectoryData(states, mu[:, 0] if d else None, times=times)


#: Times written with ``d`` decimals are uniform if their steps agree within ``10^-d`` (two roundings), as long as
#: that is at most this fraction of the step.
ROUNDED_TIMES_RTOL = 1e-3


def _rounded_uniform_step(times: np.ndarray, decimals: int):
    """The common step of times written with ``decimals`` digits in the file, or None (not uniform to that
    precision, or uniform to round-off already: :class:`TrajectoryData` sees that itself).

    Steps that are all the same whole number ``c`` of units ``10^-d`` (large times such as Unix seconds, whose
    parsed differences carry the round-off of the times' magnitude) give exactly ``c 10^-d``.  Otherwise, steps
    within ``min(10^-d, ROUNDED_TIMES_RTOL dT)`` of their mean give ``(t_K - t_0) / K`` of the first trajectory
    (error ``10^-d / K``).
    """
    if decimals >= 99:
        return None
    k = times.shape[1] - 1
    steps = np.diff(times, axis=1)
    roundoff = 64 * np.finfo(float).eps * float(np.abs(times).max())
    unit = 10.0**-decimals
    if unit > 100 * np.finfo(float).eps * float(np.abs(times).max()):  # parsed steps err by a few ulps of max|t|
        counts = np.rint(steps / unit)
        if counts.min() == counts.max() > 0 and float(np.abs(steps - counts * unit).max()) <= 1e-2 * unit:
            h = float(counts[0, 0]) * unit
            if float(np.abs(steps - h).max()) > 0:
                logger.info(f"times written with {decimals} decimals: every step is {h:.12g}")
            return h if float(np.abs(steps - h).max()) > 0 else None
    h = float((times[0, -1] - times[0, 0]) / k)
    tol = min(unit, ROUNDED_TIMES_RTOL * h)
    dev = float(np.abs(steps - h).max())
    if dev <= roundoff or dev > tol:
        return None
    logger.info(f"times written with {decimals} decimals: uniform within {tol:.1g} (steps {h:.12g} +- {dev:.1g})")
    return h


# --------------------------------------------------------------------------- writing, initial states
def write_trajectories(data: TrajectoryData, path, extra: Optional[dict] = None, *, overwrite: bool = True) -> None:
    """Write trajectories in the layout :func:`read_trajectories` reads (format by suffix), atomically.

    The file is written to a temporary sibling and renamed (:func:`sympredict.container.atomic_output`): a
    failure (disk full, a file size limit) or Ctrl-C leaves the previous file as it was and the error names the
    file that was not written.

    Parameters
    ----------
    data : TrajectoryData
        ``P`` trajectories of shape ``(K+1, 2n)``.
    path : str or path-like
        ``.npz`` (keys ``states``, ``dt`` for times ``k dt`` or else ``times``, and ``mu`` when there are
        parameters), ``.h5``/``.hdf5``
        (the same datasets) or ``.csv`` (columns ``traj`` (0..P-1), ``t``, ``q1..qn``, ``p1..pn``, then
        ``mu1..mud``; numbers written to round-trip exactly).
    extra : dict of str to ndarray of shape (P, K+1), optional
        Per-state values written beside the states (e.g. ``error``, the prediction's error estimate): a
        key of the ``.npz``/``.h5`` file, or a last column of the ``.csv`` (such a file is an output, not
        an input of :func:`read_trajectories`).
    overwrite : bool
        Replace an existing file (default); ``False`` raises :class:`FileExistsError` if the file exists, also
        if it was created while this one was written.
    """
    path = Path(path)
    kind = _SUFFIXES.get(path.suffix.lower())
    if kind is None:
        raise ValueError(f"{str(path)!r}: unknown data file type {path.suffix!r}; use .npz, .h5/.hdf5 or .csv")
    uniform = data.dt is not None and np.array_equal(
        data.times, np.broadcast_to(np.arange(data.states.shape[1]) * data.dt, data.times.shape)
    )
    arrays = {"states": data.states}
    arrays.update({"dt": np.float64(data.dt)} if uniform else {"times": np.ascontiguousarray(data.times)})
    if data.mu.shape[1]:
        arrays["mu"] = data.mu
    extra = {k: np.broadcast_to(np.asarray(v, dtype=float), data.states.shape[:2]) for k, v in (extra or {}).items()}
    arrays.update(extra)
    if kind == "npz":
        with atomic_output(path, overwrite=overwrite) as fh:  # a file object: np.savez would append .npz to other names
            np.savez(fh, **arrays)
    elif kind == "hdf5":
        import h5py

        buffer = io.BytesIO()
        with h5py.File(buffer, "w") as f:
            for key, value in arrays.items():
                f[key] = value
        with atomic_output(path, overwrite=overwrite) as fh:
            fh.write(buffer.getbuffer())
    else:
        p, k1, dim = data.states.shape
        n, d = dim // 2, data.mu.shape[1]
        header = [
            "traj",
            "t",
            *(f"q{i}" for i in range(1, n + 1)),
            *(f"p{i}" for i in range(1, n + 1)),
            *(f"mu{i}" for i in range(1, d + 1)),
            *extra,
        ]
        table = np.concatenate(
            [
                np.broadcast_to(np.arange(p)[:, None, None], (p, k1, 1)),
                data.times[:, :, None],
                data.states,
                np.broadcast_to(data.mu[:, None, :], (p, k1, d)),
                *(v[:, :, None] for v in extra.values()),
            ],
            axis=2,
        ).reshape(p * k1, -1)
        with atomic_output(path, overwrite=overwrite) as fh:
            np.savetxt(
                fh,
                table,
                delimiter=",",
                header=",".join(header),
                comments="",
                fmt=["%d"] + ["%.17g"] * (table.shape[1] - 1),
            )


def read_states(path, dim: int, *, max_bytes: int = MAX_BYTES):
    """Initial states (and optional parameters) for a rollout from a ``.npz`` or ``.csv`` file.

    ``.npz``: key ``x0`` of shape ``(B, 2n)`` or ``(2n,)``, optional ``mu`` ``(B,)`` or ``(B, d)``.
    ``.csv``: a header row with ``q1..qn, p1..pn`` (``q``, ``p`` for ``n = 1``) and optional ``mu`` or
    ``mu1..mud`` columns, one state per row.

    Parameters
    ----------
    path : str or path-like
    dim : int
        The model's state dimension ``2n``.
    max_bytes : int
        Largest size (float64 bytes) of the numbers read.

    Returns
    -------
    x0 : ndarray of shape (B, 2n)
    mu : ndarray of shape (B, d) or None
    """
    path = Path(path)
    suffix = path.suffix.lower()
    layout = (
        f"expected .npz with 'x0' (B, {dim}) [optional 'mu' (B,) or (B, d)], or .csv with the columns "
        f"{', '.join(_state_names(dim))} [optional mu or mu1..mud]"
    )
    if not path.is_file():
        raise ValueError(f"{str(path)!r} does not exist or is not a regular file")
    if suffix == ".npz":
        with _NpzArrays(path, max_bytes) as arrays:
            if "x0" not in arrays.keys():
                raise ValueError(f"{str(path)!r} has no key 'x0' (found {sorted(arrays.keys())[:10]}); {layout}")
            x0 = _real(path, "x0", arrays.get("x0"))
            mu = _real(path, "mu", arrays.get("mu")) if "mu" in arrays.keys() else None
    elif suffix == ".csv":
        picked = {}

        def select(header):
            names = ["q1", "p1"] if dim == 2 and "q1" in header else _state_names(dim)
            missing = [c for c in names if c not in header]
            if missing:
                raise ValueError(f"{str(path)!r}: the header lacks the column(s) {missing}; {layout}")
            mu_names = _parameter_names(header, path, layout)
            unknown = [c for c in header if c not in names and c not in mu_names]
            if unknown:
                raise ValueError(f"{str(path)!r}: unexpected column(s) {unknown[:5]}; {layout}")
            if len(set(header)) != len(header):
                raise ValueError(f"{str(path)!r}: the header repeats a column name: {header[:12]}")
            picked["mu"] = bool(mu_names)
            return [header.index(c) for c in [*names, *mu_names]], None  # matched by name, parameters in index order

        _, table, _, _, _ = _csv_table(path, max_bytes, layout, select)
        if not len(table):
            raise ValueError(f"{str(path)!r} has a header but no data rows; {layout}")
        x0, mu = table[:, :dim], (table[:, dim:] if picked["mu"] else None)
    else:
        raise ValueError(
            f"{str(path)!r}: initial states are read from .npz or .csv files, got {path.suffix!r}; {layout}"
        )
    x0, _ = as_states(x0, _where(path, "x0"), dim=dim)  # (B, 2n) or one state (2n,)
    return x0, mu


def _parameter_names(header: list, path: Path, layout: str) -> list:
    """The parameter columns of a CSV header by name: ``["mu"]``, or ``mu1..mud`` in that order (wherever they stand)."""
    numbered = {int(c[2:]): c for c in header if re.fullmatch(r"mu[1-9][0-9]*", c)}
    if "mu" in header and numbered:
        raise ValueError(
            f"{str(path)!r}: the header has both 'mu' and {sorted(numbered.values())[:3]}: name one parameter "
            f"'mu' or several mu1..mud; {layout}"
        )
    if "mu" in header:
        return ["mu"]
    d = len(numbered)
    if sorted(numbered) != list(range(1, d + 1)):
        raise ValueError(
            f"{str(path)!r}: the parameter columns {[numbered[k] for k in sorted(numbered)][:6]} must be "
            f"mu1..mu{d} without gaps; {layout}"
        )
    return [numbered[k] for k in range(1, d + 1)]


def _state_names(dim: int) -> list:
    n = dim // 2
    if n == 1:
        return ["q", "p"]
    return [f"q{i}" for i in range(1, n + 1)] + [f"p{i}" for i in range(1, n + 1)]
