"""The scenarios' presets (``smoke``, ``quick``, ``paper``, ...) as data: one TOML file a scenario beside this module.

A table a preset gives the sizes that differ from the preset class's defaults; ``based_on = "NAME"`` starts from an
earlier preset of the same file instead.  :func:`load_presets` checks every entry against the preset dataclass (a
known field, a value of the field's type) so that a typo in a file is an error that names the file, the preset and
the key, not a silently ignored size.
"""

from __future__ import annotations

import dataclasses
import sys
import typing
from importlib import resources

if sys.version_info >= (3, 11):
    import tomllib
else:  # the same parser, as a package before Python 3.11
    import tomli as tomllib

__all__ = ["load_presets"]

#: annotation -> the TOML values accepted for it (a float field also takes an integer, stored as float)
_ACCEPTS = {int: (int,), float: (float, int), bool: (bool,), str: (str,), tuple: (list,)}
_TOML = {int: "an integer", float: "a float", bool: "true or false", str: "a string", tuple: "an array"}


def _as_tuple(value):
    """TOML arrays (nested) as tuples, as the preset classes hold them."""
    return tuple(_as_tuple(v) for v in value) if isinstance(value, list) else value


def _checked(where: str, field: dataclasses.Field, hint, value):
    """``value`` of ``field`` (type ``hint``) from a TOML table, converted to what the dataclass holds."""
    accepted = _ACCEPTS.get(hint)
    if accepted is None:
        raise TypeError(f"{where}: the field {field.name!r} has type {hint!r}, which presets cannot set from a file")
    if isinstance(value, bool) and hint is not bool or not isinstance(value, accepted):
        raise ValueError(
            f"{where}: {field.name} = {value!r} is of type {type(value).__name__}, the field's type is "
            f"{hint.__name__} (TOML: {_TOML[hint]}): write it as one"
        )
    if hint is float:
        return float(value)
    return _as_tuple(value) if hint is tuple else value


def load_presets(scenario: str, preset_class: type) -> dict:
    """The presets of ``scenario`` (``sympredict_paper/presets/SCENARIO.toml``) as ``{name: preset_class(...)}``.

    Parameters
    ----------
    scenario : str
        The file's stem, e.g. ``"pendulum"``.
    preset_class : type
        A dataclass whose fields are ``int``, ``float``, ``bool``, ``str`` or ``tuple`` (TOML arrays, nested arrays
        as nested tuples).

    Returns
    -------
    presets : dict of str to preset_class
        In the file's order.

    Raises
    ------
    ValueError
        A key that is no field of ``preset_class``, a value of the wrong type, or a ``based_on`` that names no
        earlier preset; the message names the file, the preset and the key.
    """
    name = f"{scenario}.toml"
    with resources.files(__package__).joinpath(name).open("rb") as f:
        tables = tomllib.load(f)
    fields = {f.name: f for f in dataclasses.fields(preset_class) if f.init}
    hints = typing.get_type_hints(preset_class)
    presets: dict = {}
    for preset, table in tables.items():
        where = f"sympredict_paper/presets/{name} [{preset}]"
        table = dict(table)
        base = table.pop("based_on", None)
        if base is not None and base not in presets:
            raise ValueError(f"{where}: based_on = {base!r} names no earlier preset (have {sorted(presets)})")
        unknown = sorted(set(table) - set(fields))
        if unknown:
            raise ValueError(f"{where}: {unknown} are no fields of {preset_class.__name__} (fields: {sorted(fields)})")
        values = {key: _checked(where, fields[key], hints[key], value) for key, value in table.items()}
        presets[preset] = dataclasses.replace(presets[base], **values) if base else preset_class(**values)
    return presets
