"""Reading the user's trajectories and flow-map samples from ``.npz``, HDF5 and ``.csv`` files.

:func:`read_trajectories` is the one entry point; every file is treated as hostile input: shapes, dtypes,
sizes and finiteness are checked before arrays are allocated, and every error names the file, the key or
column, and the expected layout.
"""

from __future__ import annotations

import csv
import io
import os
import re
import zipfile
from pathlib import Path

import numpy as np

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

_SUFFIXES = {".npz": "npz", ".h5": "hdf5", ".hdf5": "hdf5", ".csv": "csv"}


def read_trajectories(path, *, states_key: str = "states", times_key: str = "times", dt_key: str = "dt",
                      mu_key: str = "mu", max_bytes: int = MAX_BYTES):
    """Read trajectories (or flow-map pairs) from a ``.npz``, HDF5 (``.h5``, ``.hdf5``) or ``.csv`` file.

    Parameters
    ----------
    path : str or path-like
        The file; its suffix picks the format.
    states_key, times_key, dt_key, mu_key : str
        Names of the arrays in ``.npz``/HDF5 files (the pair keys are ``x0``, ``x1``).
    max_bytes : int
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
        raise ValueError(f"{str(path)!r}: unknown data file type {path.suffix!r}; use .npz, .h5/.hdf5 or .csv ({LAYOUT})")
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
    """Refuse non-numeric dtypes and sizes over the budget before reading ``key``."""
    dtype = np.dtype(dtype)
    if dtype.kind not in "fiu" or dtype.fields is not None or dtype.subdtype is not None:
        raise ValueError(f"{_where(path, key)} has dtype {dtype}; a real numeric array is expected ({LAYOUT})")
    count = 1
    for n in shape:
        count *= int(n)
    budget[0] -= 8 * count
    if budget[0] < 0:
        raise ValueError(f"{_where(path, key)} declares shape {tuple(shape)}: the arrays exceed max_bytes; "
                         "pass a larger max_bytes if the file is meant to be this large")


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
        try:
            with self.zip.open(self.members[key]) as fh:
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
        except (zipfile.BadZipFile, OSError, EOFError) as exc:
            raise ValueError(f"{_where(self.path, key)} cannot be read (truncated or corrupted?): {exc}") from None
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
    arr = np.asarray(arr, dtype=float)
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{_where(path, key)} contains NaN or Inf")
    return arr


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
            if a.ndim != 2 or a.shape[0] == 0 or a.shape[1] == 0 or a.shape[1] % 2:
                raise ValueError(f"{_where(path, k)} must have shape (M, 2n) with M >= 1 and an even 2n, got {a.shape}")
        if x1.shape != x0.shape:
            raise ValueError(f"{_where(path, 'x1')} has shape {x1.shape}, 'x0' has {x0.shape}: they must agree")
        return _named(path, lambda: FlowMapData(x0, x1, mu, dt), {"mu": mu_key, "dt": dt_key})
    if states_key not in present:
        raise ValueError(f"{str(path)!r} has no key {states_key!r} (found {sorted(present)[:10]}); {LAYOUT}")
    states = _real(path, states_key, arrays.get(states_key))
    if states.ndim == 2:
        states = states[None]
    if states.ndim != 3 or states.shape[1] < 2 or states.shape[2] == 0 or states.shape[2] % 2:
        raise ValueError(f"{_where(path, states_key)} must have shape (P, K+1, 2n) with K >= 1 and an even 2n "
                         f"(or (K+1, 2n) for one trajectory), got {states.shape}")
    has_dt, has_times = dt_key in present, times_key in present
    if has_dt == has_times:
        raise ValueError(f"{str(path)!r} must hold exactly one of {dt_key!r} (a uniform step) and {times_key!r} "
                         f"((P, K+1) or (K+1,)), found {'both' if has_dt else 'neither'} ({LAYOUT})"
                         + ("" if has_dt else
                            f"; add the sampling step when saving, e.g. np.savez({Path(path).name!r}, {states_key}=states, "
                            f"mu=mu, {dt_key}=0.1)" if str(path).lower().endswith(".npz") else
                            f"; add the sampling step as a scalar data set, e.g. h5file[{dt_key!r}] = 0.1"))
    dt = _real(path, dt_key, arrays.get(dt_key)) if has_dt else None
    if dt is not None and dt.size != 1:
        raise ValueError(f"{_where(path, dt_key)} must be one positive number (uniform steps; give {times_key!r} "
                         f"otherwise), got shape {dt.shape}")
    times = _real(path, times_key, arrays.get(times_key)) if has_times else None
    return _named(path, lambda: TrajectoryData(states, mu, None if dt is None else float(dt.reshape(-1)[0]), times),
                  {"mu": mu_key, "dt": dt_key, "times": times_key})


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
        raise ValueError(f"{str(path)!r}: the header lacks the column(s) {missing or ['q1', 'p1']}; got {header[:12]} "
                         f"({LAYOUT})")
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
        raise ValueError(f"{str(path)!r}: unexpected column(s) {unknown[:5]} (for 2n = {2 * len(q_names)} states and "
                         f"{len(mu_names)} parameter(s)); {LAYOUT}")
    if len(header) != len(names):
        raise ValueError(f"{str(path)!r}: the header repeats a column name: {header[:12]}")
    return names, [names[c] for c in ["t", *q_names, *p_names, *mu_names]], len(q_names), len(mu_names)


def _csv_rows(path: Path, max_bytes: int, layout: str):
    """``(header, rows)`` of a CSV file: the stripped header and the non-blank rows as ``(line, cells)``, each with as
    many cells as the header (checked, as the file's size, before anything else is read)."""
    size = os.path.getsize(path)
    if size > max_bytes:
        raise ValueError(f"{str(path)!r} has {size} bytes, more than max_bytes = {max_bytes}; pass a larger max_bytes "
                         "if the file is meant to be this large")
    try:
        text = path.read_text(encoding="utf-8-sig")
    except (UnicodeDecodeError, OSError) as exc:
        raise ValueError(f"{str(path)!r} is not a readable UTF-8 text file: {exc}") from None
    reader = csv.reader(io.StringIO(text))
    header = next(reader, None)
    if not header:
        raise ValueError(f"{str(path)!r} is empty: a header row is expected ({layout})")
    header = [h.strip() for h in header]
    rows = []
    for line, row in enumerate(reader, start=2):
        if not row or all(not c.strip() for c in row):
            continue
        if len(row) != len(header):
            raise ValueError(f"{str(path)!r}, row {line}: {len(row)} cells, the header has {len(header)} columns")
        rows.append((line, row))
    return header, rows


def _csv_numbers(path: Path, header: list, line: int, row: list, columns: list) -> list:
    """The cells ``columns`` of one CSV row as finite floats; ``ValueError`` naming the row and column otherwise."""
    numbers = []
    for c in columns:
        cell = row[c].strip()
        try:
            value = float(cell)
        except ValueError:
            raise ValueError(f"{str(path)!r}, row {line}, column {header[c]!r}: {cell[:40]!r} is not a number") from None
        if not np.isfinite(value):
            raise ValueError(f"{str(path)!r}, row {line}, column {header[c]!r}: {cell[:40]!r} is not finite")
        numbers.append(value)
    return numbers


def _read_csv(path: Path, max_bytes: int) -> TrajectoryData:
    header, rows = _csv_rows(path, max_bytes, LAYOUT)
    names, columns, n, d = _state_columns(header, path)
    labels, values = [], []
    for line, row in rows:
        numbers = _csv_numbers(path, header, line, row, columns)
        label = row[names["traj"]].strip()
        if not label:
            raise ValueError(f"{str(path)!r}, row {line}, column 'traj': the trajectory label is empty")
        labels.append(label)
        values.append(numbers)
    if not values:
        raise ValueError(f"{str(path)!r} has a header but no data rows ({LAYOUT})")
    table = np.array(values)
    order, index = np.unique(np.array(labels), return_index=True)
    traj_ids = [str(label) for label in order[np.argsort(index)]]  # trajectories in order of first appearance
    rows_of = {label: [] for label in traj_ids}
    for i, label in enumerate(labels):
        rows_of[label].append(i)
    counts = {label: len(r) for label, r in rows_of.items()}
    first = traj_ids[0]
    for label in traj_ids:
        if counts[label] != counts[first]:
            raise ValueError(f"{str(path)!r}: trajectory {label!r} has {counts[label]} rows, trajectory {first!r} has "
                             f"{counts[first]}; all trajectories need the same number of states")
    if counts[first] < 2:
        raise ValueError(f"{str(path)!r}: every trajectory needs at least 2 states (rows), got 1")
    block = table[np.array([rows_of[label] for label in traj_ids])]  # (P, K+1, 1 + 2n + d)
    times, states, mu = block[:, :, 0], block[:, :, 1:1 + 2 * n], block[:, :, 1 + 2 * n:]
    steps = np.diff(times, axis=1)
    bad = np.flatnonzero(~(steps > 0).all(axis=1))
    if len(bad):
        label = traj_ids[bad[0]]
        k = int(np.flatnonzero(steps[bad[0]] <= 0)[0])
        raise ValueError(f"{str(path)!r}: trajectory {label!r} is not in increasing time: row {rows_of[label][k + 1] + 2} "
                         f"has t = {float(times[bad[0], k + 1])!r} after t = {float(times[bad[0], k])!r}; sort its rows by t")
    if d:
        varying = np.flatnonzero(np.ptp(mu, axis=1).max(axis=1) > 0)
        if len(varying):
            raise ValueError(f"{str(path)!r}: the parameter columns must be constant within a trajectory; trajectory "
                             f"{traj_ids[varying[0]]!r} has several values")
    return TrajectoryData(states, mu[:, 0] if d else None, times=times)


# --------------------------------------------------------------------------- writing, initial states
def write_trajectories(data: TrajectoryData, path) -> None:
    """Write trajectories in the layout :func:`read_trajectories` reads (format by suffix).

    Parameters
    ----------
    data : TrajectoryData
        ``P`` trajectories of shape ``(K+1, 2n)``.
    path : str or path-like
        ``.npz`` (keys ``states``, ``dt`` for times ``k dt`` or else ``times``, and ``mu`` when there are
        parameters), ``.h5``/``.hdf5``
        (the same datasets) or ``.csv`` (columns ``traj`` (0..P-1), ``t``, ``q1..qn``, ``p1..pn``, then
        ``mu1..mud``; numbers written to round-trip exactly).
    """
    path = Path(path)
    kind = _SUFFIXES.get(path.suffix.lower())
    if kind is None:
        raise ValueError(f"{str(path)!r}: unknown data file type {path.suffix!r}; use .npz, .h5/.hdf5 or .csv")
    uniform = data.dt is not None and np.array_equal(data.times, np.broadcast_to(np.arange(data.states.shape[1]) * data.dt,
                                                                                 data.times.shape))
    arrays = {"states": data.states}
    arrays.update({"dt": np.float64(data.dt)} if uniform else {"times": np.ascontiguousarray(data.times)})
    if data.mu.shape[1]:
        arrays["mu"] = data.mu
    if kind == "npz":
        with open(path, "wb") as fh:  # np.savez would append .npz to other names
            np.savez(fh, **arrays)
    elif kind == "hdf5":
        import h5py

        with h5py.File(path, "w") as f:
            for key, value in arrays.items():
                f[key] = value
    else:
        p, k1, dim = data.states.shape
        n, d = dim // 2, data.mu.shape[1]
        header = ["traj", "t", *(f"q{i}" for i in range(1, n + 1)), *(f"p{i}" for i in range(1, n + 1)),
                  *(f"mu{i}" for i in range(1, d + 1))]
        table = np.concatenate([np.broadcast_to(np.arange(p)[:, None, None], (p, k1, 1)), data.times[:, :, None],
                                data.states, np.broadcast_to(data.mu[:, None, :], (p, k1, d))], axis=2).reshape(p * k1, -1)
        np.savetxt(path, table, delimiter=",", header=",".join(header), comments="",
                   fmt=["%d"] + ["%.17g"] * (table.shape[1] - 1))


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
    layout = (f"expected .npz with 'x0' (B, {dim}) [optional 'mu' (B,) or (B, d)], or .csv with the columns "
              f"{', '.join(_state_names(dim))} [optional mu or mu1..mud]")
    if not path.is_file():
        raise ValueError(f"{str(path)!r} does not exist or is not a regular file")
    if suffix == ".npz":
        with _NpzArrays(path, max_bytes) as arrays:
            if "x0" not in arrays.keys():
                raise ValueError(f"{str(path)!r} has no key 'x0' (found {sorted(arrays.keys())[:10]}); {layout}")
            x0 = _real(path, "x0", arrays.get("x0"))
            mu = _real(path, "mu", arrays.get("mu")) if "mu" in arrays.keys() else None
    elif suffix == ".csv":
        header, rows = _csv_rows(path, max_bytes, layout)
        names = ["q1", "p1"] if dim == 2 and "q1" in header else _state_names(dim)
        missing = [c for c in names if c not in header]
        if missing:
            raise ValueError(f"{str(path)!r}: the header lacks the column(s) {missing}; {layout}")
        mu_names = ["mu"] if "mu" in header else [c for c in header if re.fullmatch(r"mu[1-9][0-9]*", c)]
        unknown = [c for c in header if c not in names and c not in mu_names]
        if unknown:
            raise ValueError(f"{str(path)!r}: unexpected column(s) {unknown[:5]}; {layout}")
        columns = [header.index(c) for c in [*names, *mu_names]]
        values = [_csv_numbers(path, header, line, row, columns) for line, row in rows]
        if not values:
            raise ValueError(f"{str(path)!r} has a header but no data rows; {layout}")
        table = np.array(values)
        x0, mu = table[:, :dim], (table[:, dim:] if mu_names else None)
    else:
        raise ValueError(f"{str(path)!r}: initial states are read from .npz or .csv files, got {path.suffix!r}; {layout}")
    if x0.ndim == 1:
        x0 = x0[None]
    if x0.ndim != 2 or x0.shape[1] != dim or len(x0) == 0:
        raise ValueError(f"{_where(path, 'x0')} must have shape (B, {dim}) (the model's 2n = {dim}), got {x0.shape}")
    return x0, mu


def _state_names(dim: int) -> list:
    n = dim // 2
    if n == 1:
        return ["q", "p"]
    return [f"q{i}" for i in range(1, n + 1)] + [f"p{i}" for i in range(1, n + 1)]
