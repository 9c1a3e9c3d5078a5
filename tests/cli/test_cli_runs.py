"""Outputs checked before work; one-line errors (issue 16)."""

import os
import subprocess
import sys
import time

import h5py
import pytest

from sympredict.cli import main

from _cli import assert_refused_in_one_line  # tests/


def test_outputs_equal_to_inputs_and_special_outputs_are_refused(tmp_path, capsys):
    data, model = tmp_path / "d.h5", tmp_path / "m.h5"
    assert main(["data", "--n-grid", "8", "--out", str(data)]) == 0
    assert main(["train", str(data), "--centers", "20", "--out", str(model), "--threads", "1"]) == 0
    capsys.readouterr()
    before = {p: p.read_bytes() for p in (data, model)}
    link = tmp_path / "alias.h5"
    link.symlink_to(data)
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    cases = [
        (["train", str(data), "--out", str(data)], "is also an input"),
        (["train", str(data), "--out", str(link)], "is also an input"),
        (["train", str(data), "--validation", str(model), "--out", str(model)], "is also an input"),
        (
            ["predict", str(model), "--x0", "1,0", "--steps", "2", "--mu", "0.75", "--dt", "0.05", "--out", str(model)],
            "is also an input",
        ),
        (["data", "--out", str(fifo)], "FIFO"),
        (["data", "--out", str(tmp_path)], "is a directory"),
        (["data", "--out", str(tmp_path / "no" / "d.h5")], "does not exist"),
        (["train", str(data), "--out", str(tmp_path)], "is a directory"),
    ]
    for argv, match in cases:
        t0 = time.perf_counter()
        assert main(argv) == 1, argv
        err = capsys.readouterr().err
        assert match in err and len(err.strip().splitlines()) == 1, (argv, err)
        assert time.perf_counter() - t0 < 5, f"{argv}: refused only after the work"
    assert all(p.read_bytes() == b for p, b in before.items())


@pytest.mark.parametrize(
    "argv",
    [
        ["data", "--out", "x.h5", "--n-grid", "1"],
        ["data", "--out", "x.h5", "--random", "-5"],
        ["train", "d.h5", "--out", "m.h5", "--centers", "0"],
        ["train", "d.h5", "--out", "m.h5", "--tol", "nan"],
        ["train", "d.h5", "--out", "m.h5", "--tol", "-1"],
        ["train", "d.h5", "--out", "m.h5", "--threads", "two"],
        ["predict", "m.h5", "--x0", "1,0", "--steps", "-1"],
        ["predict", "m.h5", "--x0", "1,0", "--steps", "3", "--dt", "0"],
        ["predict", "m.h5", "--x0", "1,0", "--steps", "3", "--dt", "inf"],
        ["predict", "m.h5", "--x0", "1,0", "--steps", "3", "--mu", "nan"],
    ],
)
def test_nonsense_numbers_are_refused_by_the_parser_in_one_line(argv, capsys):
    assert_refused_in_one_line(main, argv, capsys)


def test_hostile_files_reaching_the_cli_are_one_line(tmp_path, capfd):
    """Every ModelFileError/ValueError/OSError in main is one line on stderr, nothing from HDF5 or Python besides."""
    hostile = tmp_path / "hostile.h5"
    assert main(["data", "--n-grid", "8", "--out", str(hostile)]) == 0
    with h5py.File(hostile, "r+") as f:
        f["arrays/x"] = h5py.ExternalLink("/etc/passwd", "/")
    damaged = tmp_path / "damaged.h5"
    damaged.write_bytes(hostile.read_bytes()[:1500])
    fifo = tmp_path / "fifo.h5"
    os.mkfifo(fifo)
    capfd.readouterr()
    for argv in (
        ["report", str(hostile)],
        ["train", str(hostile), "--out", str(tmp_path / "m.h5")],
        ["report", str(damaged)],
        ["predict", str(fifo), "--x0", "1,0", "--steps", "1"],
        ["report", os.devnull],
    ):
        assert main(argv) == 1, argv
        captured = capfd.readouterr()
        lines = captured.err.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("sympredict: error: ") and captured.out == "", (argv, captured)
    proc = subprocess.run(
        [sys.executable, "-m", "sympredict.cli", "report", str(damaged)], capture_output=True, text=True, timeout=120
    )
    assert proc.returncode == 1 and len(proc.stderr.strip().splitlines()) == 1 and proc.stdout == ""
