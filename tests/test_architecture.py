"""The package's import rule: dependencies point one way, layer by layer, with no cycles and nothing hidden.

The layers of the role folders are import-linter contracts in ``pyproject.toml``
(``[tool.importlinter]``): :func:`test_import_contracts` runs them, so plain
pytest fails on an upward import, on a library module importing the paper's
code, or on a module that has no layer (the layers contract is exhaustive: a
new module gets its place in the contracts, docs/explanation/architecture.md).

What import-linter does not check is checked here by walking the import
statements of every module (function bodies included) with ``ast``: no
function-level imports of the package outside the command line, no cycles
between modules.  ``from sympredict import name`` counts as an import of the
submodule ``name`` when there is one, else of the package namespace.
"""

import ast
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "sympredict"

#: The command line (the package and its modules) imports what its subcommands need when they run (start-up time);
#: it is the top layer, so a function-level import there cannot hide a cycle.
LAZY_IMPORTS_ALLOWED = {"sympredict.cli"}


def _lazy_imports_allowed(name: str) -> bool:
    return any(name == m or name.startswith(m + ".") for m in LAZY_IMPORTS_ALLOWED)


_LINT_IMPORTS = "import sys; from importlinter.cli import lint_imports_command; sys.exit(lint_imports_command())"


def _modules() -> dict:
    mods = {}
    for path in PACKAGE.rglob("*.py"):
        name = ".".join(("sympredict",) + path.relative_to(PACKAGE).with_suffix("").parts)
        mods[name[: -len(".__init__")] if name.endswith(".__init__") else name] = path
    return mods


def _imports(mods: dict):
    """``{module: [(imported module, lineno, inside a function)]}`` for imports of the package's own modules."""
    out = {}
    for name, path in mods.items():
        tree = ast.parse(path.read_text(), str(path))
        in_function = set()
        for fn in ast.walk(tree):
            if isinstance(fn, (ast.FunctionDef, ast.AsyncFunctionDef)):
                in_function.update(id(n) for n in ast.walk(fn) if isinstance(n, (ast.Import, ast.ImportFrom)))
        is_pkg = path.name == "__init__.py"
        found = []
        for node in ast.walk(tree):
            targets = []
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    parts = name.split(".") if is_pkg else name.split(".")[:-1]
                    base = ".".join(parts[: len(parts) - node.level + 1] + ([base] if base else []))
                targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in mods else base for a in node.names]
            for t in targets:
                while t and t not in mods:
                    t = t.rsplit(".", 1)[0] if "." in t else ""
                if t and t != name and not name.startswith(t + "."):
                    found.append((t, node.lineno, id(node) in in_function))
        out[name] = found
    return out


def _lint_imports(*args: str, cwd: Path = ROOT) -> subprocess.CompletedProcess:
    pytest.importorskip("importlinter")
    return subprocess.run(
        [sys.executable, "-c", _LINT_IMPORTS, "--no-cache", "--no-logo", *args],
        cwd=cwd,
        capture_output=True,
        text=True,
        timeout=300,
    )


def test_import_contracts():
    """The contracts of pyproject.toml hold (what ``lint-imports`` checks in .ci/run)."""
    proc = _lint_imports("--config", str(ROOT / "pyproject.toml"))
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "0 broken" in proc.stdout


def test_the_contracts_can_fail(tmp_path):
    """The check is not vacuous: a layering the code breaks (kernels above the estimators) is reported broken."""
    config = tmp_path / "upside_down.ini"
    config.write_text(
        "[importlinter]\nroot_package = sympredict\n\n"
        "[importlinter:contract:upside-down]\nname = kernels above the estimators\ntype = layers\n"
        "layers =\n    sympredict.kernels\n    sympredict.estimators\n"
    )
    proc = _lint_imports("--config", str(config))
    assert proc.returncode == 1, proc.stdout + proc.stderr
    assert "sympredict.estimators is not allowed to import sympredict.kernels" in proc.stdout


def test_the_library_never_imports_the_paper():
    """The paper's code is a sibling package (``sympredict_paper``) that imports the library, never the reverse: no
    module of ``sympredict`` imports it, not even inside a function (what the ``paper-apart`` contract says, checked
    here on the import statements themselves)."""
    assert (ROOT / "sympredict_paper" / "__init__.py").is_file()
    wrong = []
    for name, path in _modules().items():
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            targets = (
                [a.name for a in node.names]
                if isinstance(node, ast.Import)
                else ([node.module or ""] if isinstance(node, ast.ImportFrom) and not node.level else [])
            )
            wrong += [f"{name}:{node.lineno} imports {t}" for t in targets if t.split(".")[0] == "sympredict_paper"]
    assert not wrong, "\n".join(wrong)


def test_no_import_cycles():
    mods = _modules()
    graph = {name: {t for t, _, _ in imports} for name, imports in _imports(mods).items()}
    state, stack, cycles = {}, [], []

    def visit(u):
        state[u] = 1
        stack.append(u)
        for v in sorted(graph[u]):
            if state.get(v) == 1:
                cycles.append(" -> ".join(stack[stack.index(v) :] + [v]))
            elif v not in state:
                visit(v)
        stack.pop()
        state[u] = 2

    for u in sorted(graph):
        if u not in state:
            visit(u)
    assert not cycles, "import cycles:\n" + "\n".join(cycles)


def test_no_function_level_imports_of_the_package():
    mods = _modules()
    hidden = [
        f"{name}:{line} imports {target} inside a function"
        for name, imports in _imports(mods).items()
        if not _lazy_imports_allowed(name)
        for target, line, inside in imports
        if inside
    ]
    assert not hidden, "\n".join(hidden)


# ------------------------------------------------------------------ the estimators' private members stay private
#: The estimator classes whose ``_`` members no other module may touch: other modules use their public API
#: (settings, ``check_params``, ``validate_data``, the fitted flow map ``model_``, model files' functions).
ESTIMATOR_CLASSES = {
    "sympredict.estimators.predictor": ("_FlowMapKernelModel", "SymplecticKernelPredictor", "DirectKernelPredictor")
}


def _private_members(path: Path, classes) -> set:
    """The ``_name`` members (not dunders) the classes ``classes`` of the module ``path`` define or set on ``self``,
    and those of the base classes they inherit from (``base.Parametrized``)."""
    from sympredict.estimators import predictor

    names = set()
    for cls_name in classes:
        for klass in getattr(predictor, cls_name).__mro__:
            if klass.__module__.startswith("sympredict"):
                names.update(n for n in vars(klass) if n.startswith("_") and not n.startswith("__"))
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ClassDef) and node.name in classes:
            names.update(
                sub.attr
                for sub in ast.walk(node)
                if isinstance(sub, ast.Attribute)
                and isinstance(sub.value, ast.Name)
                and sub.value.id == "self"
                and sub.attr.startswith("_")
                and not sub.attr.startswith("__")
            )
    return names


def _touches(tree, names: set) -> list:
    """``(line, name)`` of every ``obj._name`` with ``_name`` in ``names``, except on ``self``/``cls`` inside a class
    (a class's own members; a module-level ``cls`` variable holding an estimator class counts)."""
    own = {id(n) for c in ast.walk(tree) if isinstance(c, ast.ClassDef) for n in ast.walk(c)}
    return sorted(
        (node.lineno, node.attr)
        for node in ast.walk(tree)
        if isinstance(node, ast.Attribute)
        and node.attr in names
        and not (id(node) in own and isinstance(node.value, ast.Name) and node.value.id in ("self", "cls"))
    )


def test_no_module_touches_the_estimators_private_members():
    """No module of the package reads, sets or calls a ``_`` member of the estimators from outside their module
    (``model._check_params()``, ``predictor._fit_data(...)``, ``model._surrogate_from(...)``, ...): model files,
    wrappers, the search and the reductor go through the public API and the fitted flow map ``model_``."""
    mods = _modules()
    found = []
    for owner, classes in ESTIMATOR_CLASSES.items():
        names = _private_members(mods[owner], classes)
        assert {"_train", "_check_fitted", "_param_names"} <= names  # the scan sees the members
        for name, path in mods.items():
            if name != owner:
                found += [
                    f"{name}:{line} touches {attr}" for line, attr in _touches(ast.parse(path.read_text()), names)
                ]
    assert not found, "\n".join(found)


def test_the_private_member_scan_can_fail():
    """The scan of :func:`test_no_module_touches_the_estimators_private_members` finds a touch where there is one."""
    names = _private_members(
        _modules()["sympredict.estimators.predictor"], ESTIMATOR_CLASSES["sympredict.estimators.predictor"]
    )
    tree = ast.parse(
        "def f(model, cls):\n    model._fit_resolved(1)\n    cls._train()\n    return model.fit()\n"
        "class A:\n    def g(self):\n        return self._train()\n"
    )
    assert _touches(tree, names) == [(2, "_fit_resolved"), (3, "_train")]


# ------------------------------------------------------------------ the estimator stays small
#: The most lines the estimator class may span (docstring included): it holds settings, runs the fit's steps and
#: delegates predictions to the fitted flow map; hold-out scoring, the open settings' choice and the logs live apart.
ESTIMATOR_MAX_LINES = 399


def _class_lines(source: str, name: str) -> int:
    """Lines of the top-level class ``name`` of ``source``, docstring included (``end_lineno - lineno + 1``)."""
    (node,) = [n for n in ast.parse(source).body if isinstance(n, ast.ClassDef) and n.name == name]
    return node.end_lineno - node.lineno + 1


def test_the_estimator_class_stays_under_400_lines():
    lines = _class_lines((PACKAGE / "estimators" / "predictor.py").read_text(), "SymplecticKernelPredictor")
    assert lines <= ESTIMATOR_MAX_LINES, (
        f"SymplecticKernelPredictor spans {lines} lines (at most {ESTIMATOR_MAX_LINES}): move a responsibility "
        "out of the class (to the fitted flow map, the held-out scoring, the search) rather than cramming it"
    )
    # the count is the class's own span (what follows it does not count): a 400-line class is too long
    too_long = "class SymplecticKernelPredictor:\n" + "    x = 1\n" * 399 + "\n\ny = 2\n"
    assert _class_lines(too_long, "SymplecticKernelPredictor") == 400 > ESTIMATOR_MAX_LINES


# ------------------------------------------------------------------ the architecture page matches the code
ARCHITECTURE = ROOT / "docs" / "explanation" / "architecture.md"


def _layer_rows() -> list:
    """The rows of the architecture page's layer table (``| layer | folder or module | what lives there |``)."""
    rows, in_table = [], False
    for line in ARCHITECTURE.read_text().splitlines():
        if line.startswith("| layer"):
            in_table = True
        elif in_table and line.startswith("|"):
            if not line.startswith("|---"):
                rows.append(line)
        elif in_table:
            break
    return rows


def test_the_architecture_page_lists_every_module_in_its_folders_row():
    """Each module of a role folder (``sympredict/<folder>/<module>.py``, nested packages' modules too) is named
    in backticks in the table row of its folder: a new module is documented where it lives."""
    rows = _layer_rows()
    assert len(rows) >= 10, "the layer table was not found on docs/explanation/architecture.md"
    missing = []
    for folder in sorted(p for p in PACKAGE.iterdir() if p.is_dir() and (p / "__init__.py").exists()):
        row = [r for r in rows if f"`{folder.name}/`" in r]
        assert len(row) == 1, f"the layer table has {len(row)} rows for the folder {folder.name}/"
        for path in folder.rglob("*.py"):
            if path.name == "__init__.py":
                continue
            if f"`{path.stem}`" not in row[0]:
                missing.append(str(path.relative_to(PACKAGE)))
    assert not missing, f"docs/explanation/architecture.md does not list {missing} in its folder's row"


def test_the_architecture_page_states_the_estimators_settings():
    from sympredict import SymplecticKernelPredictor

    text = ARCHITECTURE.read_text()
    names = SymplecticKernelPredictor._param_names()
    words = {7: "seven", 8: "eight", 9: "nine", 10: "ten"}
    assert f"`SymplecticKernelPredictor` keeps {words.get(len(names), len(names))} settings" in text
    signature = text[text.index("SymplecticKernelPredictor(state_kernel") :].split(")", 1)[0]
    assert sorted(n.strip() for n in signature.split("(", 1)[1].split(",")) == names
