"""Users' trajectory and state files: parameter columns by name, .npz members checked before reading, CSV
bounded by what it parses, times rounded in the file."""

import io
import struct
import time
import zipfile
from pathlib import Path

import numpy as np
import pytest

from sympredict import cli
from sympredict.io.trajectories import MAX_CSV_LINE, read_states, read_trajectories


# --------------------------------------------------------------------------- parameter columns by name
def test_read_states_matches_parameter_columns_by_name(tmp_path):
    path = tmp_path / "x0.csv"
    path.write_text("q,p,mu2,mu1\n0.1,0.2,0.0802,0.5144\n0.3,0.4,0.1778,0.5188\n")
    x0, mu = read_states(path, 2)
    np.testing.assert_array_equal(mu, [[0.5144, 0.0802], [0.5188, 0.1778]])
    np.testing.assert_array_equal(x0, [[0.1, 0.2], [0.3, 0.4]])


def test_read_states_state_columns_in_any_order(tmp_path):
    path = tmp_path / "x0.csv"
    path.write_text("mu1,p2,q2,p1,q1\n7,4,2,3,1\n")
    x0, mu = read_states(path, 4)
    np.testing.assert_array_equal(x0, [[1, 2, 3, 4]])
    np.testing.assert_array_equal(mu, [[7]])


@pytest.mark.parametrize(
    "header, match", [("q,p,mu1,mu3", "without gaps"), ("q,p,mu,mu1", "both 'mu'"), ("q,p,mu2", "without gaps")]
)
def test_read_states_parameter_header_errors(tmp_path, header, match):
    path = tmp_path / "x0.csv"
    cells = ",".join(["0.5"] * len(header.split(",")))
    path.write_text(f"{header}\n{cells}\n")
    with pytest.raises(ValueError, match=match):
        read_states(path, 2)


def test_trajectory_csv_parameter_columns_by_name(tmp_path):
    path = tmp_path / "t.csv"
    path.write_text("traj,t,q,p,mu2,mu1\n" + "".join(f"a,{k},{k},{-k},20,10\n" for k in range(3)))
    data = read_trajectories(path)
    np.testing.assert_array_equal(data.mu, [[10, 20]])


# --------------------------------------------------------------------------- .npz declared shapes and members
def _npz_with_header(path: Path, shape, data: bytes, key="states", compress=zipfile.ZIP_STORED):
    header = io.BytesIO()
    np.lib.format.write_array_header_1_0(header, {"descr": "<f8", "fortran_order": False, "shape": shape})
    with zipfile.ZipFile(path, "w", compression=compress) as z:
        z.writestr(f"{key}.npy", header.getvalue() + data)
        buf = io.BytesIO()
        np.save(buf, np.float64(0.1))
        z.writestr("dt.npy", buf.getvalue())


@pytest.mark.parametrize(
    "shape, match",
    [
        ((-1, 2), "negative dimension"),
        ((0, 2), "holds no numbers"),
        ((2**62, 2**62, 4), "exceed max_bytes"),
        ((3, -5, 2), "negative dimension"),
    ],
)
def test_npz_declared_shapes_are_checked_before_reading(tmp_path, shape, match):
    path = tmp_path / "bad.npz"
    _npz_with_header(path, shape, b"\0" * 8 * 1000, compress=zipfile.ZIP_DEFLATED)
    t0 = time.perf_counter()
    with pytest.raises(ValueError, match=match) as info:
        read_trajectories(path)
    assert str(path) in str(info.value) and "'states'" in str(info.value)
    assert time.perf_counter() - t0 < 5


def test_npz_negative_shape_in_read_states(tmp_path):
    path = tmp_path / "x0.npz"
    _npz_with_header(path, (-1, 2), b"\0" * 64, key="x0")
    with pytest.raises(ValueError, match="negative dimension"):
        read_states(path, 2)


def _patch_method(path: Path, method: int = None, flag: int = None):
    raw = bytearray(path.read_bytes())
    for sig, off_flag, off_method in ((b"PK\x03\x04", 6, 8), (b"PK\x01\x02", 8, 10)):
        i = raw.find(sig)
        while i >= 0:
            if method is not None:
                raw[i + off_method : i + off_method + 2] = struct.pack("<H", method)
            if flag is not None:
                raw[i + off_flag : i + off_flag + 2] = struct.pack("<H", flag)
            i = raw.find(sig, i + 4)
    path.write_bytes(bytes(raw))


@pytest.mark.parametrize(
    "patch, match",
    [({"method": 9}, "Deflate64.*numpy.savez"), ({"flag": 1}, "encrypted")],
    ids=["deflate64", "encrypted"],
)
def test_npz_member_zipfile_cannot_read_is_a_clear_error(tmp_path, patch, match):
    """A Deflate64-compressed or an encrypted member (the npz patched into one) is refused with a clear message."""
    path = tmp_path / "member.npz"
    np.savez(path, states=np.ones((2, 3, 2)), dt=0.1)
    _patch_method(path, **patch)
    with pytest.raises(ValueError, match=match):
        read_trajectories(path)


# --------------------------------------------------------------------------- CSV bounded by what it parses
def test_csv_budget_counts_parsed_numbers_not_file_size(tmp_path):
    """Short cells take 2 bytes in the file and 8 parsed: a budget above the file size still refuses the file."""
    path = tmp_path / "t.csv"
    rows = "".join(f"{i % 7},{k % 10},1,2\n" for i in range(7) for k in range(100))
    path.write_text("traj,t,q,p\n" + rows.replace(",1,2", ",1,2"))
    size = path.stat().st_size
    with pytest.raises(ValueError, match="more than max_bytes"):
        read_trajectories(path, max_bytes=2 * size)


def test_csv_huge_cell_is_a_valueerror_naming_the_row(tmp_path):
    path = tmp_path / "t.csv"
    path.write_text("traj,t,q,p\na,0,1,2\na,1," + "1" * 200_000 + ",2\n")
    with pytest.raises(ValueError, match=r"row 3: not a valid CSV row \(field larger"):
        read_trajectories(path)


def test_csv_nul_byte_in_a_label_is_read_as_a_label(tmp_path):
    """A NUL byte in a trajectory label (a raw KeyError once: NumPy strings drop trailing NULs) is just a label."""
    path = tmp_path / "t.csv"
    path.write_text("traj,t,q,p\na\0,0,1,2\na,0,5,6\na\0,1,3,4\na,1,7,8\n")
    data = read_trajectories(path)
    np.testing.assert_array_equal(data.states, [[[1, 2], [3, 4]], [[5, 6], [7, 8]]])


def test_csv_line_longer_than_the_limit_is_refused_before_splitting(tmp_path):
    path = tmp_path / "t.csv"
    path.write_text("traj,t,q,p\n" + "," * (MAX_CSV_LINE + 10) + "\n")
    with pytest.raises(ValueError, match="longer than"):
        read_trajectories(path)


def test_cli_train_on_a_csv_with_a_huge_cell_is_one_line(tmp_path, capsys):
    path = tmp_path / "t.csv"
    path.write_text('traj,t,q,p\na,0,1,2\na,1,"' + "1" * 200_000 + '",2\n')
    code = cli.main(["train", str(path), "--out", str(tmp_path / "m.h5")])
    err = capsys.readouterr().err
    assert code == 1 and len(err.strip().splitlines()) == 1 and "row 3" in err and "Traceback" not in err


def test_csv_rows_in_any_order_keep_their_row_numbers(tmp_path):
    path = tmp_path / "t.csv"
    path.write_text("traj,t,q,p\nb,0,5,6\na,0,1,2\n\nb,1,7,8\na,0.5,3,4\na,0.2,3,4\nb,2,0,0\n")
    with pytest.raises(ValueError, match="row 7 has t = 0.2 after t = 0.5"):
        read_trajectories(path)


# --------------------------------------------------------------------------- rounded times
def _csv_times(path: Path, times):
    rows = "".join(
        f"{j},{t},{float(np.cos(float(t)))!r},{float(np.sin(float(t)))!r}\n" for j in range(2) for t in times
    )
    path.write_text("traj,t,q,p\n" + rows)


def test_times_rounded_to_six_decimals_are_uniform(tmp_path):
    h = 0.1 / 3
    _csv_times(tmp_path / "t.csv", [f"{k * h:.6f}" for k in range(30)])
    data = read_trajectories(tmp_path / "t.csv")
    assert data.dt is not None and abs(data.dt - h) <= 1e-6 / 29 + 1e-15


def test_times_jittered_beyond_their_decimals_stay_non_uniform(tmp_path):
    h = 0.1 / 3
    _csv_times(tmp_path / "t.csv", [f"{k * h + 3e-6 * (k % 2):.6f}" for k in range(30)])
    assert read_trajectories(tmp_path / "t.csv").dt is None


def test_unix_second_times_give_the_written_step(tmp_path):
    """Times such as 1700000000.01 parse with round-off of their magnitude: the step is the written 0.01."""
    _csv_times(tmp_path / "t.csv", [f"{1_700_000_000 + k * 0.01:.2f}" for k in range(300)])
    assert read_trajectories(tmp_path / "t.csv").dt == 0.01
