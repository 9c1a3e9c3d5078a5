"""Sphinx configuration of the sympredict documentation.

Build (warnings are errors, as in CI)::

    pip install -e ".[docs]"
    python -m sphinx -W --keep-going -b html docs docs/_build/html

The pages are the Markdown files in this folder (parsed by MyST) plus the API
reference (``reference/api.rst``, autodoc + napoleon over the NumPy-style docstrings).
The figures page (``explanation/figures.md``) shows the PNGs in ``docs/figures/``, copied
there from a ``sympredict-paper run all --quick`` output folder by
``python sympredict_paper/figures/collect_figures.py DIR``; they are committed, and a build
without them fails under -W (image file not readable).

Measured numbers and their tables are read at build time from the JSON files in
``docs/data/`` (``docs/_ext/jsondata.py``: the ``json-table`` and ``json-source``
directives and the ``json`` role); a reference that does not resolve, or a typed
number that disagrees with its source, fails the build under -W.
"""

import os
import sys
from pathlib import Path

# The package is normally installed (pip install -e .); the path entry makes a
# build from a bare checkout import the same sources.
ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
# docs/_ext: this documentation's own Sphinx extensions (jsondata: numbers rendered from JSON at build time)
sys.path.insert(0, str(Path(__file__).resolve().parent / "_ext"))
# plotting imports pyplot: never open a window while importing it for autodoc.
os.environ.setdefault("MPLBACKEND", "Agg")

import sympredict  # noqa: E402

project = "sympredict"
author = "the sympredict authors"
copyright = "2026, the sympredict authors"
release = sympredict.__version__
version = release

extensions = [
    "sphinx.ext.autodoc",
    "sphinx.ext.napoleon",
    "sphinx.ext.mathjax",
    "sphinx.ext.viewcode",
    "myst_parser",
    "jsondata",
]

source_suffix = {".rst": "restructuredtext", ".md": "markdown"}
root_doc = "index"
# failure_modes.py generates reference/errors.md; collect_figures.py fills figures/.
# Neither is a page, nor is anything in _ext.  _build is the output folder.
exclude_patterns = ["_build", "_ext", "failure_modes.py", "collect_figures.py", "Thumbs.db", ".DS_Store"]

# -- MyST ---------------------------------------------------------------------
# The pages write formulas as Unicode in code spans and indented blocks, with no
# $...$ math, so no math syntax extension is on: a "$" in prose stays a dollar.
# (Docstrings use reST ``.. math::``, rendered by sphinx.ext.mathjax.)
myst_enable_extensions = []
# "## 1. Data" and the like become link targets (#1-data) as on GitHub.
myst_heading_anchors = 3

# -- autodoc / napoleon ---------------------------------------------------------
autodoc_default_options = {
    "members": True,
    "undoc-members": False,
    "show-inheritance": True,
    "member-order": "bysource",
}
# Type hints stay in the signature: the NumPy docstrings already give the types
# of parameters and returns, and "description" would repeat them.
autodoc_typehints = "signature"
# The package imports pyMOR, h5py, matplotlib: all are install requirements,
# so nothing is mocked; an import failure is a real error.
autodoc_mock_imports = []

napoleon_numpy_docstring = True
napoleon_google_docstring = False
napoleon_use_rtype = False
napoleon_use_ivar = True
napoleon_preprocess_types = False
# Fitted attributes end in "_" (kernel_, history_): reST would read "kernel_" as
# a hyperlink reference and print "kernel".  With this option napoleon escapes
# the trailing underscore (it only affects names napoleon writes, and signatures,
# which contain no backslashes here).
strip_signature_backslash = True

# -- HTML -----------------------------------------------------------------------
html_theme = "alabaster"
html_title = f"sympredict {release}"
html_static_path = []
html_theme_options = {
    "description": "Symplectic large-step prediction of parameter-dependent Hamiltonian dynamics",
    "fixed_sidebar": True,
}


# -- docstring workaround --------------------------------------------------------
import re  # noqa: E402

_ENTRY = re.compile(r"\s*([A-Za-z_]\w*)\s*(?:\((.*)\))?\s*$")


def _split_attribute_lists(app, what, name, obj, options, lines):
    """Split NumPy "Attributes" entries that list several names on one line.

    ``DirectKernelPredictor``'s docstring lists its fitted attributes as
    ``kernel_, surrogate_ (type), history_, ...`` on one line, without the
    ``name : type`` form.  napoleon turns that into a single field whose name
    reST reads as hyperlink references (``kernel_``): an error under -W, and
    raw text in the page.  Such a line (inside an Attributes section, with a
    comma and no " : ") becomes one entry per name, a parenthesised part its
    description.  Regular entries are left to napoleon, which runs after this
    (priority 400 < napoleon's 500).  Remove once the docstring uses one
    ``name : type`` entry per attribute.
    """
    out, section = [], None
    for i, line in enumerate(lines):
        underline = i + 1 < len(lines) and lines[i + 1].strip() != "" and set(lines[i + 1].strip()) == {"-"}
        if underline and not line[:1].isspace():
            section = line.strip()
        elif section == "Attributes" and "," in line and " : " not in line and not line[:1].isspace():
            parts, depth, start = [], 0, 0
            for j, ch in enumerate(line):
                depth += ch == "("
                depth -= ch == ")"
                if ch == "," and depth == 0:
                    parts.append(line[start:j])
                    start = j + 1
            parts.append(line[start:])
            entries = [_ENTRY.match(part) for part in parts]
            if all(entries):
                for m in entries:
                    out.append(m.group(1))
                    if m.group(2):
                        out.append("    " + m.group(2))
                continue
        out.append(line)
    lines[:] = out


def _public_bases(app, name, obj, options, bases):
    """Show the public ancestors instead of a private base (``_FlowMapKernelModel``)."""
    i = 0
    while i < len(bases):
        if getattr(bases[i], "__name__", "").startswith("_"):
            bases[i : i + 1] = [b for b in bases[i].__bases__ if b not in bases]
        else:
            i += 1


# -- command-line help ------------------------------------------------------------
from docutils import nodes  # noqa: E402
from sphinx.util.docutils import SphinxDirective  # noqa: E402


class SympredictHelp(SphinxDirective):
    """``sympredict-help`` directive: the ``--help`` text of ``sympredict`` or of one subcommand; with the first
    argument ``sympredict-paper``, of the paper's command (``{sympredict-help} sympredict-paper run``).

    The text comes from ``sympredict.cli.build_parser()`` (``sympredict_paper.cli.build_parser()``) at build
    time, so the page always shows the options of the code it documents.  An unknown subcommand is an error.
    """

    optional_arguments = 2

    def run(self):
        import argparse

        from sympredict.cli import build_parser

        arguments, program = list(self.arguments), "sympredict"
        if arguments and arguments[0] == "sympredict-paper":
            from sympredict_paper.cli import build_parser

            program = arguments.pop(0)
        parser = build_parser()
        if arguments:
            name = arguments[0]
            sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
            if name not in sub.choices:
                raise self.error(f"{program} has no subcommand {name!r} (it has {', '.join(sub.choices)})")
            parser = sub.choices[name]
        old = os.environ.get("COLUMNS")
        os.environ["COLUMNS"] = "88"  # argparse wraps to the terminal width: fix it
        try:
            text = parser.format_help().rstrip()
        finally:
            if old is None:
                del os.environ["COLUMNS"]
            else:
                os.environ["COLUMNS"] = old
        block = nodes.literal_block(text, text)
        block["language"] = "text"
        return [block]


def setup(app):
    app.connect("autodoc-process-docstring", _split_attribute_lists, priority=400)
    app.add_directive("sympredict-help", SympredictHelp)
    app.connect("autodoc-process-bases", _public_bases)


# pyMOR's docstring substitutions used in sympredict.parallel (pyMOR defines them in its own docs)
rst_epilog = """
.. |WorkerPool| replace:: :class:`~pymor.parallel.interface.WorkerPool`
"""
