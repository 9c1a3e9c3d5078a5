"""Data-set files and atomic saving."""

import numpy as np
import pytest

from sympredict import ModelFileError
from sympredict.io import load_dataset, save_dataset


def test_dataset_roundtrip(small_pendulum_data, tmp_path):
    path = tmp_path / "data.h5"
    save_dataset(small_pendulum_data, path, system="pendulum", n_grid=20)
    data, meta = load_dataset(path)
    for name in ("x0", "x1", "mu", "dt"):
        np.testing.assert_array_equal(getattr(data, name), getattr(small_pendulum_data, name))
    assert meta == {"system": "pendulum", "n_grid": 20}


def test_model_file_is_not_a_dataset(small_pendulum_model, tmp_path):
    path = tmp_path / "model.h5"
    small_pendulum_model.save(path)
    with pytest.raises(ModelFileError, match="expected 'sympredict-dataset'"):
        load_dataset(path)


def test_failed_save_keeps_previous_file(small_pendulum_data, tmp_path, monkeypatch):
    path = tmp_path / "data.h5"
    save_dataset(small_pendulum_data, path)
    before = path.read_bytes()
    import sympredict.container as io_module

    def broken_replace(src, dst):
        raise KeyboardInterrupt  # an interruption right before the rename

    monkeypatch.setattr(io_module.os, "replace", broken_replace)
    with pytest.raises(KeyboardInterrupt):
        save_dataset(small_pendulum_data.subset(slice(0, 3)), path)
    assert path.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["data.h5"]
    with pytest.raises(ValueError, match="does not exist"):
        save_dataset(small_pendulum_data, tmp_path / "nowhere" / "d.h5")
