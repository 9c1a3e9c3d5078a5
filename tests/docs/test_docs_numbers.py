"""Numbers in the docs are rendered from JSON at build time, and every reference resolves.

``docs/_ext/jsondata.py`` (the ``json`` role, the ``json-table`` and ``json-source``
directives) reads the JSON that runs and benchmarks write.  These tests find
every reference in the pages and resolve it with the extension's own functions,
check that wrong keys, wrong typed numbers and sources without provenance are
errors, and build a small Sphinx project with ``-W`` to show that such an error
fails the build.
"""

import json
import re
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
DOCS = ROOT / "docs"
sys.path.insert(0, str(DOCS / "_ext"))

import jsondata  # noqa: E402
from jsondata import JsonDataError  # noqa: E402

PAGES = sorted(DOCS.rglob("*.md"))
ROLE = re.compile(r"\{json\}`([^`]+)`")
DIRECTIVE = re.compile(r"^```\{(json-table|json-source)\}\s+(\S+)\s*\n((?::[\w-]+:.*\n)*)", re.MULTILINE)


def _references():
    roles, directives = [], []
    for page in PAGES:
        text = page.read_text(encoding="utf-8")
        roles += [(page, m.group(1)) for m in ROLE.finditer(text)]
        for m in DIRECTIVE.finditer(text):
            options = dict(re.findall(r"^:([\w-]+):\s*(.*)$", m.group(3), re.MULTILINE))
            directives.append((page, m.group(1), m.group(2), options))
    return roles, directives


ROLES, DIRECTIVES = _references()


def test_the_pages_render_numbers_from_every_committed_source():
    used = {jsondata.parse_role(text)[1] for _, text in ROLES} | {Path(p).name for _, _, p, _ in DIRECTIVES}
    assert {"mutation_check.json", "cold_start.json", "compare_rollout.json", "fe_wave_rom.json"} <= used
    assert any(kind == "json-table" for _, kind, _, _ in DIRECTIVES)


@pytest.mark.parametrize("page,text", ROLES, ids=[f"{p.relative_to(DOCS)}:{t}" for p, t in ROLES])
def test_every_json_role_resolves(page, text):
    shown, path = jsondata.resolve_role(text, DOCS / "data")
    assert shown.strip() and path.is_file()


@pytest.mark.parametrize(
    "page,kind,path,options", DIRECTIVES, ids=[f"{p.relative_to(DOCS)}:{k}:{a}" for p, k, a, _ in DIRECTIVES]
)
def test_every_json_directive_resolves(page, kind, path, options):
    data = jsondata.load(page.parent / path)
    command, machine = jsondata.provenance(data)
    assert command.strip() and machine.strip()
    if kind == "json-table":
        columns = [c.strip() for c in options["columns"].split(",")]
        rows = jsondata.table_rows(data, options["rows"], columns)
        assert rows and all(len(r) == len(columns) and all(c.strip() for c in r) for r in rows)


def test_the_mutation_table_matches_the_per_fault_results():
    """The ``areas`` summary the page renders counts the per-fault outcomes of the same file."""
    data = jsondata.load(DOCS / "data" / "mutation_check.json")
    areas = {a["area"]: a for a in data["areas"]}
    assert sum(a["faults"] for a in areas.values()) == len(data["results"])
    for r in data["results"]:
        assert r["id"] in areas[r["area"]]["ids"]
    caught = sum(r["outcome"] in ("CAUGHT", "TIMEOUT") for r in data["results"])
    assert sum(a["caught"] for a in areas.values()) == caught == data["counts"]["CAUGHT"] + data["counts"]["TIMEOUT"]


@pytest.fixture
def source(tmp_path):
    data = {
        "command": "python make.py --out x.json",
        "machine": "2 CPUs, test box",
        "a": 17.4238,
        "n": 69,
        "rows": [{"k": "x", "v": 1.5}, {"k": "y", "v": 2.25}],
        "by": {"numpy": {"t": 0.076}, "numba": {"t": 17.4}},
        "name": "IMQ",
        "flag": True,
    }
    (tmp_path / "x.json").write_text(json.dumps(data))
    return tmp_path


def test_role_renders_with_the_format(source):
    assert jsondata.resolve_role("x.json:a:.1f", source)[0] == "17.4"
    assert jsondata.resolve_role("x.json:n", source)[0] == "69"
    assert jsondata.resolve_role("x.json:a * 1e3:,.0f", source)[0] == "17,424"
    assert jsondata.resolve_role("x.json:by.numba.t - by.numpy.t:.3f", source)[0] == "17.324"
    assert jsondata.resolve_role("x.json:rows[1].v:.2f", source)[0] == "2.25"
    assert jsondata.resolve_role('x.json:by["numpy"].t', source)[0] == "0.076"
    assert jsondata.resolve_role("x.json:len(rows)", source)[0] == "2"


@pytest.mark.parametrize("typed", ["17.4", "17.42", "17.424 s", "1.74e1", "17"])
def test_a_typed_number_that_agrees_is_shown_as_typed(source, typed):
    assert jsondata.resolve_role(f"{typed} <x.json:a>", source)[0] == typed


@pytest.mark.parametrize("typed", ["17.5", "17.43", "17.4237", "1.8e1", "18", "about 17 or 18"])
def test_a_typed_number_that_disagrees_raises(source, typed):
    with pytest.raises(JsonDataError, match="x.json:a"):
        jsondata.resolve_role(f"{typed} <x.json:a>", source)


def test_typed_text_is_compared_exactly(source):
    assert jsondata.resolve_role("IMQ <x.json:name>", source)[0] == "IMQ"
    with pytest.raises(JsonDataError, match="page says 'Matern'"):
        jsondata.resolve_role("Matern <x.json:name>", source)


@pytest.mark.parametrize(
    "text,match",
    [
        ("x.json:b", r"no 'b' in keys command, machine, a"),
        ("x.json:rows[5].v", "no 5 in a list of 2"),
        ("x.json:by.jax.t", "no 'jax' in keys numpy, numba"),
        ("x.json:name * 2", "not a number"),
        ("x.json:__import__('os')", "not allowed"),
        ("x.json:a:d", "cannot format"),
        ("x.json:by", "not a number or text"),
        ("y.json:a", "does not exist"),
        ("x.json", "FILE:KEY"),
    ],
)
def test_a_wrong_reference_raises_and_says_what_exists(source, text, match):
    with pytest.raises(JsonDataError, match=match):
        jsondata.resolve_role(text, source)


def test_a_source_without_command_and_machine_is_refused(tmp_path):
    (tmp_path / "bare.json").write_text(json.dumps({"a": 1.0}))
    with pytest.raises(JsonDataError, match="lacks 'command' and 'machine'"):
        jsondata.load(tmp_path / "bare.json")
    (tmp_path / "proto.json").write_text(
        json.dumps({"a": 1.0, "protocol": {"command": "python b.py", "machine": {"cpus": 2, "platform": "Linux"}}})
    )
    assert jsondata.provenance(jsondata.load(tmp_path / "proto.json")) == ("python b.py", "2 CPUs, Linux")


def test_table_rows_from_a_list_and_from_a_dict(source):
    data = jsondata.load(source / "x.json")
    assert jsondata.table_rows(data, "rows", ["k", "v|.1f", "v * 2"]) == [["x", "1.5", "3.0"], ["y", "2.2", "4.5"]]
    assert jsondata.table_rows(data, "by", ["@key", "t|.2f"]) == [["numpy", "0.08"], ["numba", "17.40"]]
    with pytest.raises(JsonDataError, match="column 'w'"):
        jsondata.table_rows(data, "rows", ["k", "w"])
    with pytest.raises(JsonDataError, match="not a non-empty list or dict"):
        jsondata.table_rows(data, "a", ["k"])


def _build(tmp_path, page: str):
    """Build a one-page project with the extension under -W; (exit status, HTML or None, warnings)."""
    import io

    from sphinx.application import Sphinx

    src = tmp_path / "src"
    (src / "data").mkdir(parents=True)
    (src / "data" / "x.json").write_text(
        json.dumps(
            {"command": "python make.py", "machine": "2 CPUs, test box", "a": 17.4238, "rows": [{"k": "x", "v": 1.5}]}
        )
    )
    (src / "conf.py").write_text(
        f"import sys\nsys.path.insert(0, {str(DOCS / '_ext')!r})\nextensions = ['myst_parser', 'jsondata']\n"
    )
    (src / "index.md").write_text(page)
    warnings = io.StringIO()
    app = Sphinx(
        str(src),
        str(src),
        str(tmp_path / "out"),
        str(tmp_path / "doctrees"),
        "html",
        status=None,
        warning=warnings,
        warningiserror=True,
        keep_going=True,
        freshenv=True,
    )
    try:
        app.build()
    except Exception as exc:  # Sphinx < 8 raises on the first warning under warningiserror
        return 1, None, warnings.getvalue() + str(exc)
    html = (tmp_path / "out" / "index.html").read_text() if app.statuscode == 0 else None
    return app.statuscode, html, warnings.getvalue()


def test_sphinx_build_renders_the_numbers_and_the_source(tmp_path):
    page = (
        "# T\n\nIt took {json}`x.json:a:.1f` s, typed {json}`17.42 <x.json:a>` s.\n\n"
        "```{json-table} data/x.json\n:rows: rows\n:columns: k, v|.2f\n:header: key, value\n```\n"
    )
    status, html, warnings = _build(tmp_path, page)
    assert status == 0, warnings
    assert 'It took <span class="json-number">17.4</span> s' in html and ">17.42</span>" in html
    assert "<p>1.50</p>" in html and "<p>value</p>" in html
    assert re.search(r"Made by <code[^>]*>.*python.*make\.py.*</code> on 2 CPUs, test box\.", html)


@pytest.mark.parametrize(
    "bad,match",
    [
        ("{json}`17.5 <x.json:a>`", "the page says '17.5'"),
        ("{json}`x.json:b`", "no 'b'"),
        ("```{json-table} data/x.json\n:rows: rows\n:columns: k, w\n```", "column 'w'"),
    ],
)
def test_sphinx_build_fails_on_a_wrong_number_or_key(tmp_path, bad, match):
    status, _, warnings = _build(tmp_path, f"# T\n\n{bad}\n")
    assert status != 0 and match in warnings
