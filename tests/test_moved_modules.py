"""Old import paths of the modules that moved into role subpackages: they import, warn once, and are the new modules.

``sympredict._MOVED_MODULES`` maps each old dotted name to the new one; a moved
package's submodules follow it (``sympredict.greedy.loop``,
``sympredict.experiments.pendulum``).  The old name must give the *same* module
object (``isinstance``, monkeypatching and pickles see one module), with one
``DeprecationWarning`` that names the new path and points at the importing line.
"""

import importlib
import pickle
import pkgutil
import sys
import warnings

import pytest

import sympredict
from sympredict import SymplecticKernelPredictor

MOVED = sympredict._MOVED_MODULES


def _old_and_new_names():
    """Every old name: the moved modules, and the submodules of the moved packages."""
    pairs = []
    for old, new in MOVED.items():
        pairs.append((old, new))
        module = importlib.import_module(new)
        for info in pkgutil.walk_packages(getattr(module, "__path__", []), prefix=new + "."):
            pairs.append((old + info.name[len(new):], info.name))
    return pairs


OLD_AND_NEW = _old_and_new_names()


@pytest.fixture
def forget_old_names():
    """Each test imports the old names afresh and leaves no old name behind (sys.modules, package attributes)."""

    def forget():
        for name in [m for m in sys.modules if sympredict._moved_to(m) is not None]:
            del sys.modules[name]
            parent, _, child = name.rpartition(".")
            if parent in sys.modules and sys.modules[parent].__dict__.get(child) is not None:
                if sympredict._moved_to(parent) is None:  # an attribute set on a real package by the old import
                    delattr(sys.modules[parent], child)

    forget()
    yield
    forget()


def _import_old(old: str):
    """Import ``old`` with its (old) parents already imported; return the module and the warnings of this import."""
    parent = old.rpartition(".")[0]
    if parent != "sympredict":
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", DeprecationWarning)
            importlib.import_module(parent)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        module = importlib.import_module(old)
    return module, [w for w in caught if issubclass(w.category, DeprecationWarning)]


def test_the_table_covers_the_moves():
    assert len(OLD_AND_NEW) > len(MOVED)  # the packages' submodules are there
    assert ("sympredict.greedy.loop", "sympredict.interpolation.greedy.loop") in OLD_AND_NEW
    assert ("sympredict.experiments.pendulum", "sympredict.paper.pendulum") in OLD_AND_NEW
    assert all(old != new for old, new in OLD_AND_NEW)


@pytest.mark.parametrize("old,new", OLD_AND_NEW, ids=[old for old, _ in OLD_AND_NEW])
def test_old_name_imports_warns_once_and_is_the_new_module(old, new, forget_old_names):
    module, caught = _import_old(old)
    assert module is importlib.import_module(new) is sys.modules[old] is sys.modules[new]
    assert len(caught) == 1, [str(w.message) for w in caught]
    message = str(caught[0].message)
    assert old in message and f"import {new}" in message
    assert caught[0].filename == __file__  # the importing line (here: _import_old)
    assert module.__name__ == new and module.__spec__.name == new  # the module keeps its own identity
    with warnings.catch_warnings(record=True) as again:
        warnings.simplefilter("always")
        assert importlib.import_module(old) is module
    assert not again  # once


def test_the_warning_points_at_the_importing_statement(forget_old_names):
    with pytest.warns(DeprecationWarning, match=r"sympredict\.predictor moved to sympredict\.estimators\.predictor") as w:
        import sympredict.predictor as old  # noqa: F401
    assert w[0].filename == __file__
    from sympredict.estimators import predictor

    assert old is predictor


def test_from_import_of_an_old_submodule_and_attribute_access(forget_old_names):
    with pytest.warns(DeprecationWarning, match=r"sympredict\.report moved to sympredict\.paper\.report"):
        from sympredict import report
    from sympredict.paper import report as new

    assert report is new
    del sys.modules["sympredict.report"], sympredict.report
    with pytest.warns(DeprecationWarning, match=r"sympredict\.metrics moved to sympredict\.symplectic\.metrics") as w:
        metrics = sympredict.metrics
    assert w[0].filename == __file__
    from sympredict.symplectic import metrics as new_metrics

    assert metrics is new_metrics
    with pytest.raises(AttributeError, match="no_such_module"):
        sympredict.no_such_module  # noqa: B018


def test_classes_and_monkeypatching_through_the_old_name(forget_old_names, monkeypatch):
    with pytest.warns(DeprecationWarning):
        from sympredict.predictor import SymplecticKernelPredictor as Old
        import sympredict.newton as old_newton
    assert Old is SymplecticKernelPredictor
    assert isinstance(SymplecticKernelPredictor(), Old)
    from sympredict.symplectic import newton

    monkeypatch.setattr(old_newton, "CHUNK_SECONDS", 123.0)
    assert newton.CHUNK_SECONDS == 123.0


def test_pickles_that_name_the_old_modules_load(forget_old_names):
    """A pickle written before the move names ``sympredict.predictor``; it loads the class from its new module."""
    payload = b"csympredict.predictor\nSymplecticKernelPredictor\n."  # protocol 0: GLOBAL module name
    with pytest.warns(DeprecationWarning, match=r"sympredict\.estimators\.predictor"):
        cls = pickle.loads(payload)
    assert cls is SymplecticKernelPredictor
    model = pickle.loads(pickle.dumps(SymplecticKernelPredictor()))  # and new pickles name the new module
    assert type(model).__module__ == "sympredict.estimators.predictor"


def test_unknown_old_submodules_still_fail(forget_old_names):
    with pytest.raises(ModuleNotFoundError):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", DeprecationWarning)
            importlib.import_module("sympredict.greedy.no_such_module")
    with pytest.raises(ModuleNotFoundError):
        importlib.import_module("sympredict.no_such_module")


def test_the_new_names_do_not_warn():
    """The library and the suite use the new names (pyproject's filterwarnings turns this warning into an error)."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        for _, new in OLD_AND_NEW:
            importlib.import_module(new)
    assert not [w for w in caught if "moved to sympredict." in str(w.message)]
