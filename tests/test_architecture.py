"""The package's import rule: dependencies point one way, layer by layer, with no cycles and nothing hidden.

Walks the import statements of every module (function bodies included) with
``ast``.  ``from sympredict import name`` counts as an import of the submodule
``name`` when there is one, else of the package namespace (which imports the
estimators).  A module missing from ``LAYERS`` fails the test: a new module
gets a place in the layering when it is added (docs/architecture.md).
"""

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "sympredict"

#: Lowest first.  A module may import modules of its own layer or below, never above.
LAYERS = [
    ("foundations", ["_version", "_numeric", "exceptions", "base", "_checks", "data", "newton_rule", "container"]),
    ("pool plumbing", ["parallel"]),
    ("kernels", ["kernels"]),
    ("compiled kernels", ["_fastkernels"]),
    ("interpolation", ["interpolation"]),
    ("symplectic", ["symplectic"]),
    ("systems, estimators", ["systems", "estimators", "sympredict"]),
    ("flowmap", ["flowmap"]),
    ("mor", ["mor"]),
    ("io, testing", ["io", "testing"]),
    ("paper", ["paper"]),
    ("cli", ["cli"]),
]

#: The command line imports its subcommands when they run (start-up time); it is the top layer, so a
#: function-level import there cannot hide a cycle.
LAZY_IMPORTS_ALLOWED = {"sympredict.cli"}


def _modules() -> dict:
    mods = {}
    for path in PACKAGE.rglob("*.py"):
        name = ".".join(("sympredict",) + path.relative_to(PACKAGE).with_suffix("").parts)
        mods[name[: -len(".__init__")] if name.endswith(".__init__") else name] = path
    return mods


def _layer(module: str) -> int:
    short = module[len("sympredict.") :] if module != "sympredict" else "sympredict"
    top = short.split(".")[0]
    for rank, (_, members) in enumerate(LAYERS):
        if top in members:
            return rank
    raise AssertionError(f"module {module} has no layer: add it to LAYERS in tests/test_architecture.py "
                         "and to docs/architecture.md")


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


def test_every_module_has_a_layer():
    for name in _modules():
        _layer(name)


def test_dependencies_point_down():
    mods = _modules()
    wrong = []
    for name, imports in _imports(mods).items():
        for target, line, _ in imports:
            if _layer(target) > _layer(name):
                wrong.append(f"{name}:{line} imports {target} ({LAYERS[_layer(name)][0]} -> {LAYERS[_layer(target)][0]})")
    assert not wrong, "imports that point up the layers:\n" + "\n".join(wrong)


def test_no_import_cycles():
    mods = _modules()
    graph = {name: {t for t, _, _ in imports} for name, imports in _imports(mods).items()}
    state, stack, cycles = {}, [], []

    def visit(u):
        state[u] = 1
        stack.append(u)
        for v in sorted(graph[u]):
            if state.get(v) == 1:
                cycles.append(" -> ".join(stack[stack.index(v):] + [v]))
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
    hidden = [f"{name}:{line} imports {target} inside a function"
              for name, imports in _imports(mods).items() if name not in LAZY_IMPORTS_ALLOWED
              for target, line, inside in imports if inside]
    assert not hidden, "\n".join(hidden)


@pytest.mark.parametrize("source,target,expected", [("sympredict.interpolation.greedy.loop", "sympredict.estimators.predictor", True),
                                                     ("sympredict.cli", "sympredict.kernels", False)])
def test_the_rule_itself_can_fail(source, target, expected):
    """The checks are not vacuous: an upward import is recognised as one."""
    assert (_layer(target) > _layer(source)) is expected
