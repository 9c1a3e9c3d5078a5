"""Numbers in the documentation, read at build time from the JSON files that runs and benchmarks write.

Three pieces, registered by :func:`setup` (``docs/conf.py`` lists the extension):

``json-table`` directive
    A table whose rows are a list (or a dict) in a JSON file::

        ```{json-table} ../data/mutation_check.json
        :rows: areas
        :columns: area, faults, caught, ids
        :header: area, faults, caught, ids
        ```

    The argument is a path relative to the page (or, starting with ``/``, to
    ``docs/``).  ``:rows:`` is an expression (below) giving a list of dicts or a
    dict of dicts; ``:columns:`` lists one expression per column, each
    evaluated in its row and optionally followed by ``|FORMAT`` (a Python
    format spec, e.g. ``rows: backends`` and ``first_rollout_s|.3f``); ``@key``
    is a row's key when the rows are a dict.  ``:header:`` gives the column
    titles (default: the column expressions).  Under the table, a line says
    which command made the file, on which machine.

``json-source`` directive
    Only that line, for a table typed in Markdown whose cells are ``{json}`` roles.

``json`` role
    One number in running text: ``{json}`FILE:EXPR:FORMAT``` renders the value
    of ``EXPR`` in ``docs/data/FILE`` with the format spec ``FORMAT``
    (optional).  ``{json}`TEXT <FILE:EXPR:FORMAT>``` shows ``TEXT``, a number
    typed in the page, and checks it against the source: the build fails
    when the source's value, rounded to the digits ``TEXT`` gives, differs.

Expressions are key paths with arithmetic: ``backends.numba.first_rollout_s``,
``table[1].after * 1e3``, ``cli.numba.predict_s - cli.numpy.predict_s``,
``results["key with spaces"]``, ``len(results)``.  Only names, attributes, subscripts,
numbers, ``+ - * /`` and ``len`` are allowed.

Every JSON file read must say where it comes from: top-level ``command`` and
``machine`` keys (or the same keys under ``protocol``, as the benchmarks'
protocol record writes them).  A missing file, key, provenance, a value that
cannot be formatted, or a typed number that disagrees is an error: with
``sphinx -W`` the build fails.  The functions below are plain Python so that
``tests/docs/test_docs_numbers.py`` checks every reference in the pages without a build.
"""

from __future__ import annotations

import ast
import json
import math
import operator
import re
from pathlib import Path

__all__ = [
    "JsonDataError",
    "load",
    "provenance",
    "evaluate",
    "format_value",
    "check_typed",
    "parse_role",
    "resolve_role",
    "table_rows",
    "setup",
]


class JsonDataError(ValueError):
    """A reference to a JSON source that does not resolve, or a typed number that disagrees with it."""


_CACHE: dict = {}


def load(path) -> dict:
    """The JSON object in ``path``, checked to carry its provenance (``command`` and ``machine``).

    Raises
    ------
    JsonDataError
        If the file is missing, is not a JSON object, or lacks ``command`` / ``machine``.
    """
    path = Path(path)
    if not path.is_file():
        raise JsonDataError(f"JSON source {path} does not exist: write it with the run that makes it, or fix the path")
    key = (str(path.resolve()), path.stat().st_mtime_ns)
    if key not in _CACHE:
        try:
            data = json.loads(path.read_text(encoding="utf-8"))
        except ValueError as exc:
            raise JsonDataError(f"JSON source {path} is not valid JSON ({exc})") from None
        if not isinstance(data, dict):
            raise JsonDataError(
                f"JSON source {path} holds a {type(data).__name__}, not an object: the docs read keys of an object"
            )
        provenance(data, path)
        _CACHE[key] = data
    return _CACHE[key]


def _describe_machine(machine) -> str:
    if isinstance(machine, str):
        return machine
    if isinstance(machine, dict):
        parts = []
        if machine.get("cpus"):
            parts.append(f"{machine['cpus']} CPUs")
        for k in ("cpu_model", "cpu", "platform"):
            if machine.get(k):
                parts.append(str(machine[k]))
        if parts:
            return ", ".join(parts)
    raise JsonDataError("'machine' must be a string or an object with 'cpus' / 'cpu_model' / 'platform'")


def provenance(data: dict, path="<data>") -> tuple[str, str]:
    """``(command, machine)`` of a JSON source: top-level keys, else those of its ``protocol`` record."""
    for where in (data, data.get("protocol") if isinstance(data.get("protocol"), dict) else None):
        if where is not None and where.get("command") and where.get("machine"):
            try:
                return str(where["command"]), _describe_machine(where["machine"])
            except JsonDataError as exc:
                raise JsonDataError(f"JSON source {path}: {exc}") from None
    raise JsonDataError(
        f"JSON source {path} lacks 'command' and 'machine' keys: every source the docs read must say "
        "which command made it and on which machine (add them at the top level)"
    )


_BINOPS = {ast.Add: operator.add, ast.Sub: operator.sub, ast.Mult: operator.mul, ast.Div: operator.truediv}


def _keys(obj) -> str:
    if isinstance(obj, dict):
        names = list(obj)
        return "keys " + ", ".join(map(str, names[:20])) + (" ..." if len(names) > 20 else "")
    if isinstance(obj, list):
        return f"a list of {len(obj)}"
    return f"a {type(obj).__name__}"


def _get(obj, key, expr):
    try:
        if isinstance(obj, list) and isinstance(key, int):
            return obj[key]
        if isinstance(obj, dict) and isinstance(key, str):
            return obj[key]
    except (KeyError, IndexError):
        pass
    raise JsonDataError(f"{expr!r}: no {key!r} in {_keys(obj)}")


def evaluate(data, expr: str):
    """The value of the expression ``expr`` (key paths, numbers, ``+ - * /``, ``len``) in ``data``.

    Raises
    ------
    JsonDataError
        On a syntax error, a construct that is not allowed, or a key that does not exist
        (the message lists the keys that do).
    """
    expr = expr.strip()
    if expr.startswith("@"):
        if isinstance(data, dict) and expr in data:
            return data[expr]
        raise JsonDataError(f"{expr!r} is only defined in a table whose rows are a dict")
    try:
        tree = ast.parse(expr, mode="eval").body
    except SyntaxError:
        raise JsonDataError(
            f"{expr!r} is not an expression: write a key path such as a.b[0].c, numbers and + - * /"
        ) from None

    def ev(node):
        if isinstance(node, ast.Name):
            return _get(data, node.id, expr)
        if isinstance(node, ast.Attribute):
            return _get(ev(node.value), node.attr, expr)
        if isinstance(node, ast.Subscript) and isinstance(node.slice, ast.Constant):
            return _get(ev(node.value), node.slice.value, expr)
        if isinstance(node, ast.Constant) and isinstance(node.value, (int, float)) and not isinstance(node.value, bool):
            return node.value
        if (
            isinstance(node, ast.Call)
            and isinstance(node.func, ast.Name)
            and node.func.id == "len"
            and len(node.args) == 1
            and not node.keywords
        ):
            v = ev(node.args[0])
            if not isinstance(v, (list, dict)):
                raise JsonDataError(f"{expr!r}: len() of {v!r}, which is not a list or object")
            return len(v)
        if isinstance(node, ast.UnaryOp) and isinstance(node.op, ast.USub):
            return -_number(ev(node.operand))
        if isinstance(node, ast.BinOp) and type(node.op) in _BINOPS:
            return _BINOPS[type(node.op)](_number(ev(node.left)), _number(ev(node.right)))
        raise JsonDataError(
            f"{expr!r}: {ast.unparse(node)!r} is not allowed (only key paths, numbers, + - * / and len)"
        )

    def _number(v):
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise JsonDataError(f"{expr!r}: arithmetic on {v!r}, which is not a number")
        return v

    return ev(tree)


def format_value(value, fmt: str = "", where: str = "") -> str:
    """``value`` formatted with the Python format spec ``fmt``; a list becomes its items joined by ", "."""
    if isinstance(value, (dict,)) or value is None:
        raise JsonDataError(
            f"{where}: the value is {_keys(value) if value is not None else 'null'}, not a number or text"
        )
    if isinstance(value, float) and not math.isfinite(value):
        raise JsonDataError(f"{where}: the value is {value}, not a finite number")
    if isinstance(value, list):
        return ", ".join(format_value(v, fmt, where) for v in value)
    try:
        return format(value, fmt)
    except (ValueError, TypeError) as exc:
        raise JsonDataError(f"{where}: cannot format {value!r} with {fmt!r} ({exc})") from None


_NUMBER = re.compile(r"[-+−]?(?:\d[\d,]*\.?\d*|\.\d+)(?:e[-+]?\d+)?", re.IGNORECASE)


def check_typed(typed: str, value, where: str = "") -> None:
    """Raise unless the number in ``typed`` equals ``value`` rounded to the digits ``typed`` shows.

    ``typed`` may carry text around its one number (``"17.4 s"``, ``"1.45x"``,
    ``"69,437"``); ``"2.3e-5"`` allows half a unit in the last digit,
    ``0.05e-5``, and so on.  Non-numeric values must match exactly.
    """
    if isinstance(value, str) or isinstance(value, bool):
        if typed.strip() != str(value):
            raise JsonDataError(f"{where}: the page says {typed!r}, the source says {value!r}")
        return
    found = _NUMBER.findall(typed)
    if len(found) != 1:
        raise JsonDataError(f"{where}: {typed!r} must contain exactly one number to check against the source")
    text = found[0].replace(",", "").replace("−", "-")
    mantissa, _, exponent = text.lower().partition("e")
    decimals = len(mantissa.partition(".")[2])
    unit = 10.0 ** (int(exponent or 0) - decimals)
    if not abs(float(text) - float(value)) <= 0.5 * unit * (1 + 1e-9):
        raise JsonDataError(f"{where}: the page says {typed!r}, the source says {float(value):.6g}")


def parse_role(text: str) -> tuple:
    """``(typed or None, file, expr, fmt)`` of a role's text, ``FILE:EXPR[:FMT]`` or ``TYPED <FILE:EXPR[:FMT]>``."""
    m = re.fullmatch(r"\s*(.*?)\s*<([^<>]+)>\s*", text, re.DOTALL)
    typed, target = (m.group(1), m.group(2)) if m else (None, text.strip())
    parts = target.split(":", 2)
    if len(parts) < 2 or not parts[0] or not parts[1]:
        raise JsonDataError(f"{text!r}: write FILE:KEY[:FORMAT] or TYPED <FILE:KEY[:FORMAT]> (FILE in docs/data/)")
    return typed or None, parts[0].strip(), parts[1].strip(), parts[2].strip() if len(parts) > 2 else ""


def resolve_role(text: str, data_dir) -> tuple[str, Path]:
    """The text a ``json`` role shows, and the file it read; raises :class:`JsonDataError`."""
    typed, file, expr, fmt = parse_role(text)
    path = Path(data_dir) / file
    value = evaluate(load(path), expr)
    where = f"{file}:{expr}"
    shown = format_value(value, fmt, where)
    if typed is None:
        return shown, path
    check_typed(typed, value, where)
    return typed, path


def _split(spec: str) -> list[str]:
    return [s.strip() for s in spec.split(",") if s.strip()]


def table_rows(data: dict, rows_expr: str, columns: list[str], where: str = "") -> list[list[str]]:
    """The cells of a ``json-table``: ``columns`` (``EXPR`` or ``EXPR|FORMAT``) evaluated in each row of ``rows_expr``."""
    rows = evaluate(data, rows_expr)
    if isinstance(rows, dict):
        rows = [{**v, "@key": k} if isinstance(v, dict) else {"@key": k, "@value": v} for k, v in rows.items()]
    if not isinstance(rows, list) or not rows:
        raise JsonDataError(f"{where}: rows {rows_expr!r} is {_keys(rows)}, not a non-empty list or dict")
    out = []
    for i, row in enumerate(rows):
        cells = []
        for col in columns:
            expr, _, fmt = col.partition("|")
            at = f"{where} row {i} column {expr.strip()!r}"
            try:
                value = evaluate(row, expr)
            except JsonDataError as exc:
                raise JsonDataError(f"{at}: {exc}") from None
            cells.append(format_value(value, fmt.strip(), at))
        out.append(cells)
    return out


# ----------------------------------------------------------------------------- Sphinx


def setup(app):
    from docutils import nodes
    from docutils.parsers.rst import directives
    from sphinx.util.docutils import SphinxDirective

    app.add_config_value("json_data_dir", "data", "env")

    def made_by(path: Path, data: dict):
        command, machine = provenance(data, path)
        para = nodes.paragraph(classes=["json-source"])
        para += nodes.Text("Made by ")
        para += nodes.literal(command, command)
        para += nodes.Text(f" on {machine}.")
        return para

    class _JsonDirective(SphinxDirective):
        required_arguments = 1

        def source(self):
            rel, path = self.env.relfn2path(self.arguments[0], self.env.docname)
            self.env.note_dependency(rel)
            try:
                return Path(path), load(path)
            except JsonDataError as exc:
                raise self.error(str(exc)) from None

    class JsonTable(_JsonDirective):
        """``json-table``: a table of rows from a JSON file, with the command that made it."""

        option_spec = {
            "rows": directives.unchanged_required,
            "columns": directives.unchanged_required,
            "header": directives.unchanged,
        }

        def run(self):
            path, data = self.source()
            if "rows" not in self.options or "columns" not in self.options:
                raise self.error(
                    "json-table needs :rows: (the list in the file) and :columns: (one expression per column)"
                )
            columns = _split(self.options["columns"])
            header = _split(self.options.get("header") or "") or [c.partition("|")[0].strip() for c in columns]
            if len(header) != len(columns):
                raise self.error(f"json-table: {len(header)} headers for {len(columns)} columns")
            try:
                body = table_rows(data, self.options["rows"], columns, where=self.arguments[0])
            except JsonDataError as exc:
                raise self.error(str(exc)) from None
            table = nodes.table(classes=["json-table"])
            group = nodes.tgroup(cols=len(columns))
            table += group
            group.extend(nodes.colspec(colwidth=1) for _ in columns)

            def row(cells):
                r = nodes.row()
                for c in cells:
                    entry = nodes.entry()
                    entry += nodes.paragraph(c, c)
                    r += entry
                return r

            thead = nodes.thead()
            thead += row(header)
            tbody = nodes.tbody()
            tbody.extend(row(cells) for cells in body)
            group += thead
            group += tbody
            return [table, made_by(path, data)]

    class JsonSource(_JsonDirective):
        """``json-source``: the line "Made by COMMAND on MACHINE." of a JSON file."""

        def run(self):
            path, data = self.source()
            return [made_by(path, data)]

    def json_role(name, rawtext, text, lineno, inliner, options=None, content=()):
        env = inliner.document.settings.env
        data_dir = Path(env.srcdir) / env.config.json_data_dir
        try:
            shown, path = resolve_role(text, data_dir)
        except JsonDataError as exc:
            msg = inliner.reporter.error(str(exc), line=lineno)
            prb = inliner.problematic(rawtext, rawtext, msg)
            return [prb], [msg]
        env.note_dependency(str(path))
        return [nodes.inline(rawtext, shown, classes=["json-number"])], []

    app.add_directive("json-table", JsonTable)
    app.add_directive("json-source", JsonSource)
    app.add_role("json", json_role)
    return {"version": "1", "parallel_read_safe": True, "parallel_write_safe": True}
