"""The options of sympredict 0.1's estimators, kept working: each folded into the part that now owns it.

``SymplecticKernelPredictor(tol=1e-8, backend="numba", periodic=(0,))`` is
``SymplecticKernelPredictor(Periodic(kernel, coordinates=(0,)), trainer=ExactGreedy(tol=1e-8),
solver=NewtonSolver(backend="numba"))``: the constructor, ``set_params``, attribute
access and model files of layout 2 translate through :data:`MOVED_OPTIONS`, with a
FutureWarning naming the replacement (none for files: a file is not the user's
spelling).  ``tools/migrate_options.py`` rewrites such calls in source code.
"""

from __future__ import annotations

import warnings

import numpy as np

from sympredict.base import clone
from sympredict.interpolation.greedy import Trainer
from sympredict.interpolation.greedy.trainers import ExactGreedy
from sympredict.kernels.transforms import compose_state_kernel, lower_state_kernel
from sympredict.symplectic.solvers import NewtonSolver

__all__ = ["MOVED_OPTIONS", "apply_moved", "replacement"]


#: Options of sympredict 0.1's estimators that moved into their parts: ``old name -> (part, its parameter)``.
#: Passing one (constructor, ``set_params``, a layout-2 model file) still works, with a FutureWarning naming
#: the replacement.
MOVED_OPTIONS = {
    **{name: ("trainer", name) for name in ("tol", "criterion", "power_tol", "memory_limit", "regularization")},
    **{old: ("solver", new) for old, new in (("backend", "backend"), ("newton_max_iter", "max_iter"),
                                              ("newton_warm_start", "warm_start"))},
    **{old: ("state_kernel", spelling) for old, spelling in (
        ("state_scaling", "Scaled(kernel, factors=...)"), ("periodic", "Periodic(kernel, coordinates=...)"),
        ("period", "Periodic(kernel, coordinates=..., period=...)"), ("symmetry", "Symmetric(kernel, group=...)"))},
}

_NEUTRAL = {"criterion": "f", "regularization": 0.0, "memory_limit": None}


def replacement(cls_name: str, name: str) -> str:
    """How to spell the old option ``name`` now (for messages)."""
    part, inner = MOVED_OPTIONS[name]
    if part == "trainer":
        return f"trainer=ExactGreedy({inner}=...) (or the {inner} of your training strategy)"
    if part == "solver":
        return f"solver=NewtonSolver({inner}=...)"
    return f"state_kernel={inner}"


def _same(a, b) -> bool:
    """Equal settings (tuples and lists alike, arrays by value)."""
    try:
        return bool(np.array_equal(np.asarray(a, dtype=object), np.asarray(b, dtype=object))) if a is not None and b is not None else a is b
    except Exception:  # noqa: BLE001 - settings that do not compare: different
        return False


def _refuse_both(model, old: str, part, name: str, value, default_part) -> None:
    """``ValueError`` when the old option ``old`` and the part's own ``name`` (set away from its default) differ."""
    given = getattr(part, name, None)
    if not _same(given, getattr(default_part, name, None)) and not _same(given, value):
        raise ValueError(f"{type(model).__name__}({old}={value!r}) and {type(part).__name__}({name}={given!r}) both "
                         f"given: give it once ({replacement(type(model).__name__, old)})")


def apply_moved(model, moved: dict, warn: bool = True, check_both: bool = False) -> None:
    """Fold options of sympredict 0.1 (:data:`MOVED_OPTIONS`) into ``model``'s parts (new objects, never the
    caller's); a FutureWarning names each replacement.  ``check_both`` (the parts were given in the same call):
    an old option and the part's own setting that differ raise ``ValueError`` instead of the old one winning."""
    from_base = type(model)._moved_options
    unknown = sorted(set(moved) - set(from_base))
    if unknown:
        raise TypeError(f"{type(model).__name__}() got unexpected keyword argument(s) {unknown}; "
                        f"its parameters are {type(model)._param_names()}")
    if warn:
        for name in moved:
            warnings.warn(f"{type(model).__name__}({name}=...) is deprecated: pass {replacement(type(model).__name__, name)}",
                          FutureWarning, stacklevel=4)
    trainer_opts = {MOVED_OPTIONS[k][1]: v for k, v in moved.items() if MOVED_OPTIONS[k][0] == "trainer"}
    if trainer_opts:
        trainer = ExactGreedy() if model.trainer is None else clone(model.trainer)
        valid = trainer._param_names() if isinstance(trainer, Trainer) else []
        for name, value in trainer_opts.items():
            if name in valid:
                if check_both:
                    _refuse_both(model, name, trainer, name, value, type(trainer)())
                setattr(trainer, name, value)
            elif not (value is _NEUTRAL.get(name, object()) or (name in _NEUTRAL and value == _NEUTRAL[name])):
                raise ValueError(f"the training strategy {type(trainer).__name__} has no setting {name} "
                                 f"(got {name}={value!r}): use ExactGreedy({name}=...) or ShardedGreedy({name}=...)")
        model.trainer = trainer
    solver_opts = {MOVED_OPTIONS[k][1]: v for k, v in moved.items() if MOVED_OPTIONS[k][0] == "solver"}
    if solver_opts:
        solver = NewtonSolver() if model.solver is None else clone(model.solver)
        old_names = {MOVED_OPTIONS[k][1]: k for k in moved if MOVED_OPTIONS[k][0] == "solver"}
        for name, value in solver_opts.items():
            if check_both:
                _refuse_both(model, old_names[name], solver, name, value, NewtonSolver())
            setattr(solver, name, value)
        model.solver = solver
    kernel_opts = {k: v for k, v in moved.items() if MOVED_OPTIONS[k][0] == "state_kernel"}
    if kernel_opts:
        parts = lower_state_kernel(model.state_kernel)
        for old, attr, unset in (("periodic", "periodic", None), ("state_scaling", "scaling", None),
                                 ("period", "period", 2 * np.pi), ("symmetry", "symmetry", None)):
            given = getattr(parts, attr)
            if check_both and old in kernel_opts and not _same(given, unset) and not _same(given, kernel_opts[old]):
                raise ValueError(f"{type(model).__name__}({old}={kernel_opts[old]!r}) and a state_kernel that sets it "
                                 f"too ({given!r}): give it once, in the state_kernel ({replacement(type(model).__name__, old)})")
        periodic = kernel_opts.get("periodic", parts.periodic)
        model.state_kernel = compose_state_kernel(
            parts.radial, scaling=kernel_opts.get("state_scaling", parts.scaling), periodic=periodic,
            period=kernel_opts.get("period", parts.period), symmetry=kernel_opts.get("symmetry", parts.symmetry))
