"""No lost work: output paths are checked (length, existence, permissions) before training, and a model whose save
fails is kept."""

import os
from pathlib import Path

import pytest

from sympredict import SymplecticKernelPredictor
from sympredict.container import check_save_path


def test_container_saves_under_the_longest_valid_name(coarse_pendulum_model, tmp_path):
    """A 255-byte name: the temporary sibling was longer than the limit, so the save failed after the work."""
    name = "m" * 252 + ".h5"
    coarse_pendulum_model.save(tmp_path / name)
    assert SymplecticKernelPredictor.load(tmp_path / name).n_centers_ == coarse_pendulum_model.n_centers_
    assert sorted(p.name for p in tmp_path.iterdir()) == [name]


def test_names_beyond_the_limit_are_refused_before_work(tmp_path):
    with pytest.raises(ValueError, match="bytes long"):
        check_save_path(tmp_path / ("m" * 256 + ".h5"))


@pytest.fixture(scope="module")
def data_file(tmp_path_factory):
    from sympredict.cli import main

    path = tmp_path_factory.mktemp("cli") / "data.h5"
    assert main(["data", "--n-grid", "8", "--out", str(path)]) == 0
    return path


def test_cli_train_with_a_255_byte_name(data_file, tmp_path):
    from sympredict.cli import main

    out = tmp_path / ("t" * 252 + ".h5")
    assert main(["train", str(data_file), "--centers", "10", "--out", str(out), "--threads", "1"]) == 0
    assert out.exists()


def test_cli_train_refuses_an_existing_file_before_training(data_file, tmp_path, capsys):
    from sympredict.cli import main

    out = tmp_path / "model.h5"
    out.write_bytes(b"precious")
    assert main(["train", str(data_file), "--centers", "10", "--out", str(out), "--threads", "1"]) == 1
    assert "--force" in capsys.readouterr().err and out.read_bytes() == b"precious"
    assert main(["train", str(data_file), "--centers", "10", "--out", str(out), "--threads", "1", "--force"]) == 0
    assert SymplecticKernelPredictor.load(out).n_centers_ == 10


def test_cli_predict_out_refuses_an_existing_file(coarse_pendulum_model_file, tmp_path, capsys):
    from sympredict.cli import main

    out = tmp_path / "traj.csv"
    out.write_text("keep")
    args = ["predict", str(coarse_pendulum_model_file), "--x0", "0.5,0.1", "--steps", "2", "--out", str(out)]
    assert main(args) == 1 and out.read_text() == "keep"
    assert "--force" in capsys.readouterr().err
    assert main(args + ["--force"]) == 0 and out.read_text().startswith("traj,t")


def test_cli_train_refuses_a_read_only_folder_before_training(data_file, tmp_path, capsys, monkeypatch):
    import sympredict.container as container
    from sympredict.cli import main

    folder = tmp_path / "ro"
    folder.mkdir()
    folder.chmod(0o500)
    if os.access(folder, os.W_OK):  # root: make the folder look read-only to the check
        monkeypatch.setattr(container.os, "access", lambda path, mode: False)
    fitted = []
    monkeypatch.setattr(SymplecticKernelPredictor, "fit", lambda self, *a, **k: fitted.append(1))
    try:
        assert main(["train", str(data_file), "--centers", "10", "--out", str(folder / "m.h5")]) == 1
        assert "permission" in capsys.readouterr().err and not fitted
    finally:
        folder.chmod(0o700)


def test_model_kept_when_saving_fails_after_training(coarse_pendulum_model, tmp_path, monkeypatch):
    from sympredict.cli import _files

    target = tmp_path / "m.h5"
    real_save = type(coarse_pendulum_model).save

    def failing_save(self, path):
        if Path(path) == target:
            raise OSError(28, "No space left on device")
        real_save(self, path)

    monkeypatch.setattr(type(coarse_pendulum_model), "save", failing_save)
    with pytest.raises(OSError, match="kept in") as info:
        _files._save_model_or_keep(coarse_pendulum_model, target)
    kept = [p for p in tmp_path.iterdir() if p.name.startswith("sympredict-model-")]
    assert len(kept) == 1 and str(kept[0]) in str(info.value)
    assert SymplecticKernelPredictor.load(kept[0]).n_centers_ == coarse_pendulum_model.n_centers_
