"""Container files as hostile input, and saving that never damages what is there (issue 16).

Hostile files are crafted with h5py from a good file; each must be refused with
``ModelFileError`` naming the problem before anything outside the file is touched.
"""

import contextlib
import errno
import json
import os
import signal
import stat
import subprocess
import sys
import time

import h5py
import numpy as np
import pytest

from sympredict import ModelFileError
from sympredict import container
from sympredict.container import SCHEMA_VERSION, read_container, write_container
from sympredict.io import load_dataset

FMT = "sympredict-test"
SETTINGS = {"kernel": {"family": "imq", "eps": 0.5}, "n": 3, "name": "x"}
ARRAYS = {
    "a": np.arange(12.0).reshape(3, 4),
    "i": np.arange(5, dtype=np.int64),
    "s": np.asarray(2.5),
    "e": np.zeros((0, 3)),
}


@contextlib.contextmanager
def deadline(seconds=20):
    """Fail instead of hanging (a FIFO opened for reading blocks forever)."""

    def fail(*_):
        raise TimeoutError(f"no answer within {seconds} s: the call hung")

    old = signal.signal(signal.SIGALRM, fail)
    signal.alarm(seconds)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)


def good(tmp_path, name="c.h5"):
    path = tmp_path / name
    write_container(path, FMT, SETTINGS, ARRAYS)
    return path


def refused(path, match):
    with deadline():
        with pytest.raises(ModelFileError, match=match):
            read_container(path, FMT)


def dead_pid():
    proc = subprocess.Popen([sys.executable, "-c", "pass"])
    proc.wait()
    return proc.pid


# ------------------------------------------------------------------ reading
def test_roundtrip_is_exact(tmp_path):
    settings, arrays = read_container(good(tmp_path), FMT)
    assert settings == SETTINGS and set(arrays) == set(ARRAYS)
    for name, arr in ARRAYS.items():
        assert arrays[name].dtype == arr.dtype and np.shape(arrays[name]) == arr.shape
        np.testing.assert_array_equal(arrays[name], arr)


def test_special_files_are_refused_without_hanging(tmp_path):
    fifo = tmp_path / "fifo.h5"
    os.mkfifo(fifo)
    refused(fifo, "FIFO, not a regular file")
    refused(os.devnull, "character device, not a regular file")
    refused(tmp_path, "directory, not a regular file")
    refused(tmp_path / "missing.h5", "does not exist")


@pytest.mark.parametrize("target", ["fifo", "passwd", "hdf5"])
def test_external_links_are_never_followed(tmp_path, target):
    if target == "fifo":
        dest = tmp_path / "fifo"
        os.mkfifo(dest)
    elif target == "passwd":
        dest = "/etc/passwd"
    else:  # a well-formed HDF5 file whose data would load silently
        dest = tmp_path / "other.h5"
        with h5py.File(dest, "w") as f:
            f["a"] = np.ones(3)
    path = good(tmp_path)
    with h5py.File(path, "r+") as f:
        f["arrays/x"] = h5py.ExternalLink(str(dest), "/a")
    refused(path, "array 'x' is a ExternalLink")
    path = good(tmp_path, "c2.h5")
    with h5py.File(path, "r+") as f:  # the whole group replaced by a link to another file
        del f["arrays"]
        f["arrays"] = h5py.ExternalLink(str(dest), "/")
    refused(path, "'arrays' is a ExternalLink")


def test_soft_links_and_foreign_objects_are_refused(tmp_path):
    cases = {
        "soft link": (lambda f: f["arrays"].__setitem__("y", h5py.SoftLink("/arrays/a")), "SoftLink"),
        "root attribute": (lambda f: f.attrs.__setitem__("extra", 1), "unexpected root attributes"),
        "missing attribute": (lambda f: f.attrs.__delitem__("package_version"), "lacks the attributes"),
        "dataset attribute": (
            lambda f: f["arrays/a"].attrs.__setitem__("note", "x"),
            "attributes the writer never writes",
        ),
        "group attribute": (lambda f: f["arrays"].attrs.__setitem__("note", "x"), "attributes the writer never writes"),
        "root group": (lambda f: f.create_group("more"), "objects the writer never writes"),
        "root dataset": (lambda f: f.create_dataset("z", data=np.ones(2)), "objects the writer never writes"),
        "nested group": (lambda f: f["arrays"].create_group("g"), "is not a dataset"),
        "hard link cycle": (lambda f: f["arrays"].__setitem__("loop", f["/"]), "is not a dataset"),
        "string dataset": (
            lambda f: f["arrays"].create_dataset("t", data=np.array([b"ab", b"cd"])),
            "only numeric arrays",
        ),
        "compound dataset": (
            lambda f: f["arrays"].create_dataset("c", data=np.zeros(2, dtype=[("u", "f8"), ("v", "i4")])),
            "only numeric arrays",
        ),
        "no arrays group": (lambda f: f.__delitem__("arrays"), "has no 'arrays' group"),
        "settings as int": (lambda f: f.attrs.__setitem__("settings", 3), "'settings' must be a string"),
        "checksum as array": (
            lambda f: f.attrs.__setitem__("checksum", np.array(["a", "b"], dtype=object)),
            "must be a scalar",
        ),
    }
    for label, (attack, match) in cases.items():
        path = good(tmp_path, "c.h5")
        with h5py.File(path, "r+") as f:
            attack(f)
        try:
            refused(path, match)
        except BaseException as exc:
            raise AssertionError(f"case {label!r}: {exc}") from None


def test_virtual_and_external_storage_are_refused(tmp_path):
    src = tmp_path / "source.h5"
    with h5py.File(src, "w") as f:
        f["data"] = np.arange(4.0)
    path = good(tmp_path)
    with h5py.File(path, "r+") as f:
        layout = h5py.VirtualLayout(shape=(4,), dtype="f8")
        layout[:] = h5py.VirtualSource(str(src), "data", shape=(4,))
        f["arrays"].create_virtual_dataset("v", layout)
    refused(path, "virtual dataset")
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    for dest in ("/etc/passwd", str(fifo)):
        path = good(tmp_path, "c2.h5")
        with h5py.File(path, "r+") as f:
            f["arrays"].create_dataset("x", shape=(16,), dtype="f8", external=[(dest, 0, 128)])
        refused(path, "external storage")


def test_filters_and_inflated_sizes_are_refused_before_reading(tmp_path):
    path = good(tmp_path)
    with h5py.File(path, "r+") as f:  # 80 MB of zeros compress to a few kB
        f["arrays"].create_dataset("z", data=np.zeros(10**7), compression="gzip", chunks=(10**6,))
    assert path.stat().st_size < 10**6
    refused(path, "compressed or filtered")
    path = good(tmp_path, "c2.h5")
    with h5py.File(path, "r+") as f:  # 8 TB declared, nothing stored
        f["arrays"].create_dataset("big", shape=(10**12,), dtype="f8")
    refused(path, r"declares shape \(1000000000000,\)")
    path = good(tmp_path, "c3.h5")
    with h5py.File(path, "r+") as f:
        f["arrays"].create_dataset("chunky", shape=(10**9, 10**3), dtype="f8", chunks=(1, 10))
    refused(path, "chunked")


@pytest.mark.parametrize("version", [0, -3, 1.7, 2.0, "1", True, np.array([1, 2])])
def test_invalid_schema_versions_are_refused(tmp_path, version):
    path = good(tmp_path)
    with h5py.File(path, "r+") as f:
        f.attrs["schema_version"] = version
    refused(path, "schema version|schema_version")


def test_newer_schema_asks_for_an_upgrade(tmp_path):
    path = good(tmp_path)
    with h5py.File(path, "r+") as f:
        f.attrs["schema_version"] = SCHEMA_VERSION + 1
    refused(path, f"schema version {SCHEMA_VERSION + 1}.*upgrade sympredict")


def test_checksum_covers_settings_every_attribute_and_every_array(tmp_path):
    changed = dict(SETTINGS, kernel={"family": "imq", "eps": 0.6})
    for attack in (
        lambda f: f.attrs.__setitem__("settings", np.bytes_(json.dumps(changed))),
        lambda f: f.attrs.__setitem__("package_version", np.bytes_("9.9.9")),
        lambda f: f["arrays/i"].__setitem__(0, 7),
        lambda f: f["arrays/s"].__setitem__((), 2.0),
    ):
        path = good(tmp_path)
        with h5py.File(path, "r+") as f:
            attack(f)
        refused(path, "corrupted: its settings or arrays do not match")
    path = good(tmp_path)
    with h5py.File(path, "r+") as f:
        f.attrs["format"] = np.bytes_("sympredict-other")
    refused(path, "is a 'sympredict-other' file, expected")
    path = good(tmp_path)
    with h5py.File(path, "r+") as f:  # what the writer never writes in schema 2 (its heap is unchecked)
        f.attrs["settings"] = json.dumps(SETTINGS)
    refused(path, "variable-length string")


def test_schema_1_files_are_still_read(tmp_path):
    """Files written before schema 2 (checksum over the arrays only) load; a damaged array is still found."""
    path = write_v1(tmp_path / "v1.h5")
    settings, arrays = read_container(path, FMT)
    assert settings == SETTINGS and np.array_equal(arrays["a"], ARRAYS["a"])
    with h5py.File(path, "r+") as f:
        f["arrays/a"][0, 0] = -1.0
    refused(path, "corrupted: its arrays do not match")


def write_v1(path, settings=SETTINGS, arrays=ARRAYS):
    """A file as the schema-1 writer wrote it (variable-length strings, checksum over the arrays)."""
    with h5py.File(path, "w") as f:
        f.attrs["format"] = FMT
        f.attrs["schema_version"] = 1
        f.attrs["package_version"] = "0.1.0"
        f.attrs["checksum"] = container._checksum_v1(arrays)
        f.attrs["settings"] = json.dumps(settings)
        for name, arr in arrays.items():
            f.create_dataset(f"arrays/{name}", data=arr)
    return path


def test_damaged_bytes_give_model_file_error_or_the_original_content(tmp_path):
    """Bytes zeroed or flipped, truncations: ModelFileError or the exact original, nothing else, no hang.

    (A denser sweep, every byte of a schema-2 and a schema-1 file set to 0x00, 0xFF and a
    random value, 25,000 loads, ran clean by hand; see docs/reference/errors.md.)
    """
    path = good(tmp_path)
    original = path.read_bytes()
    damaged = tmp_path / "damaged.h5"
    outcomes = {"refused": 0, "intact": 0}
    variants = [(p, 0x00) for p in range(0, len(original), 5)] + [(p, 0xFF) for p in range(2, len(original), 10)]
    for pos, value in variants:
        data = bytearray(original)
        if data[pos] == value:
            continue
        data[pos] = value
        damaged.write_bytes(bytes(data))
        with deadline():
            try:
                settings, arrays = read_container(damaged, FMT)
            except ModelFileError:
                outcomes["refused"] += 1
                continue
        assert settings == SETTINGS, f"byte {pos} = {value:#x} changed the settings silently"
        for name, arr in ARRAYS.items():
            assert np.array_equal(arrays[name], arr), f"byte {pos} = {value:#x} changed array {name} silently"
        outcomes["intact"] += 1
    for cut in range(0, len(original), 97):
        damaged.write_bytes(original[:cut])
        with pytest.raises(ModelFileError):
            read_container(damaged, FMT)
    assert outcomes["refused"] > 100  # the damage is detected, not merely tolerated


def test_damaged_global_heap_of_a_schema_1_file_does_not_hang(tmp_path):
    """HDF5 loops forever on a global heap object of size 0 (found by the byte sweep): checked before HDF5 sees it.

    Run in a child process: a hang inside HDF5 holds the GIL, so no alarm could stop it here.
    """
    path = write_v1(tmp_path / "v1.h5")
    data = path.read_bytes()
    start = data.find(b"GCOL")
    assert start > 0
    end = start + int.from_bytes(data[start + 8 : start + 16], "little")
    objects, p = [], start + 16  # (offset of the object header, index)
    while p + 16 <= end:
        index, size = int.from_bytes(data[p : p + 2], "little"), int.from_bytes(data[p + 8 : p + 16], "little")
        objects.append(p)
        p += size if index == 0 else 16 + (size + 7) // 8 * 8
    attacks = {
        "free space of size 0": (objects[-1] + 8, (0).to_bytes(8, "little")),
        "object of size 0 at index 0": (
            objects[0],
            (0).to_bytes(2, "little") + data[objects[0] + 2 : objects[0] + 8] + (0).to_bytes(8, "little"),
        ),
        "object beyond the collection": (objects[0] + 8, (10**9).to_bytes(8, "little")),
        "collection beyond the file": (start + 8, (10**9).to_bytes(8, "little")),
    }
    for label, (offset, patch) in attacks.items():
        bad = tmp_path / "bad.h5"
        bad.write_bytes(data[:offset] + patch + data[offset + len(patch) :])
        script = (
            "from sympredict import ModelFileError\nfrom sympredict.container import read_container\n"
            f"try:\n    read_container({str(bad)!r}, {FMT!r})\nexcept ModelFileError as exc:\n    print('refused:', exc)\n"
        )
        proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
        assert proc.returncode == 0 and "refused: " in proc.stdout and "global heap" in proc.stdout, (
            label,
            proc.stdout,
            proc.stderr,
        )
    # the intact file still loads
    assert read_container(path, FMT)[0] == SETTINGS


@pytest.mark.parametrize(
    "arrays, match",
    [
        ({"x0": np.ones((4, 2)), "x1": np.ones((3, 2)), "mu": np.ones((4, 1)), "dt": np.ones(4)}, "x1 has shape"),
        (
            {"x0": np.ones((4, 2)), "x1": np.ones((4, 2)), "mu": np.ones(4), "dt": np.ones(4)},
            r"mu must have shape \(4, d_mu\)",
        ),
        (
            {"x0": np.ones((4, 2)), "x1": np.ones((4, 2)), "mu": np.ones((4, 1)), "dt": np.zeros(4)},
            "dt must be positive",
        ),
        (
            {"x0": np.full((4, 2), np.nan), "x1": np.ones((4, 2)), "mu": np.ones((4, 1)), "dt": np.ones(4)},
            "x0 contains NaN",
        ),
        (
            {"x0": np.ones((4, 3)), "x1": np.ones((4, 3)), "mu": np.ones((4, 1)), "dt": np.ones(4)},
            r"x0 must have shape \(M, 2n\)",
        ),
        ({"x0": np.ones((4, 2)), "x1": np.ones((4, 2)), "dt": np.ones(4)}, r"missing arrays \['mu'\]"),
        (
            {"x0": np.ones((4, 2)), "x1": np.ones((4, 2)), "mu": np.ones((4, 1)), "dt": np.ones((4, 1))},
            r"dt must have shape \(4,\)",
        ),
        (
            {"x0": np.ones((4, 2)), "x1": np.ones((4, 2)), "mu": np.ones((4, 1)), "dt": np.ones(4), "y": np.ones(1)},
            "unexpected arrays",
        ),
    ],
)
def test_inconsistent_datasets_are_refused(tmp_path, arrays, match):
    path = tmp_path / "d.h5"
    write_container(path, "sympredict-dataset", {"metadata": {}}, arrays)
    with pytest.raises(ModelFileError, match=match):
        load_dataset(path)


# ------------------------------------------------------------------ saving
def test_special_files_are_never_replaced(tmp_path):
    fifo = tmp_path / "fifo.h5"
    os.mkfifo(fifo)
    with deadline(), pytest.raises(ValueError, match="it is a FIFO, not a regular file"):
        write_container(fifo, FMT, SETTINGS, ARRAYS)
    assert stat.S_ISFIFO(os.stat(fifo).st_mode)
    try:  # a device node of our own where we may (root), else the system's (which we cannot replace)
        device = tmp_path / "null"
        os.mknod(device, stat.S_IFCHR | 0o666, os.makedev(1, 3))
    except PermissionError:
        device = os.devnull
    with pytest.raises(ValueError, match="character device, not a regular file"):
        write_container(device, FMT, SETTINGS, ARRAYS)
    assert stat.S_ISCHR(os.stat(device).st_mode)
    with pytest.raises(ValueError, match="is a directory"):
        write_container(tmp_path, FMT, SETTINGS, ARRAYS)
    link = tmp_path / "to_fifo.h5"
    link.symlink_to(fifo)
    with pytest.raises(ValueError, match="FIFO"):
        write_container(link, FMT, SETTINGS, ARRAYS)
    assert link.is_symlink() and stat.S_ISFIFO(os.stat(fifo).st_mode)
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(
        ["fifo.h5", "to_fifo.h5"] + (["null"] if device != os.devnull else [])
    )


def test_saving_writes_through_symlinks(tmp_path):
    real = tmp_path / "store" / "model.h5"
    real.parent.mkdir()
    real.write_bytes(b"old")
    link = tmp_path / "model.h5"
    link.symlink_to(real)
    write_container(link, FMT, SETTINGS, ARRAYS)
    assert link.is_symlink() and os.readlink(link) == str(real)
    assert read_container(real, FMT)[0] == SETTINGS
    dangling = tmp_path / "new.h5"
    dangling.symlink_to(tmp_path / "store" / "new_target.h5")
    write_container(dangling, FMT, SETTINGS, ARRAYS)
    assert dangling.is_symlink() and (tmp_path / "store" / "new_target.h5").is_file()
    loop = tmp_path / "loop.h5"
    loop.symlink_to(loop)
    with pytest.raises(ValueError, match="cannot be resolved"):
        write_container(loop, FMT, SETTINGS, ARRAYS)


def test_new_files_honour_the_umask_and_overwrites_keep_the_mode(tmp_path):
    old = os.umask(0o022)
    try:
        write_container(tmp_path / "a.h5", FMT, SETTINGS, ARRAYS)
        os.umask(0o077)
        write_container(tmp_path / "b.h5", FMT, SETTINGS, ARRAYS)
        os.chmod(tmp_path / "a.h5", 0o640)
        write_container(tmp_path / "a.h5", FMT, SETTINGS, ARRAYS)  # umask 077 now, but the file keeps 0640
    finally:
        os.umask(old)
    assert stat.S_IMODE(os.stat(tmp_path / "b.h5").st_mode) == 0o600
    assert stat.S_IMODE(os.stat(tmp_path / "a.h5").st_mode) == 0o640
    old = os.umask(0o022)
    try:
        write_container(tmp_path / "c.h5", FMT, SETTINGS, ARRAYS)
    finally:
        os.umask(old)
    assert stat.S_IMODE(os.stat(tmp_path / "c.h5").st_mode) == 0o644


def test_disk_full_is_one_oserror_and_keeps_the_previous_file(tmp_path, monkeypatch, capfd):
    path = good(tmp_path)
    before = path.read_bytes()
    calls = []
    real_write = os.write

    def full(fd, data):  # a short write of 100 bytes, then the disk is full
        calls.append(len(data))
        if len(calls) == 1:
            return real_write(fd, bytes(data[:100]))
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(container.os, "write", full)
    with pytest.raises(
        OSError, match="could not save .*No space left on device; the previous file, if any, is unchanged"
    ) as info:
        write_container(path, FMT, dict(SETTINGS, n=4), {"a": np.ones(1000)})
    assert info.value.errno == errno.ENOSPC and len(calls) == 2
    monkeypatch.undo()
    assert path.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["c.h5"]
    captured = capfd.readouterr()
    assert captured.out == "" and captured.err == ""


def test_real_write_failure_in_a_fresh_process_is_one_line(tmp_path):
    """A real short write (file-size limit, EFBIG, as on a full disk): one line, clean exit, no temp file, old file intact."""
    path = good(tmp_path)
    before = path.read_bytes()
    script = f"""
import resource, signal, sys
import numpy as np
from sympredict.container import write_container
signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
resource.setrlimit(resource.RLIMIT_FSIZE, (65536, resource.RLIM_INFINITY))
try:
    write_container({str(path)!r}, "x", {{}}, {{"big": np.ones(10**6)}})
except OSError as exc:
    print(f"error: {{exc}}", file=sys.stderr)
    sys.exit(3)
"""
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 3, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "could not save" in lines[0] and "previous file" in lines[0], proc.stderr
    assert path.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["c.h5"]


def test_interrupted_write_leaves_no_temp_file(tmp_path, monkeypatch):
    path = good(tmp_path)
    before = path.read_bytes()

    def interrupted(fd, data):
        raise KeyboardInterrupt

    monkeypatch.setattr(container.os, "write", interrupted)
    with pytest.raises(KeyboardInterrupt):
        write_container(path, FMT, SETTINGS, {"a": np.ones(10)})
    monkeypatch.undo()
    assert path.read_bytes() == before and [p.name for p in tmp_path.iterdir()] == ["c.h5"]


def test_stale_temp_files_of_killed_saves_are_removed(tmp_path):
    now = time.time()
    dead = dead_pid()
    files = {
        f".c.h5.{dead}-0123abcd.tmp": (now - 2 * container.STALE_GRACE_S, False),  # dead owner, old enough: removed
        f".c.h5.{dead}-89abcdef.tmp": (now - 1, True),  # dead owner but fresh (grace period): kept
        f".c.h5.{os.getpid()}-00000000.tmp": (now - 3600, True),  # live owner: kept
        f".c.h5.{os.getpid()}-11111111.tmp": (now - 2 * container.STALE_MAX_AGE_S, False),  # ancient: removed
        ".c.h5.k2j4_x9q.tmp": (now - 2 * container.STALE_MAX_AGE_S, False),  # former mkstemp naming, ancient: removed
        ".c.h5.k2j4_x9z.tmp": (now - 3600, True),  # former naming, not ancient: kept
        f".other.h5.{dead}-0123abcd.tmp": (now - 3600, True),  # another target's: kept
        f".c.h5.{dead}-0123abcd.tmp.keep": (now - 3600, True),  # not our pattern: kept
        "c.h5.tmp": (now - 3600 * 48, True),  # not ours: kept
    }
    for name, (mtime, _) in files.items():
        (tmp_path / name).write_bytes(b"partial")
        os.utime(tmp_path / name, (mtime, mtime))
    good(tmp_path)
    left = {p.name for p in tmp_path.iterdir()}
    assert left == {"c.h5"} | {name for name, (_, kept) in files.items() if kept}


def test_same_content_gives_identical_bytes(tmp_path, small_pendulum_model):
    a, b = tmp_path / "a.h5", tmp_path / "b.h5"
    write_container(a, FMT, SETTINGS, ARRAYS)
    time.sleep(1.1)  # HDF5 timestamps have one-second resolution
    write_container(b, FMT, SETTINGS, ARRAYS)
    assert a.read_bytes() == b.read_bytes()
    small_pendulum_model.save(a)
    time.sleep(1.1)
    small_pendulum_model.save(b)
    assert a.read_bytes() == b.read_bytes()
    script = (
        f"import numpy as np; from sympredict.container import write_container; "
        f"write_container({str(tmp_path / 'c.h5')!r}, {FMT!r}, {SETTINGS!r}, "
        f"{{'a': np.arange(12.0).reshape(3, 4), 'i': np.arange(5, dtype=np.int64), 's': np.asarray(2.5), 'e': np.zeros((0, 3))}})"
    )
    write_container(a, FMT, SETTINGS, ARRAYS)
    subprocess.run([sys.executable, "-c", script], check=True, timeout=120)
    assert (tmp_path / "c.h5").read_bytes() == a.read_bytes()  # another process, another time


def test_unsavable_content_is_refused_before_touching_the_disk(tmp_path):
    with pytest.raises(ValueError, match="JSON-serializable"):
        write_container(tmp_path / "x.h5", FMT, {"a": np.float32(1)}, ARRAYS)
    with pytest.raises(ValueError, match="must be numeric"):
        write_container(tmp_path / "x.h5", FMT, SETTINGS, {"o": np.array([object()])})
    with pytest.raises(ValueError, match="without '/'"):
        write_container(tmp_path / "x.h5", FMT, SETTINGS, {"a/b": np.ones(2)})
    with pytest.raises(ValueError, match="does not exist"):
        write_container(tmp_path / "nowhere" / "x.h5", FMT, SETTINGS, ARRAYS)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.slow
@pytest.mark.parametrize("schema", [2, 1])
def test_every_byte_damaged(tmp_path, schema):
    """The full byte sweep of docs/reference/errors.md: every byte set to 0x00, 0xFF and a random value (minutes)."""
    path = good(tmp_path) if schema == 2 else write_v1(tmp_path / "v1.h5")
    original = path.read_bytes()
    damaged = tmp_path / "damaged.h5"
    rng = np.random.default_rng(1)
    counts = {"refused": 0, "intact": 0}
    for pos in range(len(original)):
        for value in (0x00, 0xFF, int(rng.integers(256))):
            data = bytearray(original)
            if data[pos] == value:
                continue
            data[pos] = value
            damaged.write_bytes(bytes(data))
            try:
                settings, arrays = read_container(damaged, FMT)
            except ModelFileError:
                counts["refused"] += 1
                continue
            assert schema == 1 or settings == SETTINGS, pos  # schema 1's checksum does not cover its settings
            assert all(np.array_equal(arrays[k], v) for k, v in ARRAYS.items()), pos
            counts["intact"] += 1
    print(f"schema {schema}: {len(original)} bytes, {counts}")
