"""The estimator contract: parameters from ``__init__``, ``get_params`` / ``set_params``, ``clone``.

scikit-learn's convention, without depending on scikit-learn (its
``sklearn.base.clone`` works on these objects too; the tests check it):

* ``__init__`` stores its keyword arguments under their own names and does
  nothing else (so :func:`clone` always works); each value is checked against
  the class's table of settings (``_parameter_constraints``) by
  :meth:`Parametrized.set_params` (which stores nothing when it refuses a value)
  and again in ``fit`` (a value assigned as an attribute is checked there);
* :meth:`Parametrized.get_params` lists exactly the parameters of
  ``__init__`` (``deep=True`` adds ``name__sub`` entries for parameters that
  are themselves parametrized, e.g. a kernel's ``eps``);
* :meth:`Parametrized.set_params` sets them, nested with ``__``, all or none;
* :func:`clone` builds an unfitted copy with the same parameters (nested
  parametrized objects cloned too; other values deep-copied, except objects
  that define ``__sklearn_clone__``, such as a training strategy holding a
  worker pool, which decide for themselves).

Kernels, training strategies and estimators all derive from
:class:`Parametrized`.
"""

from __future__ import annotations

import copy
import inspect

__all__ = ["Parametrized", "Setting", "clone"]


class Parametrized:
    """Mixin: parameters are the arguments of ``__init__``, stored as attributes of the same name."""

    @classmethod
    def _param_names(cls) -> list[str]:
        init = cls.__init__
        if init is object.__init__:
            return []
        names = []
        for p in inspect.signature(init).parameters.values():
            if p.name == "self":
                continue
            if p.kind in (p.VAR_POSITIONAL, p.VAR_KEYWORD):
                raise TypeError(f"{cls.__name__}.__init__ must not take *args or **kwargs (estimator contract)")
            names.append(p.name)
        return sorted(names)

    def get_params(self, deep: bool = True) -> dict:
        """The ``__init__`` parameters and their values; ``deep`` adds nested ``name__sub`` entries."""
        out = {}
        for name in self._param_names():
            value = getattr(self, name)
            if deep and hasattr(value, "get_params") and not isinstance(value, type):
                out.update((f"{name}__{k}", v) for k, v in value.get_params(deep=True).items())
            out[name] = value
        return out

    #: The table of settings (``{name: _checks.Constraint}``) that :meth:`set_params` and ``fit`` check; empty for
    #: parts that check themselves (their ``check()``, called by their owner's table).
    _parameter_constraints: dict = {}

    def _default_part(self, name: str):
        """The part a nested ``name__setting`` changes when the parameter ``name`` is ``None`` (none here)."""
        return None

    def set_params(self, **params):
        """Set parameters (nested ones as ``name__sub``); returns ``self``.

        Every value is checked against the table of settings (``_parameter_constraints``) before any is
        stored, so a refused call leaves the object unchanged (scikit-learn's ``check_set_params``). A nested
        ``name__sub`` changes a copy of the part (never an object another model may share), checked by the
        part's own table and by this object's row for ``name``.

        Raises
        ------
        ValueError
            For a name that is not a parameter (the message lists the valid ones), or a value its row of the
            table refuses (the message names the setting, the value and the fix).
        """
        valid = self._param_names()
        new: dict = {}
        nested: dict = {}
        for key, value in params.items():
            name, _, sub = key.partition("__")
            if name not in valid:
                raise ValueError(f"{type(self).__name__} has no parameter {name!r}; valid parameters: {valid}")
            if sub:
                nested.setdefault(name, {})[sub] = value
            else:
                new[name] = value
        for name, sub_params in nested.items():
            target = new[name] if name in new else getattr(self, name)
            if target is None:
                target = self._default_part(name)
            if not hasattr(target, "set_params"):
                raise ValueError(
                    f"{type(self).__name__}.{name} = {target!r} has no parameters to set ({sorted(sub_params)})"
                )
            # a mutable part is changed on a copy (kernels are immutable values: their set_params returns a new one)
            part = clone(target) if isinstance(target, Parametrized) else target
            try:
                new[name] = part.set_params(**sub_params)
            except ValueError as exc:
                raise ValueError(f"{self._nested_call(name, sub_params)}: {exc}") from None
        table = self._parameter_constraints
        for name, value in new.items():  # every value checked before any is stored: a refused call changes nothing
            if name in table:
                try:
                    table[name].validate(name, value)
                except ValueError as exc:
                    if name not in nested:
                        raise
                    raise ValueError(f"{self._nested_call(name, nested[name])}: {exc}") from None
        for name, value in new.items():
            setattr(self, name, value)
        return self

    def _nested_call(self, name: str, sub_params: dict) -> str:
        """``Owner.set_params(name__sub=value, ...)``: what a message about a nested setting names."""
        given = ", ".join(f"{name}__{k}={v!r}" for k, v in sub_params.items())
        return f"{type(self).__name__}.set_params({given})"

    def __repr__(self) -> str:
        args = ", ".join(f"{k}={v!r}" for k, v in self.get_params(deep=False).items())
        return f"{type(self).__name__}({args})"

    def __sklearn_clone__(self):
        return clone(self)


class Setting(Parametrized):
    """A part that is a value: equal settings are equal parts (a solver, a training strategy, a kernel search).

    Mutable through ``set_params``, so not hashable.
    """

    def set_params(self, **params):
        """As :meth:`Parametrized.set_params`; a part whose settings are checked together (a ``check()`` without
        arguments) is also checked as a whole, on a copy with the new values, before any value is stored: a
        refused call leaves the part unchanged and raises ``ValueError`` naming the setting and the value."""
        check = getattr(type(self), "check", None)
        if check is not None and len(inspect.signature(check).parameters) == 1:
            Parametrized.set_params(clone(self), **params).check()
        return super().set_params(**params)

    def __eq__(self, other) -> bool:
        return type(self) is type(other) and self.get_params(deep=False) == other.get_params(deep=False)

    __hash__ = None


def clone(obj):
    """An unfitted copy of ``obj`` with the same parameters (scikit-learn's ``clone``).

    Parametrized objects are rebuilt from ``get_params(deep=False)`` with each
    parameter cloned; lists and tuples are cloned element-wise; objects with a
    ``__sklearn_clone__`` of their own decide (a training strategy keeps its
    worker pool); anything else is deep-copied.
    """
    if isinstance(obj, Parametrized):
        if type(obj).__sklearn_clone__ is not Parametrized.__sklearn_clone__:
            return obj.__sklearn_clone__()  # the class decides (e.g. a strategy that shares its pool)
        params = {k: clone(v) for k, v in obj.get_params(deep=False).items()}
        return type(obj)(**params)
    if isinstance(obj, (list, tuple, set, frozenset)):
        return type(obj)(clone(v) for v in obj)
    if hasattr(obj, "__sklearn_clone__") and not isinstance(obj, type):
        return obj.__sklearn_clone__()
    return copy.deepcopy(obj)
