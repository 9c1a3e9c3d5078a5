"""The user's data in every natural form: TrajectoryData (times, strides), fit(data), duplicates, read_trajectories."""

import warnings
import zipfile

import h5py
import numpy as np
import pytest

from sympredict import DirectKernelPredictor, SymplecticKernelPredictor
from sympredict.data import FlowMapData, TrajectoryData, as_flowmap_data
from sympredict.exceptions import DuplicateSamplesWarning
from sympredict.io import read_trajectories, save_dataset
from sympredict.kernels import IMQ

EPS = np.finfo(float).eps


def oscillator_flow(x, omega, t):
    """Exact flow of H = (p^2 + omega^2 q^2) / 2 (n = 1); x (..., 2), omega and t broadcast against x[..., 0]."""
    q, p = x[..., 0], x[..., 1]
    c, s = np.cos(omega * t), np.sin(omega * t)
    return np.stack([q * c + p / omega * s, -omega * q * s + p * c], axis=-1)


def oscillator_trajectories(times, omega, x0):
    """States (P, K+1, 2) at ``times`` (P, K+1) from ``x0`` (P, 2) with frequencies ``omega`` (P,)."""
    return oscillator_flow(x0[:, None, :], omega[:, None], times)


@pytest.fixture
def uniform():
    rng = np.random.default_rng(0)
    omega = np.array([0.8, 1.0, 1.3])
    x0 = rng.uniform(-1, 1, (3, 2))
    dt = 0.1
    times = np.arange(9)[None, :] * dt * np.ones((3, 1))
    return TrajectoryData(oscillator_trajectories(times, omega, x0), omega, dt), omega


# --------------------------------------------------------------------------- TrajectoryData
def test_pairs_at_stride_s_are_the_exact_flow_over_s_dt(uniform):
    traj, omega = uniform
    d = traj.pairs(strides=[1, 3])
    assert len(d) == 3 * 8 + 3 * 6
    np.testing.assert_array_equal(d.dt, np.r_[np.full(24, 0.1), np.full(18, 3 * 0.1)])
    np.testing.assert_array_equal(d.mu[:, 0], np.r_[np.repeat(omega, 8), np.repeat(omega, 6)])
    # oracle: the closed-form flow from each x0 over the pair's dt
    np.testing.assert_allclose(d.x1, oscillator_flow(d.x0, d.mu[:, 0], d.dt), rtol=0, atol=64 * EPS)
    np.testing.assert_array_equal(traj.pairs(3).x0, d.x0[24:])


def test_default_pairs_keep_the_consecutive_states_in_order(uniform):
    traj, _ = uniform
    d = traj.pairs()
    np.testing.assert_array_equal(d.x0, traj.states[:, :-1].reshape(-1, 2))
    np.testing.assert_array_equal(d.x1, traj.states[:, 1:].reshape(-1, 2))
    assert traj.dt == 0.1 and traj.times.shape == (3, 9)


def test_non_uniform_times_give_each_pair_its_own_step():
    rng = np.random.default_rng(1)
    times = np.cumsum(rng.uniform(0.05, 0.2, (2, 6)), axis=1)
    omega = np.array([[1.0, 0.5], [1.2, 0.5]])  # d = 2: the frequency is the first component
    traj = TrajectoryData(oscillator_trajectories(times, omega[:, 0], rng.uniform(-1, 1, (2, 2))), omega, times=times)
    assert traj.dt is None and traj.mu.shape == (2, 2)
    d = traj.pairs(strides=(2, 1))
    np.testing.assert_array_equal(d.dt[:8], (times[:, 2:] - times[:, :-2]).reshape(-1))
    np.testing.assert_allclose(d.x1, oscillator_flow(d.x0, d.mu[:, 0], d.dt), rtol=0, atol=64 * EPS)


def test_decimal_times_that_are_uniform_to_round_off_give_one_step_per_stride():
    times = np.array([0.0, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7])  # 0.3 - 0.2 != 0.1 in floating point
    assert np.ptp(np.diff(times)) > 0
    traj = TrajectoryData(np.zeros((2, 8, 2)) + np.arange(8)[None, :, None], times=times)
    assert traj.dt == pytest.approx(0.1, rel=4 * EPS)
    assert len(np.unique(traj.pairs(strides=[1, 2]).dt)) == 2


def test_shared_times_and_broadcast_mu():
    traj = TrajectoryData(np.zeros((2, 3, 4)), mu=0.5, times=[0.0, 0.5, 2.0])
    assert traj.times.shape == (2, 3) and traj.mu.shape == (2, 1) and traj.dt is None


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"times": [[0.0, 0.1, 0.2], [0.0, 0.2, 0.2]]}, r"trajectory 1 has t\[1\] = 0.2 >= t\[2\] = 0.2"),
        ({"times": [0.0, -0.1, 0.2]}, r"increase strictly.*trajectory 0"),
        ({"times": [0.0, 0.1]}, r"times must have shape \(P, K\+1\) = \(2, 3\)"),
        ({"times": [0.0, np.nan, 0.2]}, "times contains NaN"),
        ({}, "exactly one of dt"),
        ({"dt": 0.1, "times": [0.0, 0.1, 0.2]}, "exactly one of dt"),
        ({"dt": -0.1}, "dt must be positive"),
    ],
)
def test_bad_times_are_refused_naming_the_trajectory(kwargs, message):
    with pytest.raises(ValueError, match=message):
        TrajectoryData(np.zeros((2, 3, 2)), **kwargs)


@pytest.mark.parametrize(
    "strides, message",
    [
        (0, "1..K = 1..8"),
        (9, "1..K = 1..8"),
        ([1, 1], "distinct"),
        (1.5, "positive integer"),
        ([], "positive integer"),
    ],
)
def test_bad_strides_are_refused(uniform, strides, message):
    with pytest.raises(ValueError, match=message):
        uniform[0].pairs(strides)


def test_trajectory_states_are_validated():
    with pytest.raises(ValueError, match="states contains NaN"):
        TrajectoryData(np.full((1, 3, 2), np.nan), dt=0.1)
    with pytest.raises(ValueError, match=r"\(P, K\+1, 2n\)"):
        TrajectoryData(np.zeros((1, 3, 3)), dt=0.1)


# --------------------------------------------------------------------------- duplicates
def test_drop_duplicates_counts_keeps_first_occurrences_in_order(uniform):
    d = uniform[0].pairs()
    doubled = d.concatenate(d.subset(np.arange(5))).concatenate(d.subset([2]))
    reduced, dropped = doubled.drop_duplicates()
    assert dropped == 6 and len(reduced) == len(d)
    np.testing.assert_array_equal(reduced.x0, d.x0)
    np.testing.assert_array_equal(reduced.x1, d.x1)
    same, none = d.drop_duplicates()
    assert same is d and none == 0


def test_drop_duplicates_refuses_contradictory_samples_naming_the_rows(uniform):
    d = uniform[0].pairs()
    bad = FlowMapData(
        np.r_[d.x0, d.x0[4:5]], np.r_[d.x1, d.x1[4:5] + 1e-3], np.r_[d.mu, d.mu[4:5]], np.r_[d.dt, d.dt[4:5]]
    )
    with pytest.raises(ValueError, match=rf"contradictory samples.*rows 4, {len(d)}\b"):
        bad.drop_duplicates()


def _fixed_model(cls=SymplecticKernelPredictor):
    return cls(IMQ(1.0), max_centers=8)


def _fixed_step_data():
    traj = TrajectoryData(
        oscillator_trajectories(
            np.arange(7)[None] * 0.1 * np.ones((2, 1)), np.ones(2), np.array([[0.5, 0.0], [0.0, -0.7]])
        ),
        dt=0.1,
    )
    return traj, traj.pairs()


@pytest.mark.parametrize("cls", [SymplecticKernelPredictor, DirectKernelPredictor])
def test_fit_drops_repeated_samples_with_one_warning(cls):
    _, d = _fixed_step_data()
    overlapping = d.concatenate(d.subset(np.arange(1, 4)))
    with pytest.warns(DuplicateSamplesWarning, match=rf"dropped 3 duplicated sample\(s\) .* of {len(d) + 3}") as record:
        model = _fixed_model(cls).fit(overlapping)
    assert sum(issubclass(w.category, DuplicateSamplesWarning) for w in record) == 1
    reference = _fixed_model(cls).fit(d.x0, d.x1, dt=d.dt)  # same arrays, same code path: bit equal
    np.testing.assert_array_equal(model.greedy_result_.coef, reference.greedy_result_.coef)


def test_fit_refuses_samples_the_kernel_cannot_tell_apart():
    """Same xi = (q0, p1), mu, dt but another p0: different gradient targets at one point."""
    _, d = _fixed_step_data()
    x0, x1 = d.x0.copy(), d.x1.copy()
    x0[5], x1[5] = [x0[2, 0], x0[2, 1] + 0.3], [x1[2, 0] + 0.2, x1[2, 1]]
    with pytest.raises(ValueError, match=r"contradictory samples: the same point seen by the kernel.*rows 2, 5"):
        _fixed_model().fit(x0, x1, dt=0.1)


# --------------------------------------------------------------------------- fit(data)
def test_fit_takes_flowmap_and_trajectory_data_like_arrays():
    traj, d = _fixed_step_data()
    arrays = _fixed_model().fit(d.x0, d.x1, dt=d.dt)
    for data in (d, traj):
        model = _fixed_model().fit(data)
        np.testing.assert_array_equal(model.greedy_result_.coef, arrays.greedy_result_.coef)
    direct = _fixed_model(DirectKernelPredictor).fit(traj)
    np.testing.assert_array_equal(
        direct.greedy_result_.coef, _fixed_model(DirectKernelPredictor).fit(d.x0, d.x1, dt=0.1).greedy_result_.coef
    )


def test_validation_takes_trajectory_data():
    traj, d = _fixed_step_data()
    val = TrajectoryData(traj.states[:, ::-1] * 0.9, dt=0.1)  # other states of the same flow (time reversed, scaled)
    model = _fixed_model().fit(d, validation=val)
    tuple_model = _fixed_model().fit(d, validation=(val.pairs().x0, val.pairs().x1, None, 0.1))
    assert model.history_.val_max_residual is not None
    np.testing.assert_array_equal(model.history_.val_max_residual, tuple_model.history_.val_max_residual)


@pytest.mark.parametrize("extra, name", [({"x1": np.zeros((12, 2))}, "x1"), ({"dt": 0.1}, "dt"), ({"mu": 1.0}, "mu")])
def test_data_objects_refuse_separate_arrays(extra, name):
    traj, d = _fixed_step_data()
    for data in (traj, d):
        with pytest.raises(
            ValueError, match=rf"fit: the data were given as a {type(data).__name__}.*do not pass {name}"
        ):
            _fixed_model().fit(data, **extra)


def test_arrays_need_x1():
    with pytest.raises(ValueError, match="x1 is required"):
        _fixed_model().fit(np.zeros((3, 2)), dt=0.1)
    with pytest.raises(ValueError, match="validation: x1 is required"):
        as_flowmap_data(np.zeros((3, 2)), what="validation")


# --------------------------------------------------------------------------- read_trajectories: round trips
def _write_h5(path, **arrays):
    with h5py.File(path, "w") as f:
        for k, v in arrays.items():
            f[k] = v


@pytest.fixture
def user_trajectories():
    rng = np.random.default_rng(3)
    times = np.cumsum(rng.uniform(0.05, 0.2, (3, 5)), axis=1)
    omega = np.array([0.9, 1.1, 1.4])
    return oscillator_trajectories(times, omega, rng.uniform(-1, 1, (3, 2))), times, omega


@pytest.mark.parametrize("suffix", [".npz", ".h5", ".hdf5"])
def test_binary_round_trips(tmp_path, user_trajectories, suffix):
    states, times, omega = user_trajectories
    write = (lambda p, **a: np.savez(p, **a)) if suffix == ".npz" else _write_h5
    write(tmp_path / f"t{suffix}", states=states, times=times, mu=omega)
    got = read_trajectories(tmp_path / f"t{suffix}")
    assert isinstance(got, TrajectoryData)
    np.testing.assert_array_equal(got.states, states)
    np.testing.assert_array_equal(got.times, times)
    np.testing.assert_array_equal(got.mu[:, 0], omega)
    write(tmp_path / f"u{suffix}", states=states[0].astype(np.float32), dt=np.float64(0.25))
    one = read_trajectories(tmp_path / f"u{suffix}")
    assert one.states.shape == (1, 5, 2) and one.dt == 0.25 and one.mu.shape == (1, 0)
    d = FlowMapData(states[:, :-1].reshape(-1, 2), states[:, 1:].reshape(-1, 2), None, 0.1)
    write(tmp_path / f"p{suffix}", x0=d.x0, x1=d.x1, dt=0.1)
    pairs = read_trajectories(tmp_path / f"p{suffix}")
    assert isinstance(pairs, FlowMapData)
    np.testing.assert_array_equal(pairs.x1, d.x1)
    np.testing.assert_array_equal(pairs.dt, d.dt)


def test_custom_keys(tmp_path, user_trajectories):
    states, times, omega = user_trajectories
    np.savez(tmp_path / "k.npz", X=states, T=times, c=omega)
    got = read_trajectories(tmp_path / "k.npz", states_key="X", times_key="T", mu_key="c")
    np.testing.assert_array_equal(got.states, states)


def test_the_packages_own_data_set_reads_as_pairs(tmp_path):
    d = FlowMapData(np.ones((3, 2)) * [[1], [2], [3]], np.zeros((3, 2)), [0.5, 0.6, 0.7], 0.1)
    save_dataset(d, tmp_path / "own.h5", system="test")
    got = read_trajectories(tmp_path / "own.h5")
    np.testing.assert_array_equal(got.x0, d.x0)
    np.testing.assert_array_equal(got.mu, d.mu)


def _write_csv(path, header, rows):
    path.write_text(",".join(header) + "\n" + "\n".join(",".join(str(c) for c in r) for r in rows) + "\n")


def test_csv_round_trip_with_labels_interleaved_rows_and_parameters(tmp_path, user_trajectories):
    states, times, omega = user_trajectories
    rows = []
    for k in range(5):  # rows of the trajectories interleaved, labels are strings
        for b, label in enumerate(["a", "b", "c"]):
            rows.append(
                [label, repr(float(times[b, k])), *(repr(float(v)) for v in states[b, k]), repr(float(omega[b])), 2.0]
            )
    _write_csv(tmp_path / "t.csv", ["traj", "t", "q", "p", "mu1", "mu2"], rows)
    got = read_trajectories(tmp_path / "t.csv")
    np.testing.assert_array_equal(got.states, states)  # repr round-trips floats exactly
    np.testing.assert_array_equal(got.times, times)
    np.testing.assert_array_equal(got.mu, np.column_stack([omega, np.full(3, 2.0)]))


def test_csv_with_n_2_and_one_mu_column(tmp_path):
    header = ["traj", "t", "q1", "q2", "p1", "p2", "mu"]
    rows = [[0, k * 0.1, k, 2 * k, 3 * k, 4 * k, 0.5] for k in range(4)]
    _write_csv(tmp_path / "n2.csv", header, rows)
    got = read_trajectories(tmp_path / "n2.csv")
    assert got.states.shape == (1, 4, 4) and got.dt == pytest.approx(0.1)
    np.testing.assert_array_equal(got.states[0, 3], [3, 6, 9, 12])
    np.testing.assert_array_equal(got.mu, [[0.5]])


# --------------------------------------------------------------------------- read_trajectories: errors
GOOD = ["traj", "t", "q", "p"]


@pytest.mark.parametrize(
    "header, rows, message",
    [
        (["traj", "t", "q1"], [[0, 0, 1]], r"lacks the column\(s\) \['p1'\]"),
        (["traj", "q", "p"], [[0, 1, 2]], r"lacks the column\(s\) \['t'\]"),
        (GOOD + ["energy"], [[0, 0, 1, 2, 3]], r"unexpected column\(s\) \['energy'\]"),
        (GOOD, [[0, 0, 1, 2], [0, 0.1, "abc", 2]], r"row 3, column 'q': 'abc' is not a number"),
        (GOOD, [[0, 0, 1, 2], [0, 0.1, 1, "nan"]], r"row 3, column 'p': 'nan' is not finite"),
        (GOOD, [[0, 0, 1, 2], [0, 0.1, 1]], r"row 3: 3 cells, the header has 4 columns"),
        (GOOD, [[0, 0, 1, 2], [0, 0.1, 1, 2], [1, 0, 1, 2]], r"trajectory '1' has 1 rows, trajectory '0' has 2"),
        (GOOD, [[0, 0, 1, 2]], "at least 2 states"),
        (GOOD, [[0, 0.2, 1, 2], [0, 0.1, 1, 2]], r"trajectory '0' is not in increasing time: row 3 has t = 0.1"),
        (GOOD + ["mu"], [[0, 0, 1, 2, 0.5], [0, 0.1, 1, 2, 0.6]], "constant within a trajectory; trajectory '0'"),
        (GOOD, [], "no data rows"),
        (GOOD, [["", 0, 1, 2]], "trajectory label is empty"),
    ],
)
def test_csv_errors_name_the_row_and_column(tmp_path, header, rows, message):
    _write_csv(tmp_path / "bad.csv", header, rows)
    with pytest.raises(ValueError, match=message) as info:
        read_trajectories(tmp_path / "bad.csv")
    assert "bad.csv" in str(info.value)


def test_file_level_errors(tmp_path):
    with pytest.raises(ValueError, match=r"unknown data file type '\.txt'; use \.npz"):
        read_trajectories(tmp_path / "x.txt")
    with pytest.raises(ValueError, match="does not exist"):
        read_trajectories(tmp_path / "missing.npz")
    (tmp_path / "empty.csv").write_text("")
    with pytest.raises(ValueError, match="empty: a header row"):
        read_trajectories(tmp_path / "empty.csv")
    (tmp_path / "junk.npz").write_bytes(b"not a zip file")
    with pytest.raises(ValueError, match="not a readable .npz"):
        read_trajectories(tmp_path / "junk.npz")
    (tmp_path / "junk.h5").write_bytes(b"not an hdf5 file")
    with pytest.raises(ValueError, match="not a readable HDF5"):
        read_trajectories(tmp_path / "junk.h5")
    _write_csv(tmp_path / "big.csv", GOOD, [[0, 0, 1, 2], [0, 1, 1, 2]])
    with pytest.raises(ValueError, match="more than max_bytes = 10"):
        read_trajectories(tmp_path / "big.csv", max_bytes=10)


@pytest.mark.parametrize(
    "arrays, message",
    [
        ({"dt": 0.1}, r"has no key 'states' \(found \['dt'\]\); expected layout"),
        ({"states": np.zeros((2, 3, 2))}, "exactly one of 'dt'.*found neither"),
        ({"states": np.zeros((2, 3, 2)), "dt": 0.1, "times": [0, 1, 2]}, "found both"),
        ({"states": np.zeros((2, 3, 3)), "dt": 0.1}, r"key 'states' must have shape \(P, K\+1, 2n\).*got \(2, 3, 3\)"),
        ({"states": np.zeros((2, 3, 2)), "dt": [0.1, 0.2]}, r"key 'dt' must be one positive number.*shape \(2,\)"),
        ({"states": np.full((2, 3, 2), np.inf), "dt": 0.1}, "key 'states' contains NaN or Inf"),
        ({"states": np.zeros((2, 3, 2)), "dt": 0.1, "mu": [1.0, 2.0, 3.0]}, "mu must have length 2"),
        ({"states": np.zeros((2, 3, 2)), "times": [0, 2, 1]}, "times must increase strictly.*trajectory 0"),
        ({"states": np.zeros((2, 3, 2)), "dt": -1.0}, "dt must be positive"),
        ({"x0": np.zeros((4, 2)), "x1": np.zeros((4, 2))}, r"holds pairs but lacks \['dt'\]"),
        (
            {"x0": np.zeros((4, 2)), "x1": np.zeros((3, 2)), "dt": 0.1},
            "key 'x1' has shape \\(3, 2\\), 'x0' has \\(4, 2\\)",
        ),
        ({"x0": np.zeros((4, 2)), "x1": np.zeros((4, 2)), "states": np.zeros((1, 2, 2)), "dt": 0.1}, "holds both"),
        ({"states": np.array([b"a", b"b"]), "dt": 0.1}, r"key 'states' has dtype \|?S1; a real numeric array"),
        ({"states": np.zeros((2, 3, 2), complex), "dt": 0.1}, "key 'states' has dtype complex128"),
    ],
)
@pytest.mark.parametrize("suffix", [".npz", ".h5"])
def test_binary_errors_name_the_file_and_key(tmp_path, arrays, message, suffix):
    path = tmp_path / f"bad{suffix}"
    if suffix == ".npz":
        np.savez(path, **arrays)
    else:
        _write_h5(path, **arrays)
    with pytest.raises(ValueError, match=message) as info:
        read_trajectories(path)
    assert f"bad{suffix}" in str(info.value)


def test_object_arrays_are_refused_without_unpickling(tmp_path):
    np.savez(tmp_path / "obj.npz", states=np.array([None, 1], dtype=object), dt=0.1)
    with pytest.raises(ValueError, match="key 'states' has dtype object"):
        read_trajectories(tmp_path / "obj.npz")


def test_absurd_declared_sizes_are_refused_before_allocating(tmp_path):
    """A hand-made .npy header declaring 10**15 float64 values: refused from the header."""
    header = "{'descr': '<f8', 'fortran_order': False, 'shape': (1000000, 1000000, 1000), }"
    header += " " * (63 - (len(header) + 10) % 64) + "\n"
    npy = b"\x93NUMPY\x01\x00" + len(header).to_bytes(2, "little") + header.encode() + b"\0" * 64
    with zipfile.ZipFile(tmp_path / "huge.npz", "w") as z:
        z.writestr("states.npy", npy)
        z.writestr("dt.npy", _npy_bytes(np.float64(0.1)))
    with pytest.raises(ValueError, match=r"key 'states' declares shape \(1000000, 1000000, 1000\).*max_bytes"):
        read_trajectories(tmp_path / "huge.npz")
    with h5py.File(tmp_path / "huge.h5", "w") as f:
        f.create_dataset("states", shape=(10**6, 10**6, 10), dtype="f8", chunks=(1, 10, 10))
        f["dt"] = 0.1
    with pytest.raises(ValueError, match=r"key 'states' declares shape \(1000000, 1000000, 10\)"):
        read_trajectories(tmp_path / "huge.h5")


def test_truncated_npy_member_is_refused(tmp_path):
    npy = _npy_bytes(np.zeros((2, 3, 2)))
    with zipfile.ZipFile(tmp_path / "short.npz", "w") as z:
        z.writestr("states.npy", npy[:-8])
        z.writestr("dt.npy", _npy_bytes(np.float64(0.1)))
    with pytest.raises(ValueError, match=r"key 'states' declares shape \(2, 3, 2\) but holds 88 bytes"):
        read_trajectories(tmp_path / "short.npz")


def test_hdf5_group_instead_of_dataset(tmp_path):
    with h5py.File(tmp_path / "g.h5", "w") as f:
        f.create_group("states")
        f["dt"] = 0.1
    with pytest.raises(ValueError, match="key 'states' is a group"):
        read_trajectories(tmp_path / "g.h5")


def _npy_bytes(arr):
    import io

    buf = io.BytesIO()
    np.save(buf, arr)
    return buf.getvalue()


def test_read_then_fit(tmp_path):
    traj, _ = _fixed_step_data()
    np.savez(tmp_path / "fit.npz", states=traj.states, dt=0.1)
    with warnings.catch_warnings():
        warnings.simplefilter("error", DuplicateSamplesWarning)
        model = _fixed_model().fit(read_trajectories(tmp_path / "fit.npz"))
    np.testing.assert_array_equal(model.greedy_result_.coef, _fixed_model().fit(traj).greedy_result_.coef)
