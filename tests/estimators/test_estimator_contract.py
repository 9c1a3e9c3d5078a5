"""scikit-learn's estimator contract, training strategies as parameters, and every setting in model files."""

import copy
import json

import numpy as np
import pytest
import sklearn.base
from pymor.parallel.dummy import dummy_pool

from sympredict import DirectKernelPredictor, ModelFileError, SymplecticKernelPredictor
from sympredict.base import Parametrized, clone
from sympredict.estimators.auto import KernelSearch
from sympredict.interpolation.greedy import TRAINERS, ActiveSetGreedy, BlockedGreedy, ExactGreedy, ShardedGreedy
from sympredict.io import load_model, save_model
from sympredict.kernels import IMQ, Matern32, Matern52
from sympredict.symplectic.solvers import NewtonSolver
from sympredict.kernels.transforms import Periodic
from _tolerances import assert_same_predictions, value_rollout_bound  # tests/


def _data(d, n=400):
    idx = np.random.default_rng(0).choice(len(d), n, replace=False)
    return d.x0[idx], d.x1[idx], d.mu[idx], d.dt[idx]


@pytest.mark.parametrize("cls", [SymplecticKernelPredictor, DirectKernelPredictor])
def test_params_come_from_init_and_sklearn_clone_works(cls):
    model = cls(IMQ(0.2), IMQ(1.5), Matern52(3.0), max_centers=77, trainer=ExactGreedy("float32", tol=1e-7))
    params = model.get_params(deep=False)
    import inspect

    signature = inspect.signature(cls.__init__).parameters.values()
    assert set(params) == {p.name for p in signature if p.name != "self" and p.kind != p.VAR_KEYWORD}
    assert params["max_centers"] == 77 and params["trainer"] == model.trainer
    deep = model.get_params(deep=True)
    assert (
        deep["state_kernel__eps"] == 0.2 and deep["dt_kernel__eps"] == 3.0 and deep["trainer__basis_dtype"] == "float32"
    )
    for copy_ in (clone(model), sklearn.base.clone(model)):
        assert type(copy_) is cls and copy_ is not model
        assert repr(copy_.get_params(deep=False)) == repr(params)
        assert copy_.trainer is not model.trainer and copy_.trainer.get_params() == model.trainer.get_params()
        assert not copy_.is_fitted


def test_set_params_nested_and_checked():
    model = SymplecticKernelPredictor(IMQ(0.2), IMQ(1.5), IMQ(3.0))
    same = model.set_params(state_kernel__eps=0.4, max_centers=12, trainer=ActiveSetGreedy())
    assert same is model and model.state_kernel == IMQ(0.4) and model.max_centers == 12
    given = model.trainer
    model.set_params(trainer__refresh_every=17)
    assert model.trainer.refresh_every == 17
    assert given.refresh_every != 17 and model.trainer is not given  # a copy: the caller's part may be shared
    with pytest.raises(ValueError, match="no parameter 'max_center'.*valid parameters"):
        model.set_params(max_center=3)
    with pytest.raises(ValueError, match="no parameter"):
        model.set_params(state_kernel__shape=3)
    # kernels are values: set_params gives a new kernel, the old one is untouched
    k = IMQ(1.0)
    assert k.set_params(eps=2.0) == IMQ(2.0) and k == IMQ(1.0)


def test_set_params_refuses_atomically_and_clone_still_stores():
    """set_params checks every value against the table before storing any (scikit-learn's check_set_params: a
    refused call leaves every parameter unchanged), nested part settings too; __init__ and clone store unchecked."""
    trainer, solver = ExactGreedy(tol=1e-9), NewtonSolver(backend="numpy")
    model = SymplecticKernelPredictor(IMQ(0.2), IMQ(1.5), IMQ(3.0), max_centers=20, trainer=trainer, solver=solver)
    before = repr(model.get_params(deep=True))
    for bad, match in [
        (
            {"max_centers": 30, "trainer__tol": -1.0},
            r"SymplecticKernelPredictor.set_params\(trainer__tol=-1.0\): tol must be a finite non-negative float, got -1.0",
        ),
        (
            {"trainer__tol": 1e-3, "solver__backend": "gpu"},
            r"set_params\(solver__backend='gpu'\): backend must be 'auto', 'numpy' or 'numba', got 'gpu'",
        ),
        ({"state_kernel__eps": 0.3, "max_centers": 0}, r"max_centers must be >= 1, got 0"),
        ({"update": "midpoint", "mu_kernel": "imq"}, r"mu_kernel must be a sympredict.kernels kernel .* got 'imq'"),
        ({"state_kernel__eps": -1.0}, r"set_params\(state_kernel__eps=-1.0\): IMQ: eps must be a finite positive"),
        ({"search": KernelSearch(m_star=0)}, r"m_star"),
    ]:
        with pytest.raises(ValueError, match=match):
            model.set_params(**bad)
        assert repr(model.get_params(deep=True)) == before, bad
        assert model.trainer is trainer and model.solver is solver and trainer.tol == 1e-9 and solver.backend == "numpy"
    # a nested setting of a part left None is checked on the default part, and stored as a copy of it
    with pytest.raises(ValueError, match=r"set_params\(trainer__tol=nan\): tol"):
        SymplecticKernelPredictor().set_params(trainer__tol=float("nan"))
    assert SymplecticKernelPredictor().set_params(solver__backend="numpy").solver == NewtonSolver(backend="numpy")
    # construction and cloning store without checks (clone works on any settings; fit refuses them)
    odd = SymplecticKernelPredictor(max_centers=0, trainer="fast")
    for c in (clone(odd), sklearn.base.clone(odd)):
        assert c.max_centers == 0 and c.trainer == "fast"


@pytest.mark.parametrize("cls", [SymplecticKernelPredictor, DirectKernelPredictor])
def test_scikit_learns_own_set_params_check(cls):
    """scikit-learn's estimator check: set_params may refuse a value only if it leaves every parameter unchanged."""
    import warnings

    from sklearn.utils.estimator_checks import check_set_params

    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*delay parameter validation until fit", category=UserWarning)
        check_set_params(cls.__name__, cls(IMQ(0.2), IMQ(1.0), max_centers=5, trainer=ExactGreedy()))


def test_init_only_stores(small_pendulum_data):
    """Nonsense settings are accepted by __init__ and refused by fit, naming the setting."""
    x0, x1, mu, dt = _data(small_pendulum_data, 60)
    for kw, match in [
        ({"max_centers": 0}, "max_centers"),
        ({"trainer": ExactGreedy(tol=float("nan"))}, "tol"),
        ({"trainer": ExactGreedy(power_tol=float("nan"))}, "power_tol"),
        ({"trainer": ExactGreedy(power_tol=2.0)}, "power_tol"),
        ({"trainer": ExactGreedy(memory_limit=float("nan"))}, "memory_limit"),
        ({"trainer": ExactGreedy(criterion="q")}, "criterion"),
        ({"solver": NewtonSolver(backend="gpu")}, "backend"),
        ({"trainer": "fast"}, "trainer"),
        ({"solver": NewtonSolver(max_iter=0)}, "max_iter"),
        ({"update": "leapfrog"}, "update"),
        ({"state_kernel": Periodic(IMQ(0.2), coordinates=(0, 0))}, "coordinates"),
    ]:
        args = {"state_kernel": IMQ(0.2), **kw}
        model = SymplecticKernelPredictor(mu_kernel=IMQ(1.5), dt_kernel=IMQ(3.0), **args)
        assert model.get_params()[next(iter(kw))] is kw[next(iter(kw))]
        with pytest.raises(ValueError, match=match):
            model.fit(x0, x1, mu=mu, dt=dt)


def test_strategies_that_cannot_combine_say_so(small_pendulum_data):
    x0, x1, mu, dt = _data(small_pendulum_data, 60)
    with pytest.raises(TypeError, match="criterion"):  # the active set is an f-greedy: no setting to ask otherwise
        ActiveSetGreedy(criterion="p")
    with pytest.raises(ValueError, match="direct model"):
        DirectKernelPredictor(IMQ(0.2), IMQ(1.5), IMQ(3.0), trainer=ActiveSetGreedy()).fit(x0, x1, mu=mu, dt=dt)
    with pytest.raises(ValueError, match="basis_dtype"):
        SymplecticKernelPredictor(IMQ(0.2), IMQ(1.5), IMQ(3.0), trainer=ExactGreedy("float16")).fit(
            x0, x1, mu=mu, dt=dt
        )


def test_sharded_strategy_keeps_its_pool_when_cloned():
    trainer = ShardedGreedy(dummy_pool, n_shards=2)
    for c in (clone(trainer), sklearn.base.clone(trainer), clone(SymplecticKernelPredictor(trainer=trainer)).trainer):
        assert c is not trainer and c.pool is dummy_pool and c.n_shards == 2


@pytest.mark.parametrize(
    "trainer",
    [
        None,
        ExactGreedy(),
        ExactGreedy("float32"),
        ActiveSetGreedy(initial_points=100, seed=3),
        ShardedGreedy(dummy_pool, n_shards=2, timeout=5.0),
        BlockedGreedy(block_size=8),
    ],
    ids=repr,
)
def test_every_setting_round_trips_through_files(small_pendulum_data, tmp_path, trainer):
    x0, x1, mu, dt = _data(small_pendulum_data)
    settings = {"tol": 1e-9, "criterion": "f", "power_tol": 1e-11, "memory_limit": 2e9}
    if trainer is not None:  # each strategy with the greedy settings it has
        trainer = clone(trainer).set_params(**{k: v for k, v in settings.items() if k in trainer._param_names()})
    model = SymplecticKernelPredictor(
        None,
        IMQ(1.5),
        Matern32(3.0),
        max_centers=40,
        trainer=trainer,
        solver=NewtonSolver(max_iter=31, backend="numpy"),
    ).fit(x0, x1, mu=mu, dt=dt)
    path = tmp_path / "m.h5"
    model.save(path)
    back = SymplecticKernelPredictor.load(path)
    expected = model.get_params(deep=False)
    if isinstance(trainer, ShardedGreedy):
        # a pool is a connection, not a setting
        expected["trainer"] = ShardedGreedy(
            None, **{k: v for k, v in trainer.get_params(deep=False).items() if k != "pool"}
        )
    assert repr(back.get_params(deep=True)) == repr(
        clone(model).set_params(trainer=expected["trainer"]).get_params(deep=True)
    )
    assert back.state_kernel is None and back.kernel_ == model.kernel_
    assert_same_predictions(back, model, x0[:5], 1, mu=mu[:5], dt=dt[:5])
    # the same model fitted and written again gives the same file, byte for byte: no timings in it
    path2 = tmp_path / "m2.h5"
    clone(model).fit(x0, x1, mu=mu, dt=dt).save(path2)
    assert path.read_bytes() == path2.read_bytes()


def test_direct_model_files_and_io_dispatch(small_pendulum_data, tmp_path):
    x0, x1, mu, dt = _data(small_pendulum_data)
    model = DirectKernelPredictor(IMQ(0.2), IMQ(1.5), IMQ(3.0), max_centers=30).fit(x0, x1, mu=mu, dt=dt)
    save_model(model, tmp_path / "d.h5")
    back = load_model(tmp_path / "d.h5")
    assert type(back) is DirectKernelPredictor
    np.testing.assert_array_equal(back.surrogate_.coef, model.surrogate_.coef)  # the stored arrays: bit for bit
    # the same arrays in the same layout (tests/estimators/test_memory_layout.py) through the same code; still only to
    # round-off, since AVX-512 BLAS kernels may round with the arrays' memory alignment, which NumPy never fixes
    expected = model.rollout(x0[:3], 4, mu=mu[:3], dt=dt[:3])
    bound = value_rollout_bound(model.surrogate_.coef, expected, dt[:3])
    np.testing.assert_allclose(back.rollout(x0[:3], 4, mu=mu[:3], dt=dt[:3]), expected, rtol=0, atol=bound)
    assert bound < 1e-9, bound
    with pytest.raises(ModelFileError, match="not a SymplecticKernelPredictor"):
        SymplecticKernelPredictor.load(tmp_path / "d.h5")


def test_layout_1_files_are_refused_with_the_advice_to_refit(small_pendulum_data, tmp_path):
    """A model file of the first pre-release (settings without 'layout', timings in the arrays) is refused."""
    from sympredict.container import write_container
    from sympredict.estimators.predictor import MODEL_FORMAT

    x0, x1, mu, dt = _data(small_pendulum_data)
    model = SymplecticKernelPredictor(IMQ(0.2), IMQ(1.5), IMQ(3.0), max_centers=30).fit(x0, x1, mu=mu, dt=dt)
    sur, h = model.surrogate_, model.history_
    settings = {
        "kernel": model.kernel_.spec,
        "state_kernel_given": True,
        "max_centers": 30,
        "tol": 1e-10,
        "criterion": "f",
        "power_tol": 1e-12,
        "newton_max_iter": 50,
        "memory_limit": None,
        "dim": 2,
        "n_mu": 1,
        "dt_fixed": None,
        "stop_reason": h.stop_reason,
    }
    arrays = {
        "centers_xi": sur.centers_xi,
        "centers_mu": sur.centers_mu,
        "centers_dt": sur.centers_dt,
        "components": sur.components,
        "coef": sur.coef,
        "train_max_residual": h.train_max_residual,
        "selected_power": h.selected_power,
        "elapsed": h.elapsed,
    }
    arrays.update({f"domain_{k}": np.asarray(v) for k, v in model.domain_.items()})
    write_container(tmp_path / "old.h5", MODEL_FORMAT, settings, arrays)
    with pytest.raises(ModelFileError, match=r"pre-release version .*fit the model again and save it"):
        load_model(tmp_path / "old.h5")


def test_inconsistent_model_files_are_refused(small_pendulum_data, tmp_path):
    from sympredict.container import read_container, write_container
    from sympredict.estimators.predictor import MODEL_FORMAT

    x0, x1, mu, dt = _data(small_pendulum_data)
    SymplecticKernelPredictor(IMQ(0.2), IMQ(1.5), IMQ(3.0), max_centers=30).fit(x0, x1, mu=mu, dt=dt).save(
        tmp_path / "m.h5"
    )
    settings, arrays = read_container(tmp_path / "m.h5", MODEL_FORMAT)
    for change, match in [
        (lambda s, a: a.__setitem__("components", a["components"] + 5), "components"),
        (lambda s, a: a.__setitem__("coef", a["coef"] * np.nan), "finite"),
        (lambda s, a: a.pop("domain_x_min"), "training box"),
        (lambda s, a: a.__setitem__("centers_mu", a["centers_mu"][:3]), "centers_mu"),
        (lambda s, a: s["params"].__setitem__("trainer", {"trainer": {"name": "Magic", "params": {}}}), "Magic"),
        (lambda s, a: s.__setitem__("class", "Sneaky"), "Sneaky"),
    ]:
        s, a = json.loads(json.dumps(settings)), dict(arrays)
        change(s, a)
        write_container(tmp_path / "bad.h5", MODEL_FORMAT, s, a)
        with pytest.raises(ModelFileError, match=match):
            load_model(tmp_path / "bad.h5")


def test_trainers_registry_and_a_new_strategy(small_pendulum_data):
    """A new training strategy is a Trainer subclass with a store method (docs/explanation/architecture.md)."""
    from sympredict.interpolation.greedy import DenseStore, Trainer

    assert set(TRAINERS) >= {"ExactGreedy", "ActiveSetGreedy", "ShardedGreedy"}

    class EveryOtherCentre(Trainer):  # a toy strategy: the exact greedy on every other sample
        def __init__(self, stride: int = 2):
            self.stride = stride

        def store(self, functionals, targets, *, tol, validation):
            return DenseStore(
                functionals,
                targets,
                criterion=self.criterion,
                power_tol=self.power_tol,
                validation=validation,
                memory_limit=self.memory_limit,
            )

    x0, x1, mu, dt = _data(small_pendulum_data, 200)
    a = SymplecticKernelPredictor(IMQ(0.2), IMQ(1.5), IMQ(3.0), max_centers=25, trainer=EveryOtherCentre()).fit(
        x0, x1, mu=mu, dt=dt
    )
    b = SymplecticKernelPredictor(IMQ(0.2), IMQ(1.5), IMQ(3.0), max_centers=25).fit(x0, x1, mu=mu, dt=dt)
    np.testing.assert_array_equal(a.surrogate_.coef, b.surrogate_.coef)
    assert isinstance(clone(a.trainer), EveryOtherCentre) and isinstance(a.trainer, Parametrized)
    assert copy.copy(a).n_centers_ == 25


@pytest.mark.parametrize(
    "part, good, bad, message",
    [
        (ExactGreedy(), {"criterion": "p"}, {"tol": -1.0}, r"tol must be a finite non-negative float, got -1\.0"),
        (BlockedGreedy(), {"block_size": 8}, {"target_error": 0.0}, r"target_error must be a positive float.*got 0\.0"),
        (
            NewtonSolver(),
            {"max_iter": 10},
            {"backend": "fortran"},
            r"backend must be 'auto', 'numpy' or 'numba', got 'fortran'",
        ),
        (KernelSearch(), {"seed": 3}, {"halving": "yes"}, r"halving must be True or False.*'yes'"),
    ],
)
def test_a_part_on_its_own_refuses_a_bad_setting_and_stays_unchanged(part, good, bad, message):
    """A part's set_params checks its settings as a whole (its check()) before storing any: a call with one good
    and one bad value raises, names the setting and the value, and leaves every setting as it was."""
    before = part.get_params(deep=False)
    with pytest.raises(ValueError, match=message):
        part.set_params(**good, **bad)
    assert part.get_params(deep=False) == before
    assert part.set_params(**good).get_params(deep=False) == {**before, **good}  # a good value alone is stored
