"""``sympredict-paper run``: runs that fail or are interrupted never pass for complete ones; outputs checked before
work; one-line errors."""

import json
import os
import subprocess
import sys
import time

import numpy as np
import pytest

from sympredict_paper import report, runner
from sympredict_paper.cli import main
from sympredict_paper.runner import RUN_MARKER

from _cli import assert_refused_in_one_line  # tests/

#: the paper's command in a child process
PAPER = [sys.executable, "-m", "sympredict_paper"]
#: the pendulum scenario's smoke run (``--out`` follows)
SMOKE = ["run", "pendulum", "--preset", "smoke"]


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
    monkeypatch.setattr(report, "claims", lambda results: [])

    def use(fail=None):
        monkeypatch.setattr(runner, "_run_pendulum", fake_runner(fail))

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
    assert main([*SMOKE, "--out", str(out), "--threads", "1"]) == 0
    marker = json.loads((out / RUN_MARKER).read_text())
    assert marker["complete"] is True and marker["systems"] == ["pendulum"]
    assert (
        set(marker["files"]) == {"fake_model.h5", "results.json", "summary.md"} == set(os.listdir(out)) - {RUN_MARKER}
    )
    assert "old run" not in (out / "summary.md").read_text()  # nothing of the old run is mixed in
    assert os.listdir(tmp_path) == ["results"]  # no staging or old folder left


@pytest.mark.parametrize(
    "fail, code", [(KeyboardInterrupt(), 130), (ValueError("bad"), 1), (OSError(28, "No space left on device"), 1)]
)
def test_failed_or_interrupted_run_leaves_the_previous_run_untouched(tmp_path, fake_run, capsys, fail, code):
    out = tmp_path / "results"
    before = previous_run(out)
    fake_run(fail)
    assert main([*SMOKE, "--out", str(out), "--threads", "1"]) == code
    assert contents(out) == before
    assert os.listdir(tmp_path) == ["results"]
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err


def test_failed_first_run_leaves_no_folder(tmp_path, fake_run, capsys):
    fake_run(KeyboardInterrupt())
    assert main([*SMOKE, "--out", str(tmp_path / "new" / "results")]) == 130
    assert not (tmp_path / "new" / "results").exists()
    assert os.listdir(tmp_path / "new") == []


def test_killed_run_in_a_child_process_leaves_nothing_that_passes_for_complete(tmp_path):
    """SIGKILL in the middle of a real run: --out never appears; the next run removes the staging folder."""
    out = tmp_path / "results"
    proc = subprocess.Popen(
        [*PAPER, *SMOKE, "--out", str(out), "--threads", "1"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
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
    runner._remove_stale_staging(tmp_path, "results")  # what the next run does first
    assert not stale.exists()


def test_run_output_is_checked_before_any_work(tmp_path, monkeypatch, capsys):
    def never(*args):
        raise AssertionError("the work started before --out was checked")

    monkeypatch.setattr(runner, "_run_pendulum", never)
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
        assert main([*SMOKE, "--out", str(out)]) == 1
        err = capsys.readouterr().err
        assert match in err and len(err.strip().splitlines()) == 1, err
    monkeypatch.chdir(foreign)
    assert main([*SMOKE, "--out", "."]) == 1
    assert "current directory" in capsys.readouterr().err
    assert afile.read_text() == "keep me" and (foreign / "thesis.tex").read_text() == "keep me too"


def test_smoke_run_is_marked_complete(smoke_run):
    folder, results, _ = smoke_run
    marker = json.loads((folder / RUN_MARKER).read_text())
    assert marker["complete"] is True and set(marker["files"]) == set(os.listdir(folder)) - {RUN_MARKER}
    assert not [p for p in folder.parent.iterdir() if ".partial-" in p.name or ".old-" in p.name]
    assert np.isfinite(results["results"]["pendulum"]["E_train"])


def test_cli_rejects_unknown_system(tmp_path):
    proc = subprocess.run(
        [*PAPER, "run", "nosuchsystem", "--out", str(tmp_path)],
        capture_output=True,
        text=True,
    )
    assert proc.returncode == 2 and "invalid choice" in proc.stderr


def test_cli_user_errors_are_one_line_without_traceback(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    proc = subprocess.run(
        [*PAPER, *SMOKE, "--out", str(blocker / "sub")],
        capture_output=True,
        text=True,
    )
    assert proc.returncode == 1
    assert proc.stderr.strip().startswith("sympredict-paper: error:") and "Traceback" not in proc.stderr
    proc = subprocess.run(
        [*PAPER, "run", "pendulum", "--preset", "huge", "--out", str(tmp_path)],
        capture_output=True,
        text=True,
    )
    assert proc.returncode == 2 and "invalid choice" in proc.stderr and "Traceback" not in proc.stderr


@pytest.mark.parametrize(
    "argv",
    [
        ["run", "pendulum", "--out", "x", "--threads", "0"],
        ["run", "pendulum", "--out", "x", "--threads", "-2"],
        ["run", "pendulum", "--out", "x", "--seed", "-1"],
    ],
)
def test_nonsense_numbers_are_refused_by_the_parser_in_one_line(argv, capsys):
    assert_refused_in_one_line(main, argv, capsys)


@pytest.mark.parametrize(
    "module, system",
    [("pendulum", "pendulum"), ("wave", "wave"), ("henon_heiles", "henon-heiles"), ("sine_gordon", "sine-gordon")],
)
def test_each_scenario_has_its_own_main(module, system, tmp_path, monkeypatch, capsys):
    """``python -m sympredict_paper.<scenario> ...`` is ``sympredict-paper run <scenario> ...``: the scenario's runner
    writes into the folder given, and a bad option is refused by the parser (exit 2) before any work."""
    import importlib

    monkeypatch.setattr(report, "claims", lambda results: [])
    ran = []

    def fake(preset_name, seed, out):
        ran.append((preset_name, seed))
        return {"value": 1.0}, [], ["## fake"]

    monkeypatch.setattr(runner, "_run_" + module, fake)
    scenario = importlib.import_module(f"sympredict_paper.{module}")
    assert scenario.main(["--preset", "smoke", "--seed", "3", "--out", str(tmp_path / "out"), "--threads", "1"]) == 0
    assert ran == [("smoke", 3)]
    assert json.loads((tmp_path / "out" / "results.json").read_text())["results"] == {system: {"value": 1.0}}
    with pytest.raises(SystemExit) as info:
        scenario.main(["--out", str(tmp_path / "x"), "--threads", "0"])
    assert info.value.code == 2 and "sympredict-paper run: error: argument --threads" in capsys.readouterr().err


def test_study_runs_a_script_of_the_studies_folder(capsys):
    """``sympredict-paper study NAME ARGS`` runs ``sympredict_paper/studies/NAME.py`` with ``ARGS`` (here ``--help``:
    the study's own usage, exit 0); an unknown study is refused by the parser; the helpers are no studies."""
    from sympredict_paper.cli import STUDIES, study_names

    names = study_names()
    assert "pendulum_accuracy" in names and "defaults_acceptance" in names and "_protocol" not in names
    assert sorted(names) == sorted(p.stem for p in STUDIES.glob("[!_]*.py"))
    argv, path = list(sys.argv), list(sys.path)
    assert main(["study", "three_body_growth", "--help"]) == 0
    assert "usage: three_body_growth.py" in capsys.readouterr().out
    assert sys.argv == argv and sys.path == path  # left as found
    with pytest.raises(SystemExit) as info:
        main(["study", "no_such_study"])
    assert info.value.code == 2 and "invalid choice" in capsys.readouterr().err


def test_the_paper_command_is_installed_beside_the_library_command():
    from importlib.metadata import entry_points

    scripts = {e.name: e.value for e in entry_points(group="console_scripts") if e.name.startswith("sympredict")}
    assert scripts == {"sympredict": "sympredict.cli:main", "sympredict-paper": "sympredict_paper.cli:main"}
    proc = subprocess.run([*PAPER, "--help"], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0 and "{run,study}" in proc.stdout
