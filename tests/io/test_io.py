"""Data-set files and atomic saving."""

import numpy as np
import pytest

from sympredict.exceptions import extrapolation_expected
from sympredict import ModelFileError
from sympredict.io import load_dataset, save_dataset
from _tolerances import assert_same_predictions  # tests/


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


def test_model_roundtrip_keeps_predictions_and_history(tmp_path):
    """Everything a saved model reports comes back: predictions bit for bit, the greedy's curves and stop reason."""
    from sympredict import SymplecticKernelPredictor
    from sympredict.kernels import IMQ
    from sympredict.systems.pendulum import Pendulum, flow_map_data, random_flow_map_data

    data = flow_map_data(Pendulum(), mus=(0.7, 0.8), dts=(0.04, 0.06), n_grid=8)
    val = random_flow_map_data(Pendulum(), 40, seed=1)
    model = SymplecticKernelPredictor(IMQ(0.3), IMQ(2.0), IMQ(5.0), max_centers=30).fit(
        data.x0, data.x1, mu=data.mu, dt=data.dt, validation=val
    )
    path = tmp_path / "model.h5"
    model.save(path)
    loaded = SymplecticKernelPredictor.load(path)
    for name in ("train_max_residual", "val_max_residual", "selected_power"):
        got, expected = getattr(loaded.history_, name), getattr(model.history_, name)
        assert got is not None and expected is not None, name
        np.testing.assert_array_equal(got, expected, err_msg=name)
    # wall-clock timings stay out of files (a file is byte-for-byte reproducible): loaded as NaN, one per step
    assert loaded.history_.elapsed.shape == model.history_.elapsed.shape and np.all(np.isnan(loaded.history_.elapsed))
    assert loaded.history_.stop_reason == model.history_.stop_reason
    assert loaded.n_centers_ == model.n_centers_ and loaded.kernel_ == model.kernel_
    x = data.x0[:5]
    with extrapolation_expected():  # a round trip, not accuracy: 30 centres may drift off the training states
        assert_same_predictions(loaded, model, x, 3, mu=0.75, dt=0.05)
