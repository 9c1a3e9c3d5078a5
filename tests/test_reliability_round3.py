"""Reliability round 3: silent identity models, hostile model files, fitted state, lost work, start-up, the reductor.

Every case here failed (or misled) before the fix it tests; each says what happens now.  Model files are
rewritten with a recomputed checksum (:func:`sympredict.container.write_container`), as anyone can: a file
either loads into a model that predicts finite states, or is refused with :class:`ModelFileError` naming
the setting.
"""

import json
import os
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

from sympredict import DirectKernelPredictor, ModelFileError, SymplecticKernelPredictor, SympredictError
from sympredict.container import check_save_path, read_container, write_container
from sympredict.exceptions import ExtrapolationWarning, NonFinitePredictionError, UnderfitWarning, extrapolation_expected
from sympredict.io import load_model
from sympredict.kernels import IMQ
from sympredict.estimators.predictor import MAX_NEWTON_ITER, MODEL_FORMAT
from sympredict.systems.pendulum import Pendulum, flow_map_data
from sympredict.interpolation.greedy import ExactGreedy
from sympredict.symplectic.solvers import NewtonSolver
from sympredict.kernels.transforms import Periodic, Scaled

ROOT = Path(__file__).resolve().parents[1]
DT = 0.1


@pytest.fixture(scope="module")
def data():
    return flow_map_data(Pendulum(), mus=(0.75,), dts=(DT,), n_grid=8)


@pytest.fixture(scope="module")
def model(data):
    return SymplecticKernelPredictor(IMQ(0.3), max_centers=30, solver=NewtonSolver(backend="numpy")).fit(data.x0, data.x1, dt=DT)


@pytest.fixture(scope="module")
def model_file(model, tmp_path_factory):
    path = tmp_path_factory.mktemp("files") / "model.h5"
    model.save(path)
    return path


def _rewrite(src, dst, settings=None, arrays=None):
    """A copy of the model file ``src`` with edited settings / arrays and a valid checksum."""
    s, a = read_container(src, MODEL_FORMAT)
    if settings is not None:
        settings(s)
    if arrays is not None:
        arrays(a)
    write_container(dst, MODEL_FORMAT, s, a)
    return dst


def _param(name, value):
    def edit(s):
        s["params"][name] = value
    return edit


# ------------------------------------------------------------------ silent identity models
def test_small_units_fit_learns(data):
    """States x 1e-11 with the shape scaled to match: before, tol (absolute) stopped at 0 centres (identity)."""
    s = 1e-11
    m = SymplecticKernelPredictor(IMQ(0.3 / s), max_centers=30, solver=NewtonSolver(backend="numpy")).fit(data.x0 * s, data.x1 * s, dt=DT)
    ref = SymplecticKernelPredictor(IMQ(0.3), max_centers=30, solver=NewtonSolver(backend="numpy")).fit(data.x0, data.x1, dt=DT)
    assert m.n_centers_ == ref.n_centers_ == 30
    x, x1 = data.x0, data.x1
    err, err_ref, moved = (np.abs(m.step(x * s) / s - x1).max(), np.abs(ref.step(x) - x1).max(), np.abs(x1 - x).max())
    assert err < 0.1 * moved and err < 3 * err_ref  # learned as well as in units of order one


def test_small_units_default_kernel_learns(data):
    """``state_kernel=None`` on states x 1e-11: the default shape follows the data and the fit learns."""
    s = 1e-11
    m = SymplecticKernelPredictor(max_centers=30, solver=NewtonSolver(backend="numpy")).fit(data.x0 * s, data.x1 * s, dt=DT)
    assert m.n_centers_ == 30
    err = np.abs(m.step(data.x0[:4] * s) - data.x1[:4] * s).max() / s
    assert err < 0.1 * np.abs(data.x1 - data.x0).max()


def test_default_kernel_on_states_too_small_is_refused(data):
    """States x 1e-170: the diameter was 0 (underflow) and IMQ(1) was used silently; now a clear ValueError."""
    with pytest.raises(ValueError, match="rescale the states"):
        SymplecticKernelPredictor(max_centers=10).fit(data.x0 * 1e-170, data.x1 * 1e-170, dt=DT)


def test_fit_selecting_no_centre_warns(data):
    with pytest.warns(UnderfitWarning, match="selected no centre.*lower tol"):
        m = SymplecticKernelPredictor(IMQ(0.3), max_centers=30, trainer=ExactGreedy(tol=100.0)).fit(data.x0, data.x1, dt=DT)
    assert m.n_centers_ == 0


def test_direct_fit_selecting_no_centre_warns(data):
    with pytest.warns(UnderfitWarning, match="DirectKernelPredictor.fit selected no centre"):
        DirectKernelPredictor(IMQ(0.3), max_centers=30, trainer=ExactGreedy(tol=100.0)).fit(data.x0, data.x1, dt=DT)


def test_fit_with_a_kernel_far_too_narrow_warns(data):
    """A shape 10^4 times too large: the model moves only its few centres, i.e. barely moves the data."""
    with pytest.warns(UnderfitWarning, match="less than a tenth"):
        SymplecticKernelPredictor(IMQ(3e4), max_centers=3, solver=NewtonSolver(backend="numpy")).fit(data.x0, data.x1, dt=DT)


def test_data_that_do_not_move_give_the_identity_without_warning(data):
    with warnings.catch_warnings():
        warnings.simplefilter("error", UnderfitWarning)
        m = SymplecticKernelPredictor(IMQ(0.3), max_centers=30).fit(data.x0, data.x0.copy(), dt=DT)
    assert m.n_centers_ == 0


# ------------------------------------------------------------------ model files: one schema of settings
@pytest.mark.parametrize("name, value, match", [
    ("solver", {"solver": {"max_iter": 10 ** 15, "warm_start": False, "backend": "auto"}}, "max_iter must be at most"),
    ("solver", {"solver": {"max_iter": 0, "warm_start": False, "backend": "auto"}}, "max_iter"),
    ("solver", {"solver": {"max_iter": 2.5, "warm_start": False, "backend": "auto"}}, "max_iter"),
    ("solver", {"solver": {"max_iter": 50, "warm_start": False, "backend": "cuda"}}, "backend"),
    ("solver", {"solver": {"max_iter": 50, "warm_start": "yes", "backend": "auto"}}, "warm_start"),
    ("solver", {"solver": {"max_iter": 50, "gpu": True}}, "gpu"),
    ("update", "leapfrog", "update"),
    ("trainer", {"trainer": {"name": "ExactGreedy", "params": {"tol": -1.0}}}, "tol"),
    ("newton_max_iter", 50, "unknown setting.*newton_max_iter"),  # a layout-3 file has no flat options
    ("max_centers", -3, "max_centers"),
    ("state_kernel", {"transform": "scaled", "params": {"kernel": {"kernel": {"family": "imq", "eps": 0.3}},
                                                        "factors": {"list": [1.0, 2.0]}}}, "factors"),
    ("state_kernel", {"transform": "periodic", "params": {"kernel": None, "coordinates": {"tuple": [5]},
                                                          "period": 6.0}}, "periodic"),
    ("state_kernel", {"transform": "symmetric", "params": {"kernel": None, "group": {"list": [{"tuple": [1, 1]},
                                                                                              {"tuple": [1, -1]}]}}},
     "symmetry"),
])
def test_invalid_setting_in_a_file_is_refused_naming_it(model_file, tmp_path, name, value, match):
    path = _rewrite(model_file, tmp_path / "bad.h5", settings=_param(name, value))
    with pytest.raises(ModelFileError, match=match):
        SymplecticKernelPredictor.load(path)
    with pytest.raises(ModelFileError, match=match):
        load_model(path)


@pytest.mark.parametrize("key, value, match", [
    ("dim", float("inf"), "dim"),
    ("dim", 2.0, "dim"),
    ("dim", True, "dim"),
    ("n_mu", -1, "n_mu"),
    ("dt_fixed", -0.1, "dt_fixed"),
    ("dt_fixed", "0.1", "dt_fixed"),
    ("layout", 7, "layout"),
    ("stop_reason", 3, "stop_reason"),
])
def test_invalid_shape_information_in_a_file_is_refused(model_file, tmp_path, key, value, match):
    def edit(s):
        s[key] = value
    path = _rewrite(model_file, tmp_path / "bad.h5", settings=edit)
    with pytest.raises(ModelFileError, match=match):
        SymplecticKernelPredictor.load(path)


@pytest.mark.parametrize("name, value", [
    ("train_max_residual", np.zeros(0)),
    ("selected_power", np.zeros(0)),
    ("train_max_residual", np.zeros((31, 1))),
    ("domain_x_min", np.full(2, 10.0)),  # min above max
    ("domain_dt_min", np.array(-1.0)),
])
def test_inconsistent_arrays_in_a_file_are_refused(model_file, tmp_path, name, value):
    def edit(a):
        a[name] = value
    path = _rewrite(model_file, tmp_path / "bad.h5", arrays=edit)
    with pytest.raises(ModelFileError):
        SymplecticKernelPredictor.load(path)


def test_file_asking_for_endless_newton_never_hangs(model_file, tmp_path):
    """A solver with max_iter = 10**15 loaded would make `sympredict predict` run without end: the file is refused."""
    path = _rewrite(model_file, tmp_path / "hang.h5",
                    settings=_param("solver", {"solver": {"max_iter": 10 ** 15, "warm_start": False, "backend": "auto"}}))
    proc = subprocess.run([sys.executable, "-m", "sympredict.cli", "predict", str(path), "--x0", "0.5,0.1", "--steps", "3"],
                          capture_output=True, text=True, timeout=120, env={**os.environ, "NUMBA_NUM_THREADS": "1"})
    assert proc.returncode == 1 and "max_iter" in proc.stderr and "Traceback" not in proc.stderr


def test_direct_model_with_huge_coefficients_raises_instead_of_inf(data, tmp_path):
    model = DirectKernelPredictor(IMQ(0.3), max_centers=10).fit(data.x0, data.x1, dt=DT)
    model.save(tmp_path / "d.h5")

    def edit(a):
        a["coef"] = np.full_like(a["coef"], 1.7e308)
    path = _rewrite(tmp_path / "d.h5", tmp_path / "huge.h5", arrays=edit)
    loaded = DirectKernelPredictor.load(path)
    with pytest.raises(NonFinitePredictionError, match="non-finite"):
        loaded.step(data.x0[:3])
    with pytest.raises(NonFinitePredictionError):
        loaded.rollout(data.x0[:3], 4)


def test_symplectic_model_with_huge_coefficients_raises(model_file, data, tmp_path):
    def edit(a):
        a["coef"] = np.full_like(a["coef"], 1e308)
    loaded = SymplecticKernelPredictor.load(_rewrite(model_file, tmp_path / "huge.h5", arrays=edit))
    for call in (lambda: loaded.step(data.x0[:3]), lambda: loaded.rollout(data.x0[:3], 3)):
        with pytest.raises(SympredictError):
            call()


def test_split_model_with_huge_coefficients_raises(data, tmp_path):
    from sympredict.flowmap.splitting import SplitKernelPredictor

    quad = Pendulum().quadratic_part()
    mu = np.full(len(data.x0), 0.75)
    inner = SymplecticKernelPredictor(IMQ(0.5), IMQ(1.0), max_centers=10, solver=NewtonSolver(backend="numpy"))
    split = SplitKernelPredictor(inner, quad).fit(data.x0, data.x1, mu=mu, dt=DT)
    split.predictor_.surrogate_.coef[:] = 1e308
    x = data.x0[:3]
    for call in (lambda: split.step(x, mu=0.75, dt=DT), lambda: split.rollout(x, 3, mu=0.75, dt=DT)):
        with pytest.raises(SympredictError):
            with extrapolation_expected():
                call()


# ------------------------------------------------------------------ fitted state is what predicts
def test_set_params_after_fit_does_not_change_predictions(data, tmp_path):
    m = SymplecticKernelPredictor(IMQ(0.3), max_centers=20, solver=NewtonSolver(backend="numpy")).fit(data.x0, data.x1, dt=DT)
    x = data.x0[:4]
    before = m.step(x)
    for change in ({"update": "midpoint"}, {"state_kernel": Scaled(IMQ(0.3), factors=(2.0,))},
                   {"state_kernel": Periodic(IMQ(0.3), coordinates=(0,))}):
        m.set_params(**change)
        np.testing.assert_array_equal(m.step(x), before)
    m.save(tmp_path / "m.h5")  # the fitted settings are written (a later periodic kernel would not fit the arrays)
    back = SymplecticKernelPredictor.load(tmp_path / "m.h5")
    np.testing.assert_array_equal(back.step(x), before)
    # the fitted settings, not the later ones (update=None at fit: 'symplectic_euler' with the kernel given)
    assert back.update is None and back.update_ == "symplectic_euler" and back.state_kernel == IMQ(0.3)


def test_a_changed_parameter_takes_effect_at_the_next_fit(data):
    m = SymplecticKernelPredictor(IMQ(0.3), max_centers=20, solver=NewtonSolver(backend="numpy")).fit(data.x0, data.x1, dt=DT)
    m.set_params(update="midpoint").fit(data.x0, data.x1, dt=DT)
    assert m.update_ == "midpoint" and m.fitted_params_["update"] == "midpoint"


def test_failed_refit_keeps_the_fitted_settings(data):
    m = SymplecticKernelPredictor(IMQ(0.3), max_centers=20, solver=NewtonSolver(backend="numpy")).fit(data.x0, data.x1, dt=DT)
    x = data.x0[:4]
    before = m.step(x)
    m.set_params(state_kernel=Scaled(IMQ(0.3), factors=(2.0,)))
    with pytest.raises(ValueError):
        m.fit(data.x0, data.x1[:5], dt=DT)
    assert m.state_scaling_ is None
    np.testing.assert_array_equal(m.step(x), before)


def test_save_refuses_a_solver_setting_load_would_refuse(model, tmp_path):
    import copy

    m = copy.copy(model)
    m.set_params(solver__backend="gpu")
    with pytest.raises(ValueError, match="backend"):
        m.save(tmp_path / "x.h5")
    assert not (tmp_path / "x.h5").exists()


def test_a_fitted_periodic_model_saves_with_the_compiled_backend(data, tmp_path):
    """Periodic coordinates run compiled now: backend='numba' is a valid pair, saved and loaded back (a pair load
    would refuse is refused at save: test_save_refuses_a_solver_setting_load_would_refuse)."""
    m = SymplecticKernelPredictor(Periodic(IMQ(0.3), coordinates=(0,)), max_centers=10,
                                  solver=NewtonSolver(backend="numpy")).fit(data.x0, data.x1, dt=DT)
    m.set_params(solver__backend="numba")
    m.save(tmp_path / "n.h5")
    loaded = SymplecticKernelPredictor.load(tmp_path / "n.h5")
    assert loaded.periodic_ == (0,) and loaded.solver.backend == "numba"
    m.set_params(solver__backend="auto")
    m.save(tmp_path / "p.h5")
    assert SymplecticKernelPredictor.load(tmp_path / "p.h5").periodic_ == (0,)


def test_endless_newton_setting_refused_at_prediction(model, data):
    import copy

    m = copy.copy(model)
    m.set_params(solver__max_iter=10 ** 15)
    with pytest.raises(ValueError, match="max_iter must be at most"):
        m.step(data.x0[:2])
    with pytest.raises(ValueError, match=str(MAX_NEWTON_ITER)):
        SymplecticKernelPredictor(IMQ(0.3), solver=NewtonSolver(max_iter=MAX_NEWTON_ITER + 1)).fit(data.x0, data.x1, dt=DT)


# ------------------------------------------------------------------ lost work: output paths
def test_container_saves_under_the_longest_valid_name(model, tmp_path):
    """A 255-byte name: the temporary sibling was longer than the limit, so the save failed after the work."""
    name = "m" * 252 + ".h5"
    model.save(tmp_path / name)
    assert SymplecticKernelPredictor.load(tmp_path / name).n_centers_ == model.n_centers_
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


def test_cli_predict_out_refuses_an_existing_file(model_file, tmp_path, capsys):
    from sympredict.cli import main

    out = tmp_path / "traj.csv"
    out.write_text("keep")
    args = ["predict", str(model_file), "--x0", "0.5,0.1", "--steps", "2", "--out", str(out)]
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


def test_model_kept_when_saving_fails_after_training(model, tmp_path, monkeypatch):
    from sympredict import cli

    target = tmp_path / "m.h5"
    real_save = type(model).save

    def failing_save(self, path):
        if Path(path) == target:
            raise OSError(28, "No space left on device")
        real_save(self, path)
    monkeypatch.setattr(type(model), "save", failing_save)
    with pytest.raises(OSError, match="kept in") as info:
        cli._save_model_or_keep(model, target)
    kept = [p for p in tmp_path.iterdir() if p.name.startswith("sympredict-model-")]
    assert len(kept) == 1 and str(kept[0]) in str(info.value)
    assert SymplecticKernelPredictor.load(kept[0]).n_centers_ == model.n_centers_


# ------------------------------------------------------------------ start-up
def _python(code, **env):
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300,
                          env={**os.environ, **env}, cwd=ROOT)


def test_invalid_numba_thread_count_falls_back_to_numpy_with_one_warning():
    code = ("import warnings; warnings.simplefilter('always')\n"
            "import numpy as np, sympredict\n"
            "from sympredict import _fastkernels\n"
            "from sympredict.kernels import IMQ\n"
            "assert not _fastkernels.HAVE_NUMBA\n"
            "x0 = np.random.default_rng(0).uniform(-1, 1, (20, 2)); x1 = x0 + 0.05 * x0[:, ::-1]\n"
            "m = sympredict.SymplecticKernelPredictor(IMQ(0.5), max_centers=10).fit(x0, x1, dt=0.1)\n"
            "print(np.isfinite(m.step(x0[:2] * 0.5)).all())\n")
    proc = _python(code, NUMBA_NUM_THREADS="0")
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == "True"
    assert proc.stderr.count("RuntimeWarning") == 1 and "NUMBA_NUM_THREADS" in proc.stderr


def test_bad_mplbackend_does_not_break_predict(model_file):
    code = ("import sys\nfrom sympredict.cli import main\n"
            f"rc = main(['predict', {str(model_file)!r}, '--x0', '0.5,0.1', '--steps', '2'])\n"
            "assert 'matplotlib' not in sys.modules\nsys.exit(rc)\n")
    proc = _python(code, MPLBACKEND="no-such-backend", NUMBA_NUM_THREADS="1")
    assert proc.returncode == 0, proc.stderr
    assert "instance 0" in proc.stdout


def test_bad_mplbackend_does_not_break_plotting():
    proc = _python("import sympredict.paper.plotting as p, matplotlib, os\n"
                   "assert matplotlib.get_backend().lower() == 'agg' and os.environ['MPLBACKEND'] == 'no-such-backend'\n",
                   MPLBACKEND="no-such-backend", NUMBA_NUM_THREADS="1")
    assert proc.returncode == 0, proc.stderr


# ------------------------------------------------------------------ the reductor's arguments
@pytest.fixture(scope="module")
def wave_parts():
    pymordemos = pytest.importorskip("pymordemos.symplectic_wave_equation")
    from pymor.algorithms.symplectic import psd_complex_svd

    fom = pymordemos.discretize_fom(T=0.5)
    RB = psd_complex_svd(fom.solve(), 2)
    return fom, RB


@pytest.mark.parametrize("kwargs, match", [
    ({"dt": "0.1"}, r"dt must be a real number, got '0.1'"),
    ({"dt": [0.1, 0.2]}, r"dt must be a real number, got \[0.1, 0.2\]"),
    ({"dt": -0.1}, r"dt must be positive, got -0.1"),
    ({"n_samples": 0}, r"n_samples must be >= 2, got 0"),
    ({"n_samples": 2.5}, r"n_samples must be an integer"),
    ({"n_validation": 0}, r"n_validation must be >= 1, got 0"),
    ({"radius": -0.1}, r"radius must be >= 0, got -0.1"),
    ({"radius": "big"}, r"radius must be a real number"),
    ({"horizon": -1.0}, r"horizon must be positive, got -1.0"),
    ({"horizon": "1"}, r"horizon must be a real number"),
    ({"max_centers": 0}, r"max_centers must be >= 1, got 0"),
    ({"estimator": "imq"}, r"estimator must be an estimator"),
    ({"estimator": SymplecticKernelPredictor}, r"estimator must be an estimator"),
    ({"state_scaling": "log"}, r"state_scaling must be one of"),
    ({"check_existence": "no"}, r"check_existence must be True or False"),
])
def test_reductor_checks_its_arguments_up_front(wave_parts, monkeypatch, kwargs, match):
    from sympredict.mor import SymplecticKernelReductor

    fom, RB = wave_parts
    monkeypatch.setattr(type(fom), "solve", lambda *a, **k: (_ for _ in ()).throw(AssertionError("FOM solved")))
    args = {"dt": 0.05, **kwargs}
    dt = args.pop("dt")
    with pytest.raises(ValueError, match=match):
        SymplecticKernelReductor(fom, RB, None, dt, **args)


def test_reductor_checks_its_predictors_settings_before_sampling(monkeypatch):
    """A predictor with an unknown update, or without mu_kernel for varying parameters, was refused only after
    every FOM sample (in fit / reduce)."""
    pymordemos = pytest.importorskip("pymordemos.symplectic_wave_equation")
    from pymor.algorithms.symplectic import psd_complex_svd

    from sympredict.mor import SymplecticKernelReductor

    from pymor.operators.block import BlockDiagonalOperator
    from pymor.operators.constructions import LincombOperator
    from pymor.parameters.functionals import ExpressionParameterFunctional

    demo = pymordemos.discretize_fom(T=0.5)  # its stiffness scaled by c^2 / 0.01, as in test_mor.py
    blocks = demo.H_op.blocks
    fom = demo.with_(H_op=BlockDiagonalOperator([
        LincombOperator([blocks[0, 0]], [ExpressionParameterFunctional("c[0]**2/0.01", {"c": 1})]), blocks[1, 1]]))
    RB = psd_complex_svd(fom.solve(fom.parameters.parse(0.1)), 2)
    train = fom.parameters.space(0.08, 0.12).sample_uniformly(2)
    monkeypatch.setattr(type(fom), "solve", lambda *a, **k: (_ for _ in ()).throw(AssertionError("FOM solved")))
    with pytest.raises(ValueError, match="update must be one of"):
        SymplecticKernelReductor(fom, RB, train, 0.05, SymplecticKernelPredictor(update="leapfrog"))
    class NoChoice(SymplecticKernelPredictor):  # an estimator that does not choose an open mu_kernel itself
        _chooses_open_factors = False

    reductor = SymplecticKernelReductor(fom, RB, train, 0.05, NoChoice(IMQ(1.0)))
    with pytest.raises(ValueError, match="mu_kernel=None"):
        reductor.reduce()


def test_reductor_refuses_a_parameter_space_of_other_parameters(wave_parts):
    from pymor.parameters.base import Parameters

    from sympredict.mor import SymplecticKernelReductor

    fom, RB = wave_parts
    with pytest.raises(ValueError, match="parameter_space has the parameters"):
        SymplecticKernelReductor(fom, RB, None, 0.05, parameter_space=Parameters({"k": 2}).space(0, 1))
    with pytest.raises(ValueError, match="parameter_space must be a pyMOR ParameterSpace"):
        SymplecticKernelReductor(fom, RB, None, 0.05, parameter_space=(0, 1))


# ------------------------------------------------------------------ messages
def test_memory_advice_never_suggests_an_invalid_max_centers():
    from sympredict.interpolation.greedy.loop import check_memory

    with pytest.raises(ValueError) as info:
        check_memory(100, 10 ** 6, 0, memory_limit=1000.0)
    assert "max_centers <= 0" not in str(info.value) and "memory_limit" in str(info.value)


def test_fixed_step_message_tells_two_close_steps_apart(model, data):
    other = DT + 1e-12
    with pytest.raises(ValueError) as info:
        model.step(data.x0[:1], dt=other)
    assert repr(DT) in str(info.value) and repr(other) in str(info.value)


def test_projected_stride_message_tells_the_steps_apart(wave_parts):
    """dt a hair off a multiple of the FOM's output step: both printed with ``:.6g`` looked equal."""
    from sympredict.mor import SymplecticKernelReductor

    fom, RB = wave_parts
    h = fom.T / fom.time_stepper.nt
    dt = 10 * h * (1 + 1e-8)
    with pytest.raises(ValueError, match="multiple of the FOM's output step") as info:
        SymplecticKernelReductor(fom, RB, None, dt, data="projected")
    assert repr(dt) in str(info.value) and repr(h) in str(info.value)


def test_normalized_flow_map_warns_in_the_users_units():
    from sympredict.flowmap.scaling import BoxScaling, NormalizedFlowMap, SymplecticScaling

    rng = np.random.default_rng(0)
    x = rng.uniform(-1, 1, (40, 2))
    mu = rng.uniform(10.0, 20.0, 40)
    scaling = SymplecticScaling("none").fit(x)
    box = BoxScaling().fit(mu[:, None])
    inner = SymplecticKernelPredictor(IMQ(0.5), IMQ(1.0), max_centers=10, solver=NewtonSolver(backend="numpy"))
    inner.fit(x, x + 0.01 * x[:, ::-1], mu=box.transform(mu[:, None]), dt=np.ones(40))
    flow = NormalizedFlowMap(inner, scaling, box, tau=0.25)
    with pytest.warns(ExtrapolationWarning) as caught:
        flow.step(x[:1] * 0.5, mu=30.0, dt=0.25)
    text = str(caught[0].message)
    assert "30.0" in text and "training steps 0.25..0.25" in text  # the user's mu and dt, not 2.0 and 1.0


# ------------------------------------------------------------------ fuzz: files either work or are refused
_SETTING_VALUES = [None, True, False, 0, 1, -1, 2, 3, 10 ** 15, 2.5, -0.5, 1e308, float("inf"), float("nan"), "",
                   "numba", "midpoint", "x", [], [0], [1.0, 2.0], {}, {"kernel": {}}, {"tuple": [0]}, {"list": [1e300]}]


def _paths(d, prefix=()):
    """Every key path into the nested settings dict."""
    for key, value in d.items():
        yield prefix + (key,)
        if isinstance(value, dict):
            yield from _paths(value, prefix + (key,))


def _mutations(settings, arrays, rng, n):
    """``n`` seeded edits of a model's (settings, arrays): one setting or one array changed each."""
    keys = list(_paths(settings))
    names = sorted(arrays)
    for _ in range(n):
        s, a = json.loads(json.dumps(settings)), {k: v.copy() for k, v in arrays.items()}
        if rng.random() < 0.5:
            where = keys[rng.integers(len(keys))]
            target = s
            for key in where[:-1]:
                target = target[key]
            key = where[-1]
            choice = rng.integers(3)
            if choice == 0:
                target[key] = _SETTING_VALUES[rng.integers(len(_SETTING_VALUES))]
            elif choice == 1:
                target.pop(key)
            else:
                target[key] = {"kernel": {"family": "imq", "eps": float(10 ** rng.uniform(-60, 60))}}
        else:
            name = names[rng.integers(len(names))]
            arr = a[name]
            choice = rng.integers(5)
            if choice == 0 and arr.size:
                flat = arr.reshape(-1)
                if arr.dtype.kind == "f":
                    flat[rng.integers(flat.size)] = [np.inf, np.nan, 1e308, -1e308, 0.0, 1e-308][rng.integers(6)]
                else:
                    flat[rng.integers(flat.size)] = [-1, 0, 1, 2, 10 ** 9][rng.integers(5)]
            elif choice == 1:
                a[name] = arr.reshape(-1)[: max(0, arr.size - 1)]
            elif choice == 2:
                a[name] = arr * 10.0 ** rng.integers(-300, 300) if arr.dtype.kind == "f" else arr + 10 ** 9
            elif choice == 3:
                a[name] = np.concatenate([arr.reshape(-1), arr.reshape(-1)]) if arr.size else np.ones(3)
            else:
                a.pop(name)
        yield s, a


def _fuzz(model_file, tmp_path, n, seed, mu=None):
    settings, arrays = read_container(model_file, MODEL_FORMAT)
    x = np.array([[0.4, 0.1], [-0.3, 0.2]])
    outcomes = {"refused": 0, "predicted": 0, "numerical": 0}
    path = tmp_path / "fuzz.h5"
    for s, a in _mutations(settings, arrays, np.random.default_rng(seed), n):
        try:
            write_container(path, MODEL_FORMAT, s, a)
        except ValueError:
            continue  # not writable as a container at all (e.g. NaN in JSON is fine, but not every object)
        try:
            loaded = load_model(path)
        except ModelFileError:
            outcomes["refused"] += 1
            continue
        try:
            with extrapolation_expected():
                out = loaded.rollout(x, 3, mu=mu if loaded.n_mu_ else None, dt=DT)
        except SympredictError as exc:  # numerical failure said clearly (Newton, non-finite), never silent
            assert not isinstance(exc, ModelFileError)
            outcomes["numerical"] += 1
            continue
        except ValueError as exc:  # the query is invalid for this (valid) model: a step it was not trained for
            assert "fixed step" in str(exc), exc
            outcomes["predicted"] += 1
            continue
        assert np.all(np.isfinite(out))
        outcomes["predicted"] += 1
    assert outcomes["refused"] > n // 4 and outcomes["predicted"] > 0
    return outcomes


@pytest.fixture(scope="module")
def other_model_files(data, tmp_path_factory):
    """A DirectKernelPredictor's and a SplitKernelPredictor's files (the symplectic one is ``model_file``)."""
    from sympredict.flowmap.splitting import SplitKernelPredictor

    folder = tmp_path_factory.mktemp("others")
    DirectKernelPredictor(IMQ(0.3), max_centers=20).fit(data.x0, data.x1, dt=DT).save(folder / "direct.h5")
    inner = SymplecticKernelPredictor(IMQ(0.5), IMQ(1.0), max_centers=15, solver=NewtonSolver(backend="numpy"))
    SplitKernelPredictor(inner, Pendulum().quadratic_part()).fit(
        data.x0, data.x1, mu=np.full(len(data.x0), 0.75), dt=DT).save(folder / "split.h5")
    return {"direct": folder / "direct.h5", "split": folder / "split.h5"}


def test_fuzzed_model_files_load_and_predict_or_are_refused(model_file, tmp_path):
    _fuzz(model_file, tmp_path, 300, seed=3)


@pytest.mark.parametrize("kind", ["direct", "split"])
def test_fuzzed_files_of_the_other_models(other_model_files, tmp_path, kind):
    _fuzz(other_model_files[kind], tmp_path, 150, seed=4, mu=0.75)


@pytest.mark.slow
def test_fuzzed_model_files_long(model_file, other_model_files, tmp_path):
    for seed in range(6):
        _fuzz(model_file, tmp_path, 1000, seed=100 + seed)
        for kind, path in other_model_files.items():
            _fuzz(path, tmp_path, 500, seed=200 + seed, mu=0.75)


@pytest.mark.parametrize("key", ["dim", "n_mu"])
def test_a_file_with_huge_sizes_is_refused_before_allocating(model_file, tmp_path, key):
    """A file's dim or n_mu of 10**15 must be refused by its arrays' shapes, not by a failed allocation."""
    path = _rewrite(model_file, tmp_path / "huge.h5", settings=lambda s: s.__setitem__(key, 10 ** 15))
    with pytest.raises(ModelFileError, match=f"{key}=1000000000000000 disagrees with its training box"):
        SymplecticKernelPredictor.load(path)
