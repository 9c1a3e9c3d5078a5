"""Runs that fail or are interrupted never pass for complete ones; outputs checked before work; one-line errors (issue 16)."""

import json
import os
import subprocess
import sys
import time

import h5py
import numpy as np
import pytest

from sympredict import cli
from sympredict.cli import RUN_MARKER, main


def fake_runner(fail=None):
    """A stand-in for a scenario runner: writes a file into the run folder, then returns or fails."""

    def run(preset_name, seed, out):
        (out / "fake_model.h5").write_bytes(b"new")
        if fail is not None:
            raise fail
        return {"value": 1.0}, ["fake.png"], ["## fake"]

    return run


@pytest.fixture
def fake_run(monkeypatch):
    monkeypatch.setattr(cli.report, "claims", lambda results: [])

    def use(fail=None):
        monkeypatch.setattr(cli, "_run_pendulum", fake_runner(fail))

    return use


def previous_run(folder):
    folder.mkdir()
    (folder / "summary.md").write_text("old run\n")
    (folder / "results.json").write_text("{}")
    (folder / RUN_MARKER).write_text(json.dumps({"complete": True}))
    return {p.name: p.read_bytes() for p in folder.iterdir()}


def contents(folder):
    return {p.name: p.read_bytes() for p in folder.iterdir()}


def test_completed_run_has_the_marker_and_replaces_a_previous_run(tmp_path, fake_run, capsys):
    out = tmp_path / "results"
    previous_run(out)
    fake_run()
    assert main(["run", "pendulum", "--preset", "smoke", "--out", str(out), "--threads", "1"]) == 0
    marker = json.loads((out / RUN_MARKER).read_text())
    assert marker["complete"] is True and marker["systems"] == ["pendulum"]
    assert set(marker["files"]) == {"fake_model.h5", "results.json", "summary.md"} == set(os.listdir(out)) - {RUN_MARKER}
    assert "old run" not in (out / "summary.md").read_text()  # nothing of the old run is mixed in
    assert os.listdir(tmp_path) == ["results"]  # no staging or old folder left


@pytest.mark.parametrize("fail, code", [(KeyboardInterrupt(), 130), (ValueError("bad"), 1), (OSError(28, "No space left on device"), 1)])
def test_failed_or_interrupted_run_leaves_the_previous_run_untouched(tmp_path, fake_run, capsys, fail, code):
    out = tmp_path / "results"
    before = previous_run(out)
    fake_run(fail)
    assert main(["run", "pendulum", "--preset", "smoke", "--out", str(out), "--threads", "1"]) == code
    assert contents(out) == before
    assert os.listdir(tmp_path) == ["results"]
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err


def test_failed_first_run_leaves_no_folder(tmp_path, fake_run, capsys):
    fake_run(KeyboardInterrupt())
    assert main(["run", "pendulum", "--preset", "smoke", "--out", str(tmp_path / "new" / "results")]) == 130
    assert not (tmp_path / "new" / "results").exists()
    assert os.listdir(tmp_path / "new") == []


def test_killed_run_in_a_child_process_leaves_nothing_that_passes_for_complete(tmp_path):
    """SIGKILL in the middle of a real run: --out never appears; the next run removes the staging folder."""
    out = tmp_path / "results"
    proc = subprocess.Popen([sys.executable, "-m", "sympredict.cli", "run", "pendulum", "--preset", "smoke", "--out", str(out),
                             "--threads", "1"], stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    deadline = time.time() + 120
    staging = []
    while time.time() < deadline and not staging:  # wait until the run has started writing
        staging = [p for p in tmp_path.iterdir() if p.name.startswith(".results.partial-") and any(p.iterdir())]
        time.sleep(0.2)
    proc.kill()
    proc.wait()
    assert staging, "the run never started writing"
    assert not out.exists()
    stale = staging[0]
    old = time.time() - 3600
    os.utime(stale, (old, old))
    cli._remove_stale_staging(tmp_path, "results")  # what the next run does first
    assert not stale.exists()


def test_run_output_is_checked_before_any_work(tmp_path, monkeypatch, capsys):
    def never(*args):
        raise AssertionError("the work started before --out was checked")

    monkeypatch.setattr(cli, "_run_pendulum", never)
    afile = tmp_path / "file"
    afile.write_text("keep me")
    foreign = tmp_path / "mine"
    foreign.mkdir()
    (foreign / "thesis.tex").write_text("keep me too")
    cases = [
        (afile, "exists and is not a directory"),
        (afile / "sub", "is not a directory"),
        (foreign, "not the output folder of a previous run"),
        (tmp_path, "not the output folder of a previous run"),
    ]
    for out, match in cases:
        assert main(["run", "pendulum", "--preset", "smoke", "--out", str(out)]) == 1
        err = capsys.readouterr().err
        assert match in err and len(err.strip().splitlines()) == 1, err
    monkeypatch.chdir(foreign)
    assert main(["run", "pendulum", "--preset", "smoke", "--out", "."]) == 1
    assert "current directory" in capsys.readouterr().err
    assert afile.read_text() == "keep me" and (foreign / "thesis.tex").read_text() == "keep me too"


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
        (["predict", str(model), "--x0", "1,0", "--steps", "2", "--mu", "0.75", "--dt", "0.05", "--out", str(model)], "is also an input"),
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
        ["run", "pendulum", "--out", "x", "--threads", "0"],
        ["run", "pendulum", "--out", "x", "--threads", "-2"],
        ["run", "pendulum", "--out", "x", "--seed", "-1"],
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
    with pytest.raises(SystemExit) as info:
        main(argv)
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "error: argument" in err, err


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
    for argv in (["report", str(hostile)], ["train", str(hostile), "--out", str(tmp_path / "m.h5")], ["report", str(damaged)],
                 ["predict", str(fifo), "--x0", "1,0", "--steps", "1"], ["report", os.devnull]):
        assert main(argv) == 1, argv
        captured = capfd.readouterr()
        lines = captured.err.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("sympredict: error: ") and captured.out == "", (argv, captured)
    proc = subprocess.run([sys.executable, "-m", "sympredict.cli", "report", str(damaged)], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 1 and len(proc.stderr.strip().splitlines()) == 1 and proc.stdout == ""


def test_smoke_run_is_marked_complete(smoke_run):
    folder, results, _ = smoke_run
    marker = json.loads((folder / RUN_MARKER).read_text())
    assert marker["complete"] is True and set(marker["files"]) == set(os.listdir(folder)) - {RUN_MARKER}
    assert not [p for p in folder.parent.iterdir() if ".partial-" in p.name or ".old-" in p.name]
    assert np.isfinite(results["results"]["pendulum"]["E_train"])
