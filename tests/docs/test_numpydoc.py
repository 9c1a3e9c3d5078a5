"""The main classes' docstrings follow numpydoc: every parameter documented as ``name : type, default=...``.

The objects checked are those of the API reference's "Main classes" section (``docs/reference/api.rst``),
with the members it lists, so that page is the one list. numpydoc's own validator finds undocumented,
unknown and untyped parameters (PR01, PR02, PR04); the default rule (scikit-learn's spelling) is checked here:
a parameter with a default in the signature says ``default=<value>`` in its type line.
"""

import importlib
import inspect
import re
from pathlib import Path

import pytest
from numpydoc import validate

API = Path(__file__).resolve().parents[2] / "docs" / "reference" / "api.rst"
CHECKED_CODES = ("PR01", "PR02", "PR04")


def _main_objects() -> list[str]:
    """``module.Name`` and ``module.Name.member`` for every object of the "Main classes" section."""
    text = API.read_text()
    section = text.split("Main classes\n------------", 1)[1].split("\n----", 1)[0]
    names = []
    for block in re.split(r"\n(?=\.\. auto)", section):
        head = re.match(r"\.\. auto(?:class|function):: (\S+)", block.strip())
        if not head:
            continue
        names.append(head.group(1))
        members = re.search(r":members: (.+)", block)
        if members:
            names += [f"{head.group(1)}.{m.strip()}" for m in members.group(1).split(",")]
    return names


def _resolve(name: str):
    parts = name.split(".")
    for cut in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:cut]))
        except ImportError:
            continue
        for attr in parts[cut:]:
            obj = getattr(obj, attr)
        return obj
    raise ImportError(name)


OBJECTS = _main_objects()


def test_the_main_classes_section_lists_objects():
    assert "sympredict.SymplecticKernelPredictor" in OBJECTS and "sympredict.SymplecticKernelPredictor.fit" in OBJECTS


@pytest.mark.parametrize("name", OBJECTS)
def test_every_parameter_is_documented_with_its_type(name):
    errors = [f"{code}: {message}" for code, message in validate.validate(name)["errors"] if code in CHECKED_CODES]
    assert not errors, "\n".join(errors)


@pytest.mark.parametrize("name", OBJECTS)
def test_every_default_is_stated(name):
    obj = _resolve(name)
    signature = inspect.signature(obj.__init__ if inspect.isclass(obj) else obj)
    doc = validate.Validator(validate.get_doc_object(obj))
    types = {n: t for n, (t, _) in doc.doc_parameters.items()}
    missing = []
    for pname, param in signature.parameters.items():
        if (
            pname == "self"
            or param.default is inspect.Parameter.empty
            or param.kind in (param.VAR_POSITIONAL, param.VAR_KEYWORD)
        ):
            continue
        type_line = next((t for n, t in types.items() if pname in [s.strip() for s in n.split(",")]), None)
        if type_line is not None and "default=" not in type_line.replace(" ", ""):
            missing.append(f"{pname} : {type_line}  (signature default {param.default!r})")
    assert not missing, "no 'default=...' in the type line of:\n" + "\n".join(missing)
